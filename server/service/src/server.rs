//! Server setup in one place: services, limits, auth, TLS, health, reflection, shutdown.

use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use std::pin::Pin;
use std::task::Poll;
use thiserror::Error;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore, mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::server::{Connected, TcpConnectInfo};
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
    /// Connection and HTTP/2 limits.
    pub transport: TransportLimits,
    /// Test hook: sessions created with this seed panic when stepped.
    #[doc(hidden)]
    pub fault_injection_seed: Option<u64>,
    /// Test hook: apply the rules for serving beyond loopback on a loopback listener.
    #[doc(hidden)]
    pub assume_remote: bool,
}

/// Limits on connections and HTTP/2 streams, so that idle or half-open connections and
/// stream floods cannot exhaust the server's file descriptors, tasks or memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TransportLimits {
    /// Connections open at once (accepted, handshaking or serving); beyond it the server stops
    /// accepting until one closes (new ones wait in the listen backlog). Default 512.
    pub max_connections: usize,
    /// HTTP/2 streams (calls) open at once on one connection. Default 128.
    pub max_concurrent_streams: u32,
    /// Time a new connection has to send its first bytes (the HTTP/2 preface, or a TLS
    /// ClientHello) and to finish its TLS handshake. Default 10 s.
    pub handshake_timeout: Duration,
    /// Age after which a connection is asked to go away (GOAWAY; calls in flight finish, the
    /// client reconnects); None: no limit (the default, as a training run's step stream may
    /// last days).
    pub max_connection_age: Option<Duration>,
    /// Streams a client may reset before the server accepts them, and streams the server
    /// may reset for a client's protocol errors, before the connection is closed (h2's and
    /// hyper's defaults, which tonic does not pass on by itself). Default 20 and 1024.
    pub max_pending_accept_reset_streams: usize,
    /// See `max_pending_accept_reset_streams`.
    pub max_local_error_reset_streams: usize,
}

impl Default for TransportLimits {
    fn default() -> Self {
        Self {
            max_connections: 512,
            max_concurrent_streams: 128,
            handshake_timeout: Duration::from_secs(10),
            max_connection_age: None,
            max_pending_accept_reset_streams: 20,
            max_local_error_reset_streams: 1024,
        }
    }
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
            transport: TransportLimits::default(),
            fault_injection_seed: None,
            assume_remote: false,
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

/// Whether `a` and `b` are equal, in time that depends on their lengths only (`subtle`, whose
/// comparison the optimiser cannot turn into an early exit).
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    use subtle::ConstantTimeEq;
    a.ct_eq(b).into()
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

/// Requires the token on Health `Watch` only (a stream a client holds open); `Check` stays
/// open for probes. The call's path comes from [`WithPath`].
#[derive(Clone)]
struct WatchTokenCheck(TokenCheck);

impl tonic::service::Interceptor for WatchTokenCheck {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        match request.extensions().get::<CallPath>() {
            Some(CallPath(path)) if !path.ends_with("/Check") => self.0.call(request),
            Some(_) => Ok(request),
            // Fail closed: every call comes through `WithPath`.
            None => self.0.call(request),
        }
    }
}

/// The HTTP path of a call, for interceptors (which see no URI).
#[derive(Clone)]
struct CallPath(String);

/// Puts the call's path into the request's extensions, as a [`CallPath`].
#[derive(Clone)]
struct WithPath<S>(S);

impl<S, B> tonic::codegen::Service<tonic::codegen::http::Request<B>> for WithPath<S>
where
    S: tonic::codegen::Service<tonic::codegen::http::Request<B>>,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = S::Future;

    fn poll_ready(
        &mut self,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Result<(), Self::Error>> {
        self.0.poll_ready(cx)
    }

    fn call(&mut self, mut request: tonic::codegen::http::Request<B>) -> Self::Future {
        let path = CallPath(request.uri().path().to_owned());
        request.extensions_mut().insert(path);
        self.0.call(request)
    }
}

impl<S: tonic::server::NamedService> tonic::server::NamedService for WithPath<S> {
    const NAME: &'static str = S::NAME;
}

/// Set TCP keepalive and no-delay on an accepted connection.
fn tune(stream: &TcpStream, keepalive: Duration) -> std::io::Result<()> {
    stream.set_nodelay(true)?;
    let ka = socket2::TcpKeepalive::new()
        .with_time(keepalive)
        .with_interval(Duration::from_secs(10))
        .with_retries(3);
    socket2::SockRef::from(stream).set_tcp_keepalive(&ka)?;
    Ok(())
}

/// Bytes a new connection must send within the handshake timeout: the HTTP/2 client preface
/// (`PRI * HTTP/2.0...`, 24 bytes); a TLS ClientHello is longer.
const FIRST_BYTES: usize = 24;

/// An accepted connection: holds one of the server's connection slots until it is dropped,
/// and fails its reads if its first bytes do not come within the handshake timeout.
struct Connection {
    stream: TcpStream,
    _slot: OwnedSemaphorePermit,
    /// Until the first bytes have come: the deadline and the bytes read so far.
    first_bytes: Option<(Pin<Box<tokio::time::Sleep>>, usize)>,
}

impl AsyncRead for Connection {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let this = &mut *self;
        let before = buf.filled().len();
        let polled = Pin::new(&mut this.stream).poll_read(cx, buf);
        if let Some((deadline, read)) = &mut this.first_bytes {
            *read += buf.filled().len() - before;
            if *read >= FIRST_BYTES {
                this.first_bytes = None;
            } else if polled.is_pending() && deadline.as_mut().poll(cx).is_ready() {
                return Poll::Ready(Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    "no handshake within the server's handshake timeout",
                )));
            }
        }
        polled
    }
}

impl AsyncWrite for Connection {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }

    fn poll_flush(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

impl Connected for Connection {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.stream.connect_info()
    }
}

/// Waits after a failed accept: 5 ms, doubling up to 1 s, back to the start after a success.
#[derive(Debug, Default)]
struct AcceptBackoff {
    failures: u32,
}

impl AcceptBackoff {
    /// The wait after one more failure.
    fn next_wait(&mut self) -> Duration {
        let wait = Duration::from_millis(5 << self.failures.min(8)).min(Duration::from_secs(1));
        self.failures = self.failures.saturating_add(1);
        wait
    }

    /// After a success.
    fn reset(&mut self) {
        self.failures = 0;
    }
}

/// Accept connections from `listener` into `tx` while a connection slot is free, until
/// `draining` turns true or the receiver goes. A failed accept (out of file descriptors, say)
/// waits with [`AcceptBackoff`] instead of retrying at once.
async fn accept_loop(
    listener: TcpListener,
    slots: Arc<Semaphore>,
    tx: mpsc::Sender<std::io::Result<Connection>>,
    transport: TransportLimits,
    keepalive: Duration,
    mut draining: watch::Receiver<bool>,
) {
    let mut backoff = AcceptBackoff::default();
    let mut warned_full = false;
    loop {
        let slot = match slots.clone().try_acquire_owned() {
            Ok(slot) => slot,
            Err(_) => {
                if !warned_full {
                    warn!(
                        max_connections = transport.max_connections,
                        "connection limit reached; new connections wait until one closes"
                    );
                    warned_full = true;
                }
                tokio::select! {
                    slot = slots.clone().acquire_owned() => match slot {
                        Ok(slot) => slot,
                        Err(_) => return,
                    },
                    _ = draining.wait_for(|d| *d) => return,
                }
            }
        };
        let accepted = tokio::select! {
            a = listener.accept() => a,
            _ = draining.wait_for(|d| *d) => return,
        };
        match accepted {
            Ok((stream, _)) => {
                backoff.reset();
                if slots.available_permits() > 0 {
                    warned_full = false;
                }
                if let Err(e) = tune(&stream, keepalive) {
                    // The peer may already be gone; the connection fails on its own then.
                    tracing::debug!(error = %e, "cannot tune an accepted connection");
                }
                let deadline = Box::pin(tokio::time::sleep(transport.handshake_timeout));
                let connection = Connection {
                    stream,
                    _slot: slot,
                    first_bytes: Some((deadline, 0)),
                };
                if tx.send(Ok(connection)).await.is_err() {
                    return;
                }
            }
            Err(e) => {
                let wait = backoff.next_wait();
                warn!(error = %e, wait_ms = wait.as_millis() as u64, "accept failed; waiting before the next");
                drop(slot);
                tokio::select! {
                    () = tokio::time::sleep(wait) => {}
                    _ = draining.wait_for(|d| *d) => return,
                }
            }
        }
    }
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
    let remote = options.assume_remote || !is_loopback(&listener.local_addr()?);
    let pool = worker_pool(options.threads)?;
    let limits = options.limits;
    let evaluation = Arc::new(EvaluateContext {
        base_config: options.base_config.clone(),
        model: Arc::new(RobotModel::go2()),
        pool: Some(pool.clone()),
        policy_worker: options
            .policy_worker
            .clone()
            .map(|exe| (exe, options.sandbox)),
        limits,
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
    // Beyond loopback, reflection (which describes the service) and health's Watch (a stream
    // held open) need the token too; health's Check stays open for probes.
    let reflection_token = TokenCheck(if remote {
        options.token.as_deref().map(Arc::from)
    } else {
        None
    });
    let health = WithPath(InterceptedService::new(
        health,
        WatchTokenCheck(reflection_token.clone()),
    ));

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

    let transport = options.transport;
    let mut builder = Server::builder()
        .http2_keepalive_interval(Some(options.keepalive))
        .http2_keepalive_timeout(Some(Duration::from_secs(20)))
        .max_concurrent_streams(Some(transport.max_concurrent_streams))
        .http2_max_pending_accept_reset_streams(Some(transport.max_pending_accept_reset_streams))
        .http2_max_local_error_reset_streams(Some(transport.max_local_error_reset_streams));
    if let Some(age) = transport.max_connection_age {
        // No `max_connection_age_grace`: with it, tonic sends no GOAWAY at the age but cuts the
        // connection at age + grace, calls in flight and all.
        builder = builder.max_connection_age(age);
    }
    if let Some((cert, key)) = &options.tls {
        builder = builder.tls_config(
            ServerTlsConfig::new()
                .identity(Identity::from_pem(cert, key))
                .timeout(transport.handshake_timeout),
        )?;
    }
    let (conn_tx, conn_rx) = mpsc::channel(1);
    let acceptor = tokio::spawn(accept_loop(
        listener,
        Arc::new(Semaphore::new(transport.max_connections.max(1))),
        conn_tx,
        transport,
        options.keepalive,
        drain_rx.clone(),
    ));
    let incoming = ReceiverStream::new(conn_rx);
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
    acceptor.abort();
    let closed = sessions.close_all();
    info!(closed_sessions = closed, "server stopped");
    Ok(result?)
}

/// Resolves on SIGINT or SIGTERM; a second SIGINT then exits the process at once (130).
#[cfg(unix)]
pub async fn shutdown_signal() {
    use tokio::signal::unix::{SignalKind, signal};
    // One SIGINT stream for both: it is registered before the first signal, so a second one
    // that comes right after is not missed.
    let (Ok(mut interrupts), Ok(mut terms)) = (
        signal(SignalKind::interrupt()),
        signal(SignalKind::terminate()),
    ) else {
        warn!("cannot listen for SIGINT/SIGTERM; stop the server with SIGKILL");
        return std::future::pending().await;
    };
    tokio::select! {
        _ = interrupts.recv() => {},
        _ = terms.recv() => {},
    }
    info!("shutdown requested; a second Ctrl-C exits at once");
    tokio::spawn(async move {
        if interrupts.recv().await.is_some() {
            warn!("second interrupt: exiting without draining");
            std::process::exit(130);
        }
    });
}

/// Resolves on Ctrl-C; a second one then exits the process at once (130).
#[cfg(not(unix))]
pub async fn shutdown_signal() {
    let _ = tokio::signal::ctrl_c().await;
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

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::Code;

    const TOKEN: &str = "0123456789abcdef-unit-token";

    fn check(token: Option<&str>, header: Option<&str>) -> Result<(), Code> {
        let mut request = Request::new(());
        if let Some(h) = header {
            request
                .metadata_mut()
                .insert("authorization", h.parse().expect("header"));
        }
        let mut interceptor = TokenCheck(token.map(Arc::from));
        tonic::service::Interceptor::call(&mut interceptor, request)
            .map(|_| ())
            .map_err(|s| s.code())
    }

    #[test]
    fn tokens_compare_equal_only_when_identical() {
        let t = TOKEN.as_bytes();
        assert!(constant_time_eq(t, t));
        assert!(constant_time_eq(b"", b""));
        // Every prefix, every extension, and a change at every position differs.
        for n in 0..t.len() {
            assert!(!constant_time_eq(&t[..n], t), "prefix of {n}");
            assert!(!constant_time_eq(t, &t[..n]), "prefix of {n}, swapped");
            let mut changed = t.to_vec();
            changed[n] ^= 1;
            assert!(!constant_time_eq(&changed, t), "byte {n} changed");
        }
        let longer = [t, b"x"].concat();
        assert!(!constant_time_eq(&longer, t));
        assert!(!constant_time_eq(t, &longer));
        // Zero bytes past the end are not "equal padding".
        let padded = [t, &[0u8]].concat();
        assert!(!constant_time_eq(&padded, t));
    }

    #[test]
    fn the_interceptor_wants_exactly_bearer_and_the_token() {
        assert_eq!(check(None, None), Ok(()));
        assert_eq!(check(Some(TOKEN), Some(&format!("Bearer {TOKEN}"))), Ok(()));
        for wrong in [
            format!("Bearer {TOKEN}x"),
            format!("Bearer {}", &TOKEN[..TOKEN.len() - 1]),
            format!("bearer {TOKEN}"),
            format!("Bearer  {TOKEN}"),
            TOKEN.to_string(),
            "Bearer ".to_string(),
        ] {
            assert_eq!(
                check(Some(TOKEN), Some(&wrong)),
                Err(Code::Unauthenticated),
                "{wrong:?}"
            );
        }
        assert_eq!(check(Some(TOKEN), None), Err(Code::Unauthenticated));
    }

    #[test]
    fn accept_backoff_doubles_to_a_second_and_resets() {
        let mut b = AcceptBackoff::default();
        let waits: Vec<u64> = (0..10).map(|_| b.next_wait().as_millis() as u64).collect();
        assert_eq!(waits, [5, 10, 20, 40, 80, 160, 320, 640, 1000, 1000]);
        b.reset();
        assert_eq!(b.next_wait(), Duration::from_millis(5));
    }
}
