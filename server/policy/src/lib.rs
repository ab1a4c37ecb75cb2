//! unigait-policy: ONNX locomotion policies run with tract.
//!
//! A policy maps the observation history `[batch, 3, 53]` (o_t, o_{t-1}, o_{t-2}, f32,
//! row-major) to actions `[batch, 12]`. [`OnnxPolicy`] loads an exported graph (bytes or a
//! path), checks its input and output against a [`PolicySpec`], makes the batch dimension
//! symbolic (an exporter such as rsl_rl's may fix it at 1) and runs it batched, through plans
//! optimised for each row count met (built on first use, cached; large batches go in chunks).
//! [`ObsHistory`] keeps the per-env history the policy reads; [`Policy`] is the interface the
//! evaluation runs, so scripted test policies ([`ConstantPolicy`]) fit in as well.
//!
//! Policies from untrusted clients go through [`check_model`] (an op allow-list and size
//! caps) and load and run in a worker process with memory and time limits
//! ([`SandboxedPolicy`]).
#![warn(missing_docs)]

mod checks;
mod elu;
mod error;
mod history;
mod metadata;
mod onnx;
mod policy;
mod sandbox;

pub use checks::{ALLOWED_OPS, ModelLimits, check_model, parse_checked, scan_wire};
pub use error::PolicyError;
pub use history::ObsHistory;
pub use metadata::{PHYSICS_ENGINE_KEY, metadata, trained_engine, with_metadata};
pub use onnx::{InputLayout, OnnxPolicy};
pub use policy::{ConstantPolicy, Policy, PolicySpec};
pub use sandbox::{
    SECCOMP_SELF_TEST_ARG, SandboxLimits, SandboxedPolicy, WORKER_SUBCOMMAND, run_worker,
};
