//! A Rust learner for unigait: PPO with the concurrently trained estimator, the algorithm,
//! hyper-parameters and networks of the Python learner (client-py's `unigait.algorithms`), on
//! burn's Flex CPU backend (chosen by measurement: docs/src/rust-learner.md).

pub mod gae;
pub mod nets;
pub mod ppo;
pub mod rng;
pub mod schedule;
pub mod storage;

/// Errors of the learner.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A tensor's values could not be read back.
    #[error("tensor data: {0}")]
    Data(#[from] burn::tensor::DataError),
    /// The rollout storage refused a step.
    #[error(transparent)]
    Storage(#[from] storage::StorageError),
}

/// The learner's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;
