//! unigait-server: the gRPC service over the simulation core (sessions, batched step streams,
//! limits, errors) and the in-process benchmark.
#![warn(missing_docs)]

pub mod bench;
mod convert;
mod error;
mod evaluate;
mod limits;
pub mod probe;
mod server;
mod service;
mod session;
mod terrain;

pub use error::ServiceError;
pub use evaluate::EvaluateContext;
pub use limits::Limits;
pub use server::{ServeError, ServeOptions, is_loopback, serve, shutdown_signal};
