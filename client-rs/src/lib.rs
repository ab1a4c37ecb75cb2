//! unigait-client: an async Rust client for the unigait v1 service (sessions, step streams,
//! typed specs with slices by name) and a compliance suite any server of the protocol must pass.
#![warn(missing_docs)]

mod client;
pub mod compliance;
mod error;
pub mod eval;

pub use client::{Client, MAX_MESSAGE_BYTES, Session, Spec, Step, StepStream};
pub use error::ClientError;
pub use unigait_proto::v1;
