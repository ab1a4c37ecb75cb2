//! Server setup in one place: services, limits, auth, TLS, health, reflection, shutdown.

use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use thiserror::Error;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio_stream::StreamExt;
use tokio_stream::wrappers::TcpListenerStream;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Identity, Server, ServerTlsConfig};
use tonic::{Request, Status};
use tracing::{info, warn};
use unigait_policy::SandboxLimits;
use unigait_proto::v1::simulator_server::SimulatorServer;
use unigait_sim::env::worker_pool;
use unigait_sim::robot::RobotModel;
use unigait_sim::task::TaskConfig;

use crate::evaluate::EvaluateContext;
use crate::limits::Limits;
use crate::service::SimulatorService;
use crate::session::Sessions;

/// Shortest bearer token the server accepts.
pub const MIN_TOKEN_LEN: usize = 16;

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
    /// Bearer token every Simulator call must carry (at least [`MIN_TOKEN_LEN`] characters).
    pub token: Option<String>,
    /// The executable client policies are loaded and run in (its `policy-worker` subcommand),
    /// under `sandbox` limits. None: in this process, after the static checks only.
    pub policy_worker: Option<PathBuf>,
    /// Limits of a policy worker.
    pub sandbox: SandboxLimits,
    /// How long a shutdown waits for calls in flight before the server stops anyway.
    pub drain_timeout: Duration,
    /// HTTP/2 keepalive ping interval (a peer that does not answer within the timeout is
    /// dropped) and TCP keepalive idle time.
    pub keepalive: Duration,
    /// Test hook: sessions created with this seed panic when stepped.
    #[doc(hidden)]
    pub fault_injection_seed: Option<u64>,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            limits: Limits::default(),
            threads: 0,
            base_config: TaskConfig::embedded_default(),
            tls: None,
            token: None,
            policy_worker: None,
            sandbox: SandboxLimits::default(),
            drain_timeout: Duration::from_secs(10),
            keepalive: Duration::from_secs(30),
            fault_injection_seed: None,
        }
    }
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
    /// The token is unusable.
    #[error("the bearer token {0}")]
    Token(String),
    /// The listener's address is unknown.
    #[error("listener: {0}")]
    Listener(#[from] std::io::Error),
}

/// Check a token the server is configured with.
pub fn check_token(token: &str) -> Result<(), ServeError> {
    if token.chars().count() < MIN_TOKEN_LEN {
        return Err(ServeError::Token(format!(
            "has {} characters; use at least {MIN_TOKEN_LEN} (e.g. `openssl rand -hex 32`)",
            token.chars().count()
        )));
    }
    if token.chars().any(|c| !c.is_ascii_graphic()) {
        return Err(ServeError::Token(
            "must be printable ASCII without spaces".into(),
        ));
    }
    Ok(())
}

/// Whether `a` and `b` are equal, in time that depends on their lengths only.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    let mut diff = a.len() ^ b.len();
    for i in 0..a.len().max(b.len()) {
        let x = a.get(i).copied().unwrap_or(0);
        let y = b.get(i).copied().unwrap_or(0);
        diff |= usize::from(x ^ y);
    }
    std::hint::black_box(diff) == 0
}

/// Checks `authorization: Bearer <token>` when a token is configured.
#[derive(Clone)]
struct TokenCheck(Option<Arc<str>>);

impl tonic::service::Interceptor for TokenCheck {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        let Some(token) = &self.0 else {
            return Ok(request);
        };
        let given = request.metadata_mut().remove("authorization");
        let given = given.as_ref().and_then(|v| v.to_str().ok());
        match given.and_then(|v| v.strip_prefix("Bearer ")) {
            Some(t) if constant_time_eq(t.as_bytes(), token.as_bytes()) => Ok(request),
            Some(_) => Err(Status::unauthenticated("wrong bearer token")),
            None => Err(Status::unauthenticated(
                "this server needs `authorization: Bearer <token>`",
            )),
        }
    }
}

/// Set TCP keepalive and no-delay on an accepted connection.
fn tune(stream: TcpStream, keepalive: Duration) -> std::io::Result<TcpStream> {
    stream.set_nodelay(true)?;
    let ka = socket2::TcpKeepalive::new()
        .with_time(keepalive)
        .with_interval(Duration::from_secs(10))
        .with_retries(3);
    socket2::SockRef::from(&stream).set_tcp_keepalive(&ka)?;
    Ok(stream)
}

/// Serve on `listener` until `shutdown` completes, then drain: health turns NOT_SERVING, new
/// sessions, streams and evaluations are refused, open streams end with UNAVAILABLE, running
/// evaluations stop, and the server returns once the calls in flight are done or
/// `drain_timeout` has passed.
pub async fn serve(
    listener: TcpListener,
    options: ServeOptions,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), ServeError> {
    if let Some(token) = &options.token {
        check_token(token)?;
    }
    let remote = !is_loopback(&listener.local_addr()?);
    let pool = worker_pool(options.threads)?;
    let limits = options.limits;
    let evaluation = Arc::new(EvaluateContext {
        base_config: options.base_config.clone(),
        model: Arc::new(RobotModel::go2()),
        pool: Some(pool.clone()),
        max_envs: limits.max_envs_per_session,
        policy_worker: options
            .policy_worker
            .clone()
            .map(|exe| (exe, options.sandbox)),
        max_duration: Duration::from_secs(limits.max_evaluation_s),
        max_reply_bytes: limits.max_evaluation_reply_bytes,
        max_policy_bytes: limits.max_policy_bytes,
    });
    if options.policy_worker.is_none() {
        warn!("no policy worker: client policies load in the server process (static checks only)");
    }
    let sessions = Arc::new(Sessions::new(
        limits,
        options.base_config.clone(),
        pool,
        options.fault_injection_seed,
    ));
    let (drain_tx, drain_rx) = watch::channel(false);
    let simulator = SimulatorServer::new(SimulatorService::new(
        sessions.clone(),
        evaluation,
        drain_rx.clone(),
    ))
    .max_decoding_message_size(limits.max_message_bytes())
    .max_encoding_message_size(limits.max_reply_bytes());
    let token = TokenCheck(options.token.as_deref().map(Arc::from));
    let simulator = InterceptedService::new(simulator, token.clone());

    let (health_reporter, health) = tonic_health::server::health_reporter();
    health_reporter
        .set_serving::<SimulatorServer<SimulatorService>>()
        .await;
    let reflection = |builder: tonic_reflection::server::Builder<'static>| {
        builder.register_encoded_file_descriptor_set(unigait_proto::v1::FILE_DESCRIPTOR_SET)
    };
    let reflection_v1 = reflection(tonic_reflection::server::Builder::configure())
        .build_v1()
        .map_err(|e| ServeError::Reflection(e.to_string()))?;
    let reflection_v1alpha = reflection(tonic_reflection::server::Builder::configure())
        .build_v1alpha()
        .map_err(|e| ServeError::Reflection(e.to_string()))?;
    // Beyond loopback, reflection (which describes the service) needs the token too; health
    // stays open for probes.
    let reflection_token = TokenCheck(if remote {
        options.token.as_deref().map(Arc::from)
    } else {
        None
    });

    let reaper = {
        let sessions = sessions.clone();
        let every = Duration::from_secs(limits.idle_timeout_s.clamp(1, 20)) / 2;
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(every);
            loop {
                tick.tick().await;
                for id in sessions.reap_idle() {
                    info!(session = %id, "closed an idle session");
                }
            }
        })
    };

    let mut builder = Server::builder()
        .http2_keepalive_interval(Some(options.keepalive))
        .http2_keepalive_timeout(Some(Duration::from_secs(20)));
    if let Some((cert, key)) = &options.tls {
        builder =
            builder.tls_config(ServerTlsConfig::new().identity(Identity::from_pem(cert, key)))?;
    }
    let keepalive = options.keepalive;
    let incoming =
        TcpListenerStream::new(listener).map(move |s| s.and_then(|s| tune(s, keepalive)));
    let signal = {
        let health_reporter = health_reporter.clone();
        async move {
            shutdown.await;
            info!("draining: refusing new work, ending open streams");
            health_reporter
                .set_not_serving::<SimulatorServer<SimulatorService>>()
                .await;
            health_reporter
                .set_service_status("", tonic_health::ServingStatus::NotServing)
                .await;
            let _ = drain_tx.send(true);
        }
    };
    let serving = builder
        .add_service(health)
        .add_service(InterceptedService::new(
            reflection_v1,
            reflection_token.clone(),
        ))
        .add_service(InterceptedService::new(
            reflection_v1alpha,
            reflection_token,
        ))
        .add_service(simulator)
        .serve_with_incoming_shutdown(incoming, signal);
    let mut drained = drain_rx.clone();
    let deadline = async move {
        let _ = drained.wait_for(|d| *d).await;
        tokio::time::sleep(options.drain_timeout).await;
    };
    let result = tokio::select! {
        r = serving => r,
        () = deadline => {
            warn!(timeout_s = options.drain_timeout.as_secs_f64(), "drain deadline passed; stopping with calls still open");
            Ok(())
        }
    };
    reaper.abort();
    let closed = sessions.close_all();
    info!(closed_sessions = closed, "server stopped");
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
    info!("shutdown requested; a second Ctrl-C exits at once");
    tokio::spawn(async {
        if tokio::signal::ctrl_c().await.is_ok() {
            warn!("second interrupt: exiting without draining");
            std::process::exit(130);
        }
    });
}

/// Whether serving on `addr` stays on this machine.
pub fn is_loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}
