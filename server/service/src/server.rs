//! Server setup in one place: services, limits, auth, TLS, health, reflection, shutdown.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use thiserror::Error;
use tokio::net::TcpListener;
use tokio_stream::wrappers::TcpListenerStream;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Identity, Server, ServerTlsConfig};
use tonic::{Request, Status};
use tracing::info;
use unigait_proto::v1::simulator_server::SimulatorServer;
use unigait_sim::env::worker_pool;
use unigait_sim::robot::RobotModel;
use unigait_sim::task::TaskConfig;

use crate::evaluate::EvaluateContext;
use crate::limits::Limits;
use crate::service::SimulatorService;
use crate::session::Sessions;

/// Everything a server is started with.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Limits on sessions and envs.
    pub limits: Limits,
    /// Env worker threads (0 = one per core).
    pub threads: usize,
    /// The task config sessions start from.
    pub base_config: TaskConfig,
    /// TLS certificate and key (PEM).
    pub tls: Option<(Vec<u8>, Vec<u8>)>,
    /// Bearer token every Simulator call must carry.
    pub token: Option<String>,
}

/// Why a server could not start or stopped.
#[derive(Debug, Error)]
pub enum ServeError {
    /// The env worker pool could not be built.
    #[error(transparent)]
    Sim(#[from] unigait_sim::SimError),
    /// TLS configuration or the transport failed.
    #[error(transparent)]
    Transport(#[from] tonic::transport::Error),
    /// The reflection service could not be built.
    #[error("reflection: {0}")]
    Reflection(String),
}

/// Checks `authorization: Bearer <token>` when a token is configured.
#[derive(Clone)]
struct TokenCheck(Option<Arc<str>>);

impl tonic::service::Interceptor for TokenCheck {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        let Some(token) = &self.0 else {
            return Ok(request);
        };
        let given = request
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok());
        match given.and_then(|v| v.strip_prefix("Bearer ")) {
            Some(t) if t.as_bytes() == token.as_bytes() => Ok(request),
            Some(_) => Err(Status::unauthenticated("wrong bearer token")),
            None => Err(Status::unauthenticated(
                "this server needs `authorization: Bearer <token>`",
            )),
        }
    }
}

/// Serve on `listener` until `shutdown` completes, then finish in-flight calls and return.
pub async fn serve(
    listener: TcpListener,
    options: ServeOptions,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), ServeError> {
    let pool = worker_pool(options.threads)?;
    let evaluation = Arc::new(EvaluateContext {
        base_config: options.base_config.clone(),
        model: Arc::new(RobotModel::go2()),
        pool: Some(pool.clone()),
        max_envs: options.limits.max_envs_per_session,
    });
    let sessions = Arc::new(Sessions::new(
        options.limits,
        options.base_config.clone(),
        pool,
    ));
    let max_message = options.limits.max_message_bytes();
    let simulator = SimulatorServer::new(SimulatorService::new(sessions.clone(), evaluation))
        .max_decoding_message_size(max_message)
        .max_encoding_message_size(max_message);
    let simulator = InterceptedService::new(
        simulator,
        TokenCheck(options.token.as_deref().map(Arc::from)),
    );

    let (health_reporter, health) = tonic_health::server::health_reporter();
    health_reporter
        .set_serving::<SimulatorServer<SimulatorService>>()
        .await;
    let reflection = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(unigait_proto::v1::FILE_DESCRIPTOR_SET)
        .build_v1()
        .map_err(|e| ServeError::Reflection(e.to_string()))?;

    let reaper = {
        let sessions = sessions.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(10));
            loop {
                tick.tick().await;
                for id in sessions.reap_idle() {
                    info!(session = %id, "closed an idle session");
                }
            }
        })
    };

    let mut builder = Server::builder();
    if let Some((cert, key)) = &options.tls {
        builder =
            builder.tls_config(ServerTlsConfig::new().identity(Identity::from_pem(cert, key)))?;
    }
    let result = builder
        .add_service(health)
        .add_service(reflection)
        .add_service(simulator)
        .serve_with_incoming_shutdown(TcpListenerStream::new(listener), shutdown)
        .await;
    reaper.abort();
    info!("server stopped");
    Ok(result?)
}

/// Resolves on SIGINT or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
    info!("shutdown requested");
}

/// Whether serving on `addr` stays on this machine.
pub fn is_loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}
