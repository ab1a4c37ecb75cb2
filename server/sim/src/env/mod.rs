//! Batches of envs: per-env episode state, world groups, the parallel batch and its outputs.

mod env_id;
mod env_state;
mod group;
mod layout;
mod observation_rows;
mod output;
mod upright_curriculum;
mod vec_env;

pub use env_id::EnvId;
pub use env_state::{EnvState, sample_command};
pub use group::StageTimes;
pub use layout::{ElementType, SliceLayout, TensorLayout, tensor_layouts};
pub use observation_rows::{write_labels, write_observation};
pub use output::{OutputChunk, StepOutput};
pub use upright_curriculum::{UprightCounts, UprightThreshold};
pub use vec_env::{VecEnv, VecEnvOptions, validate_actions, worker_pool};
