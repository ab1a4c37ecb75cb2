//! The gRPC handlers: validate, convert, call the core on a blocking thread, convert back.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::sync::{Semaphore, mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::{Stream, StreamExt};
use tonic::{Request, Response, Status, Streaming};
use tracing::{info, warn};
use unigait_proto::v1::{self, simulator_server::Simulator};

use crate::error::{ServiceError, cut_message};
use crate::evaluate::{self, EvaluateContext, StopFlag};
use crate::session::{Session, Sessions};

/// The Simulator service.
#[derive(Clone)]
pub struct SimulatorService {
    sessions: Arc<Sessions>,
    evaluation: Arc<EvaluateContext>,
    evaluations: Arc<Semaphore>,
    draining: watch::Receiver<bool>,
}

impl SimulatorService {
    /// A service over `sessions`, evaluating policies with `evaluation`; its streams end with
    /// UNAVAILABLE once `draining` turns true.
    pub fn new(
        sessions: Arc<Sessions>,
        evaluation: Arc<EvaluateContext>,
        draining: watch::Receiver<bool>,
    ) -> Self {
        let slots = sessions.limits().max_concurrent_evaluations;
        Self {
            sessions,
            evaluation,
            evaluations: Arc::new(Semaphore::new(slots)),
            draining,
        }
    }
}

/// A status from a service error, with the message cut to a readable length.
fn status(e: ServiceError) -> Status {
    Status::from(e)
}

/// Run blocking work (env building) off the async runtime's threads.
async fn blocking<T: Send + 'static>(
    work: impl FnOnce() -> Result<T, ServiceError> + Send + 'static,
) -> Result<T, Status> {
    tokio::task::spawn_blocking(work)
        .await
        .map_err(|e| Status::internal(cut_message(&format!("worker failed: {e}"))))?
        .map_err(status)
}

/// Run a blocking operation on `session`. A panic (a server bug) or a lock broken by one
/// closes the session: it answers INTERNAL once, then NOT_FOUND, instead of INTERNAL forever.
async fn on_session<T: Send + 'static>(
    sessions: &Sessions,
    session: Arc<Session>,
    work: impl FnOnce(&Session) -> Result<T, ServiceError> + Send + 'static,
) -> Result<T, Status> {
    let id = session.id.clone();
    // Counted before it waits for the session's lock (or a blocking thread), so one client's
    // flood of calls on one session is refused rather than queued.
    let slot = session
        .begin_call(sessions.limits().max_calls_per_session)
        .map_err(status)?;
    let joined = tokio::task::spawn_blocking(move || {
        let _slot = slot;
        work(&session)
    })
    .await;
    let broken = match joined {
        Ok(Ok(value)) => return Ok(value),
        Ok(Err(e @ ServiceError::Broken(_))) => e,
        Ok(Err(e)) => return Err(status(e)),
        Err(e) => {
            warn!(session = %id, error = %e, "a session operation panicked");
            ServiceError::Broken(id.clone())
        }
    };
    if sessions.close(&id).is_ok() {
        warn!(session = %id, "closed a session broken by a server error");
    }
    Err(status(broken))
}

/// How a step stream's wait for the next request ended.
enum Next {
    Request(Option<Result<v1::StepRequest, Status>>),
    Closed,
    Draining,
    Idle,
}

/// Wait for the stream's next request, the session's close, the server's drain or the idle
/// timeout, whichever comes first.
async fn next_request(
    inbound: &mut Streaming<v1::StepRequest>,
    session: Option<&Session>,
    draining: &mut watch::Receiver<bool>,
    idle: Duration,
) -> Next {
    let closed = async {
        match session {
            Some(s) => s.closed().await,
            None => std::future::pending().await,
        }
    };
    tokio::select! {
        item = tokio::time::timeout(idle, inbound.next()) => match item {
            Ok(item) => Next::Request(item),
            Err(_) => Next::Idle,
        },
        () = closed => Next::Closed,
        _ = draining.wait_for(|d| *d) => Next::Draining,
    }
}

fn draining_status() -> Status {
    Status::unavailable("the server is shutting down; reconnect to another server or later")
}

/// Send `item` on the stream unless the client has not read for `timeout` (its replies fill
/// the HTTP/2 window, then this channel); false when it is not sent.
async fn send_within(
    tx: &mpsc::Sender<Result<v1::StepResult, Status>>,
    item: Result<v1::StepResult, Status>,
    timeout: Duration,
) -> bool {
    matches!(
        tokio::time::timeout(timeout, tx.send(item)).await,
        Ok(Ok(()))
    )
}

/// Serve one step stream: the first request names the session; each request gets one reply.
/// A failed step, a bad or oversized message, a close or a server shutdown end the stream with
/// that status. The session outlives its stream (a client whose connection broke can open a
/// new one) until it is closed or idle for the idle timeout.
async fn run_step_stream(
    sessions: Arc<Sessions>,
    mut inbound: Streaming<v1::StepRequest>,
    tx: mpsc::Sender<Result<v1::StepResult, Status>>,
    mut draining: watch::Receiver<bool>,
) {
    let idle = Duration::from_secs(sessions.limits().stream_idle_timeout_s.max(1));
    let first = match next_request(&mut inbound, None, &mut draining, idle).await {
        Next::Request(Some(Ok(first))) => first,
        Next::Request(Some(Err(status))) => {
            send_within(&tx, Err(status), idle).await;
            return;
        }
        Next::Draining => {
            send_within(&tx, Err(draining_status()), idle).await;
            return;
        }
        Next::Idle => {
            let end = Status::deadline_exceeded(
                "no request on the step stream within the server's stream idle timeout",
            );
            send_within(&tx, Err(end), idle).await;
            return;
        }
        Next::Request(None) | Next::Closed => return,
    };
    let session = match sessions
        .get(&first.session_id)
        .and_then(|s| s.open_stream().map(|g| (s, g)))
    {
        Ok(found) => found,
        Err(e) => {
            send_within(&tx, Err(status(e)), idle).await;
            return;
        }
    };
    let (session, _guard) = session;
    let mut request = first;
    loop {
        if !request.session_id.is_empty() && request.session_id != session.id {
            let message = format!(
                "this stream belongs to session `{}`, not `{}`",
                session.id, request.session_id
            );
            let end = Status::invalid_argument(cut_message(&message));
            send_within(&tx, Err(end), idle).await;
            return;
        }
        let result = on_session(&sessions, session.clone(), move |s| s.step(&request)).await;
        let failed = result.is_err();
        if !send_within(&tx, result, idle).await {
            info!(session = %session.id, "client stopped reading its step stream (gone, or no reply read within the stream idle timeout); the stream ends, the session stays until closed or idle");
            return;
        }
        if failed {
            return;
        }
        request = match next_request(&mut inbound, Some(&session), &mut draining, idle).await {
            Next::Request(Some(Ok(r))) => r,
            Next::Request(Some(Err(status))) => {
                warn!(session = %session.id, %status, "step stream broken; the session stays until closed or idle");
                send_within(&tx, Err(status), idle).await;
                return;
            }
            Next::Request(None) => return,
            Next::Closed => {
                let end = Status::not_found(format!("session `{}` was closed", session.id));
                send_within(&tx, Err(end), idle).await;
                return;
            }
            Next::Draining => {
                send_within(&tx, Err(draining_status()), idle).await;
                return;
            }
            Next::Idle => {
                warn!(session = %session.id, "step stream idle; ended (the session stays until closed or idle)");
                let end = Status::deadline_exceeded(
                    "no request on the step stream within the server's stream idle timeout; open a new stream to go on",
                );
                send_within(&tx, Err(end), idle).await;
                return;
            }
        };
    }
}

type ResultStream = Pin<Box<dyn Stream<Item = Result<v1::StepResult, Status>> + Send>>;

/// Sets its flag when dropped: the handler's future was dropped (caller gone, deadline) or
/// finished.
struct StopOnDrop(StopFlag);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Release);
    }
}

#[tonic::async_trait]
impl Simulator for SimulatorService {
    async fn get_server_info(
        &self,
        _: Request<v1::GetServerInfoRequest>,
    ) -> Result<Response<v1::ServerInfo>, Status> {
        let limits = self.sessions.limits();
        Ok(Response::new(v1::ServerInfo {
            protocol_version: unigait_proto::PROTOCOL_VERSION.into(),
            server_version: crate::convert::SERVER_VERSION.into(),
            max_envs_per_session: limits.max_envs_per_session as u32,
            max_sessions: limits.max_sessions as u32,
            active_sessions: self.sessions.len() as u32,
            threads: self.sessions.threads() as u32,
            max_message_bytes: limits.max_message_bytes() as u64,
            active_envs: self.sessions.envs_in_use() as u32,
        }))
    }

    async fn create_session(
        &self,
        request: Request<v1::CreateSessionRequest>,
    ) -> Result<Response<v1::CreateSessionResponse>, Status> {
        if *self.draining.borrow() {
            return Err(draining_status());
        }
        let config = request.into_inner().config.unwrap_or_default();
        let sessions = self.sessions.clone();
        let (session, initial) = blocking(move || sessions.create(&config)).await?;
        info!(session = %session.id, envs = session.spec.num_envs, terrain = %session.spec.terrain, "session created");
        Ok(Response::new(v1::CreateSessionResponse {
            session_id: session.id.clone(),
            spec: Some(session.spec.clone()),
            initial: Some(initial),
        }))
    }

    async fn reset(
        &self,
        request: Request<v1::ResetRequest>,
    ) -> Result<Response<v1::StepResult>, Status> {
        let request = request.into_inner();
        let session = self.sessions.get(&request.session_id).map_err(status)?;
        let result = on_session(&self.sessions, session, move |s| {
            s.reset(request.mask.as_ref())
        })
        .await?;
        Ok(Response::new(result))
    }

    async fn step(
        &self,
        request: Request<v1::StepRequest>,
    ) -> Result<Response<v1::StepResult>, Status> {
        let request = request.into_inner();
        let session = self.sessions.get(&request.session_id).map_err(status)?;
        let result = on_session(&self.sessions, session, move |s| s.step_unary(&request)).await?;
        Ok(Response::new(result))
    }

    type StepStreamStream = ResultStream;

    async fn step_stream(
        &self,
        request: Request<Streaming<v1::StepRequest>>,
    ) -> Result<Response<Self::StepStreamStream>, Status> {
        if *self.draining.borrow() {
            return Err(draining_status());
        }
        let inbound = request.into_inner();
        let (tx, rx) = mpsc::channel(2);
        tokio::spawn(run_step_stream(
            self.sessions.clone(),
            inbound,
            tx,
            self.draining.clone(),
        ));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn close_session(
        &self,
        request: Request<v1::CloseSessionRequest>,
    ) -> Result<Response<v1::CloseSessionResponse>, Status> {
        let id = request.into_inner().session_id;
        self.sessions.close(&id).map_err(status)?;
        info!(session = %id, "session closed");
        Ok(Response::new(v1::CloseSessionResponse {}))
    }

    async fn evaluate(
        &self,
        request: Request<v1::EvaluateRequest>,
    ) -> Result<Response<v1::EvaluateResponse>, Status> {
        if *self.draining.borrow() {
            return Err(draining_status());
        }
        let permit = self.evaluations.clone().try_acquire_owned().map_err(|_| {
            status(ServiceError::LimitExceeded(format!(
                "the server runs at most {} evaluations at once; try again when one has finished",
                self.sessions.limits().max_concurrent_evaluations
            )))
        })?;
        let request = request.into_inner();
        let ctx = self.evaluation.clone();
        let stop: StopFlag = Arc::new(AtomicBool::new(false));
        // Dropped with this future: a caller that goes away or whose deadline passes (tonic
        // drops the call's future) stops the rollout at its next step.
        let _stop_on_drop = StopOnDrop(stop.clone());
        let mut draining = self.draining.clone();
        let drain_stop = stop.clone();
        let watcher = tokio::spawn(async move {
            if draining.wait_for(|d| *d).await.is_ok() {
                drain_stop.store(true, Ordering::Release);
            }
        });
        let reply = blocking(move || {
            // The slot is held until the rollout really stops, not just until the caller left.
            let _permit = permit;
            evaluate::handle(request, &ctx, &stop)
        })
        .await;
        watcher.abort();
        Ok(Response::new(reply?))
    }
}
