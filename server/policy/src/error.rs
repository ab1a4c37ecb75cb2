//! What can go wrong loading or running a policy.

use thiserror::Error;

/// A policy that cannot be loaded or run.
#[derive(Debug, Error)]
pub enum PolicyError {
    /// The policy file could not be read.
    #[error("cannot read policy file `{path}`: {source}")]
    Io {
        /// The path given.
        path: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// The bytes are not an ONNX model (protobuf decoding failed).
    #[error("not an ONNX model ({len} bytes): {message}")]
    Parse {
        /// Number of bytes given.
        len: usize,
        /// The decoder's complaint.
        message: String,
    },
    /// The graph does not have exactly one (non-initializer) input and one output.
    #[error(
        "the policy graph must have exactly one input and one output, it has {inputs} and {outputs}"
    )]
    Arity {
        /// Graph inputs (initializers excluded).
        inputs: usize,
        /// Graph outputs.
        outputs: usize,
    },
    /// The input is not f32.
    #[error("input `{name}` must be f32 (ONNX FLOAT), it is ONNX element type {elem_type}")]
    InputType {
        /// Input name.
        name: String,
        /// ONNX `TensorProto.DataType` code.
        elem_type: i32,
    },
    /// The input shape does not fit the observation history.
    #[error("input `{name}` has shape {got}, expected {expected}")]
    InputShape {
        /// Input name.
        name: String,
        /// The declared shape (`?` for an unknown dim, names for symbolic dims).
        got: String,
        /// What fits.
        expected: String,
    },
    /// The output shape does not fit the actions.
    #[error("output `{name}` has shape {got}, expected {expected}")]
    OutputShape {
        /// Output name.
        name: String,
        /// The shape tract inferred.
        got: String,
        /// What fits.
        expected: String,
    },
    /// tract could not analyse, type or optimise the graph.
    #[error("cannot build the policy model ({stage}): {message}")]
    Build {
        /// Which stage failed.
        stage: &'static str,
        /// tract's error chain.
        message: String,
    },
    /// The observation batch handed to the policy has the wrong length.
    #[error("observation history has {got} values, expected {expected} ({detail})")]
    Batch {
        /// Values given.
        got: usize,
        /// Values expected.
        expected: usize,
        /// The shape behind `expected`.
        detail: String,
    },
    /// The model is not one a policy may be (a missing graph, negative dims, ...).
    #[error("not a usable policy: {message}")]
    Invalid {
        /// What is wrong.
        message: String,
    },
    /// The graph uses an op outside the policy allow-list.
    #[error(
        "node `{node}` uses op `{op}`, which a policy may not use (an MLP policy needs Gemm/MatMul, activations, Concat, Flatten, Reshape, Slice, Gather, ...)"
    )]
    UnsupportedOp {
        /// The op (with its domain when not the standard one).
        op: String,
        /// The node's name.
        node: String,
    },
    /// Part of the model is over a size limit.
    #[error("the policy's {what} is {size}, over the limit of {limit}")]
    TooLarge {
        /// What was measured.
        what: String,
        /// Its size.
        size: u64,
        /// The limit.
        limit: u64,
    },
    /// Loading or running the policy went over its worker's memory or time limit.
    #[error("{0}")]
    ResourceLimit(String),
    /// The policy worker died on a signal that is not a limit (SIGSEGV, SIGILL, ...): the
    /// model made the ONNX runtime crash, or something killed the worker.
    #[error("{0}")]
    Crashed(String),
    /// The policy worker could not be started or talked to (a server-side failure).
    #[error("policy worker: {0}")]
    Worker(String),
    /// The caller stopped the run (its deadline passed or it went away).
    #[error("{0}")]
    Stopped(String),
    /// Inference failed.
    #[error("policy inference failed: {0}")]
    Run(String),
    /// The policy produced a NaN or infinite action.
    #[error("policy produced a non-finite action {value} (env {env}, joint {joint})")]
    NonFinite {
        /// Env (row) index.
        env: usize,
        /// Action index.
        joint: usize,
        /// The value.
        value: f32,
    },
}
