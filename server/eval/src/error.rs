//! What can go wrong in an evaluation.

use thiserror::Error;
use unigait_policy::PolicyError;
use unigait_sim::SimError;

/// An evaluation that cannot run.
#[derive(Debug, Error)]
pub enum EvalError {
    /// No scenario has this name.
    #[error("unknown scenario `{name}`; known scenarios: {known}")]
    UnknownScenario {
        /// The name asked for.
        name: String,
        /// Every registered name, comma separated.
        known: String,
    },
    /// An option is out of range.
    #[error("invalid evaluation option: {0}")]
    InvalidOption(String),
    /// The policy could not be loaded or run.
    #[error(transparent)]
    Policy(#[from] PolicyError),
    /// The simulation core refused the scenario's config or terrain.
    #[error(transparent)]
    Sim(#[from] SimError),
}
