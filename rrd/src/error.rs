//! What can go wrong while serving or sending a recording.

use thiserror::Error;

/// A recording that could not be served or sent.
#[derive(Debug, Error)]
pub enum RrdError {
    /// The viewer could not be reached (bad viewer URL, nothing listening, ...).
    #[error("cannot open the rerun recording: {0}")]
    Open(String),
    /// The recording could not be served (address in use, server not listening, ...).
    #[error("cannot serve the rerun recording on {addr}: {reason}")]
    Serve {
        /// The address asked for.
        addr: String,
        /// What went wrong.
        reason: String,
    },
    /// Bytes that are not a valid `.rrd` recording.
    #[error("not a valid rerun recording: {0}")]
    InvalidRrd(String),
}
