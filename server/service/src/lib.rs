//! unigait-server: the gRPC service over the simulation core (sessions, batched step streams,
//! limits, errors). The in-process `bench` and `probe` commands belong to the binary
//! (`src/main.rs`), not to this API.
#![warn(missing_docs)]

mod convert;
mod error;
mod evaluate;
mod limits;
mod overrides;
mod server;
mod service;
mod session;
mod terrain;

pub use error::ServiceError;
pub use evaluate::EvaluateContext;
pub use limits::{CostCaps, Limits};
pub use server::{
    MIN_TOKEN_LEN, ServeError, ServeOptions, TransportLimits, check_token, is_loopback, serve,
    shutdown_signal,
};
pub use terrain::terrain_for;
