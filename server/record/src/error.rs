//! What can go wrong while recording.

use thiserror::Error;

/// A recording that could not be made.
#[derive(Debug, Error)]
pub enum RecordError {
    /// The rerun stream could not be created (bad viewer URL, unwritable file, ...).
    #[error("cannot open the rerun recording: {0}")]
    Open(String),
    /// The recording could not be flushed or encoded.
    #[error("cannot finish the rerun recording: {0}")]
    Finish(String),
    /// The env index is not in the batch.
    #[error("env {index} is not in the batch of {num_envs}")]
    EnvIndex {
        /// The index asked for.
        index: usize,
        /// Envs in the batch.
        num_envs: usize,
    },
}
