//! Client errors.

use thiserror::Error;

/// What a client call can fail with.
#[derive(Debug, Error)]
pub enum ClientError {
    /// The server could not be reached.
    #[error("cannot connect to {addr}: {source}")]
    Connect {
        /// Address tried.
        addr: String,
        /// Transport error.
        source: tonic::transport::Error,
    },
    /// The address is malformed.
    #[error("bad server address `{0}`")]
    Address(String),
    /// The server answered with an error status.
    #[error("{}: {}", .0.code(), .0.message())]
    Status(#[from] tonic::Status),
    /// A reply tensor does not match its header or the spec.
    #[error(transparent)]
    Tensor(#[from] unigait_proto::TensorError),
    /// A reply lacks a field the protocol requires.
    #[error("the server's reply lacks `{0}`")]
    Missing(&'static str),
    /// The step stream ended.
    #[error("the step stream ended")]
    StreamClosed,
}

impl ClientError {
    /// The gRPC status code, if the server sent one.
    pub fn code(&self) -> Option<tonic::Code> {
        match self {
            ClientError::Status(s) => Some(s.code()),
            _ => None,
        }
    }
}
