//! Service errors and their one mapping to gRPC status codes.

use thiserror::Error;
use tonic::Status;
use unigait_proto::TensorError;
use unigait_sim::SimError;

/// What can go wrong in a request.
#[derive(Debug, Error)]
pub enum ServiceError {
    /// The session id is unknown (never created, closed, or expired).
    #[error("no session `{0}` (closed, expired or never created)")]
    UnknownSession(String),
    /// A request value is wrong.
    #[error("{0}")]
    InvalidArgument(String),
    /// The simulation core rejected the request.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// A tensor does not hold what its header says.
    #[error(transparent)]
    Tensor(#[from] TensorError),
    /// A server limit would be exceeded.
    #[error("{0}")]
    LimitExceeded(String),
    /// The request conflicts with the session's state (e.g. a second step stream).
    #[error("{0}")]
    Precondition(String),
    /// A bug or an unexpected failure on the server side.
    #[error("internal error: {0}")]
    Internal(String),
}

impl From<ServiceError> for Status {
    fn from(e: ServiceError) -> Self {
        let message = e.to_string();
        match e {
            ServiceError::UnknownSession(_) => Status::not_found(message),
            ServiceError::InvalidArgument(_) | ServiceError::Tensor(_) => {
                Status::invalid_argument(message)
            }
            ServiceError::Sim(sim) => match sim {
                SimError::Io { .. } => Status::internal(message),
                SimError::Urdf(_)
                | SimError::Robot(_)
                | SimError::InvalidConfig { .. }
                | SimError::ConfigSyntax(_)
                | SimError::Shape { .. }
                | SimError::NonFinite { .. } => Status::invalid_argument(message),
            },
            ServiceError::LimitExceeded(_) => Status::resource_exhausted(message),
            ServiceError::Precondition(_) => Status::failed_precondition(message),
            ServiceError::Internal(_) => Status::internal(message),
        }
    }
}
