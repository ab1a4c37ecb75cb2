//! The unigait v1 wire format: code generated from `unigait/v1/unigait.proto`, and helpers to
//! pack and unpack tensors (little-endian values in `bytes`, row-major shape).
#![warn(missing_docs)]

mod codec;
mod tensor;

/// Generated messages and services of package `unigait.v1`.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod v1 {
    tonic::include_proto!("unigait.v1");
    pub use crate::v1_server::simulator_server;

    /// Encoded file descriptor set, for gRPC reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] =
        tonic::include_file_descriptor_set!("unigait_v1_descriptor");
}

/// The server side of package `unigait.v1`, on [`RequestCodec`] (re-exported in [`v1`]).
#[allow(missing_docs, clippy::all, clippy::pedantic)]
mod v1_server {
    include!(concat!(env!("OUT_DIR"), "/server/unigait.v1.rs"));
}

pub use codec::{RequestCodec, RequestDecoder};
pub use tensor::{TensorError, TensorView, f32_tensor, u8_tensor, u32_tensor};

/// The protocol version carried by the package name.
pub const PROTOCOL_VERSION: &str = "v1";
