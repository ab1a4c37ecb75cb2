//! unigait-sim: batched Unitree Go2 environments on rapier3d for the quadrupedal + bipedal
//! locomotion task (one policy, task indicators). Knows nothing of gRPC.
#![warn(missing_docs)]

mod error;
pub mod physics;
pub mod robot;

pub use error::SimError;
