//! What can go wrong while recording.

use thiserror::Error;
use unigait_rrd::RrdError;

/// A recording that could not be made.
#[derive(Debug, Error)]
pub enum RecordError {
    /// The rerun stream could not be created (bad viewer URL, unwritable file, ...).
    #[error("cannot open the rerun recording: {0}")]
    Open(String),
    /// The recording could not be flushed or encoded.
    #[error("cannot finish the rerun recording: {0}")]
    Finish(String),
    /// The recording could not be served (address in use, server not listening, ...).
    #[error("cannot serve the rerun recording on {addr}: {reason}")]
    Serve {
        /// The address asked for.
        addr: String,
        /// What went wrong.
        reason: String,
    },
    /// `finish_serving` on a recorder that does not serve.
    #[error("this recording is not served (make it with Recorder::serve)")]
    NotServed,
    /// Bytes that are not a valid `.rrd` recording.
    #[error("not a valid rerun recording: {0}")]
    InvalidRrd(String),
    /// The env index is not in the batch.
    #[error("env {index} is not in the batch of {num_envs}")]
    EnvIndex {
        /// The index asked for.
        index: usize,
        /// Envs in the batch.
        num_envs: usize,
    },
}

/// Serving and sending (`unigait-rrd`) fail the same ways a recording does.
impl From<RrdError> for RecordError {
    fn from(e: RrdError) -> Self {
        match e {
            RrdError::Open(reason) => Self::Open(reason),
            RrdError::Serve { addr, reason } => Self::Serve { addr, reason },
            RrdError::InvalidRrd(reason) => Self::InvalidRrd(reason),
        }
    }
}

/// A stream that could not be opened, as a [`RecordError`].
pub(crate) fn open_err(e: impl std::fmt::Display) -> RecordError {
    RecordError::Open(e.to_string())
}

/// A log or flush that failed, as a [`RecordError`].
pub(crate) fn log_err(e: impl std::fmt::Display) -> RecordError {
    RecordError::Finish(e.to_string())
}
