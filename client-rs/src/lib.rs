//! unigait-client: an async Rust client for the unigait v1 service (sessions, step streams,
//! typed specs with slices by name) and a compliance suite any server of the protocol must pass.
//!
//! The default `cli` feature adds what the `unigait` command line needs (the `eval` module, the
//! recording replay through rerun); `default-features = false` keeps the library lean.
#![warn(missing_docs)]

mod client;
pub mod compliance;
mod error;
#[cfg(feature = "cli")]
pub mod eval;

pub use client::{Client, MAX_MESSAGE_BYTES, Session, Spec, Step, StepStream};
pub use error::ClientError;
pub use unigait_proto::v1;
