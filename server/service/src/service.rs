//! The gRPC handlers: validate, convert, call the core on a blocking thread, convert back.

use std::pin::Pin;
use std::sync::Arc;

use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::{Stream, StreamExt};
use tonic::{Request, Response, Status, Streaming};
use tracing::{info, warn};
use unigait_proto::v1::{self, simulator_server::Simulator};

use crate::error::ServiceError;
use crate::evaluate::{self, EvaluateContext};
use crate::session::Sessions;

/// The Simulator service.
#[derive(Clone)]
pub struct SimulatorService {
    sessions: Arc<Sessions>,
    evaluation: Arc<EvaluateContext>,
}

impl SimulatorService {
    /// A service over `sessions`, evaluating policies with `evaluation`.
    pub fn new(sessions: Arc<Sessions>, evaluation: Arc<EvaluateContext>) -> Self {
        Self {
            sessions,
            evaluation,
        }
    }
}

/// Run blocking work (env building and stepping) off the async runtime's threads.
async fn blocking<T: Send + 'static>(
    work: impl FnOnce() -> Result<T, ServiceError> + Send + 'static,
) -> Result<T, Status> {
    tokio::task::spawn_blocking(work)
        .await
        .map_err(|e| Status::internal(format!("worker failed: {e}")))?
        .map_err(Status::from)
}

/// Serve one step stream: the first request names the session; each request gets one reply.
/// Any error ends the stream with its status. A client that vanishes mid-stream loses its
/// session.
async fn run_step_stream(
    sessions: Arc<Sessions>,
    mut inbound: Streaming<v1::StepRequest>,
    tx: mpsc::Sender<Result<v1::StepResult, Status>>,
) {
    let first = match inbound.next().await {
        Some(Ok(first)) => first,
        Some(Err(_)) | None => return,
    };
    let session = match sessions
        .get(&first.session_id)
        .and_then(|s| s.open_stream().map(|g| (s, g)))
    {
        Ok(found) => found,
        Err(e) => {
            let _ = tx.send(Err(e.into())).await;
            return;
        }
    };
    let (session, _guard) = session;
    let mut next = Some(Ok(first));
    while let Some(item) = next.take() {
        let request = match item {
            Ok(r) => r,
            Err(status) => {
                warn!(session = %session.id, %status, "step stream broken; closing its session");
                let _ = sessions.close(&session.id);
                return;
            }
        };
        if !request.session_id.is_empty() && request.session_id != session.id {
            let message = format!(
                "this stream belongs to session `{}`, not `{}`",
                session.id, request.session_id
            );
            let _ = tx.send(Err(Status::invalid_argument(message))).await;
            return;
        }
        let s = session.clone();
        let result = blocking(move || s.step(&request)).await;
        let failed = result.is_err();
        if tx.send(result).await.is_err() {
            warn!(session = %session.id, "client stopped reading; closing its session");
            let _ = sessions.close(&session.id);
            return;
        }
        if failed {
            return;
        }
        next = inbound.next().await;
    }
}

type ResultStream = Pin<Box<dyn Stream<Item = Result<v1::StepResult, Status>> + Send>>;

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
        }))
    }

    async fn create_session(
        &self,
        request: Request<v1::CreateSessionRequest>,
    ) -> Result<Response<v1::CreateSessionResponse>, Status> {
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
        let session = self.sessions.get(&request.session_id)?;
        let result = blocking(move || session.reset(request.mask.as_ref())).await?;
        Ok(Response::new(result))
    }

    async fn step(
        &self,
        request: Request<v1::StepRequest>,
    ) -> Result<Response<v1::StepResult>, Status> {
        let request = request.into_inner();
        let session = self.sessions.get(&request.session_id)?;
        let result = blocking(move || session.step(&request)).await?;
        Ok(Response::new(result))
    }

    type StepStreamStream = ResultStream;

    async fn step_stream(
        &self,
        request: Request<Streaming<v1::StepRequest>>,
    ) -> Result<Response<Self::StepStreamStream>, Status> {
        let inbound = request.into_inner();
        let (tx, rx) = mpsc::channel(2);
        tokio::spawn(run_step_stream(self.sessions.clone(), inbound, tx));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn close_session(
        &self,
        request: Request<v1::CloseSessionRequest>,
    ) -> Result<Response<v1::CloseSessionResponse>, Status> {
        let id = request.into_inner().session_id;
        self.sessions.close(&id)?;
        info!(session = %id, "session closed");
        Ok(Response::new(v1::CloseSessionResponse {}))
    }

    async fn evaluate(
        &self,
        request: Request<v1::EvaluateRequest>,
    ) -> Result<Response<v1::EvaluateResponse>, Status> {
        let request = request.into_inner();
        let ctx = self.evaluation.clone();
        let reply = blocking(move || evaluate::handle(request, &ctx)).await?;
        Ok(Response::new(reply))
    }
}
