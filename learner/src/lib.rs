//! A Rust learner for unigait: PPO with the concurrently trained estimator, the algorithm,
//! hyper-parameters and networks of the Python learner (client-py's `unigait.algorithms`), on
//! burn's Flex CPU backend (chosen by measurement: docs/src/rust-learner.md).
//!
//! It trains over the protocol with the Rust client (`unigait-client`) and never links the
//! simulator: [`run`] reads a recipe of `assets/recipes/` ([`recipe`]), opens a session per
//! stage and trains it ([`learner`]), writing the progress CSV ([`log`]), checkpoints
//! ([`checkpoint`]) and the fused ONNX policy the server serves ([`onnx`]).

pub mod checkpoint;
pub mod config;
pub mod env;
pub mod gae;
pub mod learner;
pub mod log;
pub mod milestone;
pub mod mirror;
pub mod nets;
pub mod onnx;
pub mod pass_chance;
pub mod ppo;
pub mod recipe;
pub mod rng;
pub mod run;
pub mod schedule;
pub mod server;
pub mod stats;
pub mod storage;
pub mod tensorboard;

/// Errors of the learner.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A tensor's values could not be read back.
    #[error("tensor data: {0}")]
    Data(#[from] burn::tensor::DataError),
    /// The rollout storage refused a step.
    #[error(transparent)]
    Storage(#[from] storage::StorageError),
    /// A call to the server failed.
    #[error(transparent)]
    Client(#[from] unigait_client::ClientError),
    /// A reply tensor does not decode.
    #[error(transparent)]
    Tensor(#[from] unigait_proto::TensorError),
    /// The session's spec or a reply does not fit the learner.
    #[error("{0}")]
    Spec(String),
    /// An optimiser record could not be written or read.
    #[error("optimiser record: {0}")]
    Record(String),
    /// A checkpoint that cannot be used.
    #[error("checkpoint: {0}")]
    Checkpoint(String),
    /// A config that cannot be used.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    /// A recipe that cannot be read.
    #[error(transparent)]
    Recipe(#[from] recipe::RecipeError),
    /// A run that cannot start or go on.
    #[error("{0}")]
    Run(String),
    /// A rollout or update with a non-finite value: nothing of the iteration is saved, and the
    /// run resumes cleanly from its last checkpoint (decision record 0031).
    #[error("{0}")]
    NonFinite(String),
    /// A file could not be read or written.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// The learner's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;
