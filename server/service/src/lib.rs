//! unigait-server: the gRPC service over the simulation core (sessions, batched step streams,
//! limits, errors) and the in-process benchmark.
#![warn(missing_docs)]

pub mod bench;
mod convert;
mod error;
mod evaluate;
mod limits;
mod overrides;
pub mod probe;
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
