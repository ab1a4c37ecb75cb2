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
    /// A session broke on a server bug (a panic while stepping) and was closed.
    #[error("session `{0}` broke on a server error and was closed; create a new one")]
    Broken(String),
    /// The server is shutting down.
    #[error("{0}")]
    Unavailable(String),
    /// The call ran past its deadline or its caller went away.
    #[error("{0}")]
    Deadline(String),
    /// A bug or an unexpected failure on the server side.
    #[error("internal error: {0}")]
    Internal(String),
}

/// Longest status message sent: messages may echo client strings (names, TOML, shapes).
pub const MAX_STATUS_MESSAGE_CHARS: usize = 400;

/// `message` cut to [`MAX_STATUS_MESSAGE_CHARS`] characters, marked when cut.
pub fn cut_message(message: &str) -> String {
    match message.char_indices().nth(MAX_STATUS_MESSAGE_CHARS) {
        None => message.to_string(),
        Some((at, _)) => format!(
            "{}... ({} more bytes cut)",
            &message[..at],
            message.len() - at
        ),
    }
}

impl From<ServiceError> for Status {
    fn from(e: ServiceError) -> Self {
        let message = cut_message(&e.to_string());
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
            ServiceError::Broken(_) | ServiceError::Internal(_) => Status::internal(message),
            ServiceError::Unavailable(_) => Status::unavailable(message),
            ServiceError::Deadline(_) => Status::deadline_exceeded(message),
        }
    }
}
