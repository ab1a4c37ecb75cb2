//! unigait-sim: batched Unitree Go2 environments on rapier3d for the quadrupedal + bipedal
//! locomotion task (one policy, task indicators). Knows nothing of gRPC.
//!
//! Layers: [`robot`] (URDF and model) -> [`physics`] (rapier worlds, PD actuation) ->
//! [`task`] (observations, labels, rewards, randomisation) -> [`env`] (episodes, batching).
#![warn(missing_docs)]

pub mod env;
mod error;
pub mod physics;
pub mod robot;
pub mod task;
pub mod terrain;

pub use error::SimError;

/// The commonly used types.
pub mod prelude {
    pub use crate::SimError;
    pub use crate::env::{StepOutput, VecEnv, VecEnvOptions};
    pub use crate::robot::{NUM_FEET, NUM_JOINTS, RobotModel};
    pub use crate::task::{LABEL_DIM, OBS_DIM, PRIVILEGED_DIM, RewardTerm, TaskConfig, TaskMode};
    pub use crate::terrain::Terrain;
}
