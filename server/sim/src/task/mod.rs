//! The paper's locomotion task: config, observations, labels, rewards, gait clock, randomisation.

mod air_time;
mod config;
mod config_validation;
mod context;
mod frames;
mod gait;
mod observation;
mod randomization;
mod reward_terms;
mod rewards;

pub use air_time::FeetAirTime;
pub use config::{
    BipedStance, ClearanceWeighting, CommandParams, CommandRanges, DEFAULT_TASK_TOML, EnvParams,
    FrictionCombine, GaitParams, InitParams, ModeParams, NoiseParams, RandomizationParams, Range,
    RewardParams, RewardWeights, TaskConfig, UprightCurriculum,
};
pub use context::TaskContext;
pub use frames::{
    angle_from, euler_pitch, heading_direction, heading_hold, heading_yaw, projected_gravity,
    to_heading_frame,
};
pub use gait::{GaitCoefficients, VonMisesCdf, expected_indicators, gait_coefficients};
pub use observation::{
    Field, LABEL_DIM, LABELS, OBS_DIM, OBSERVATION, PRIVILEGED, PRIVILEGED_DIM, noise_amplitudes,
    scales, slice_of, table_dim,
};
pub use randomization::{Randomization, uniform};
pub use reward_terms::{Indicators, RewardTerm, TermGroup};
pub use rewards::*;

/// The task mode x of the paper.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum TaskMode {
    /// x = 1: bipedal locomotion on the front legs.
    Biped = 1,
    /// x = 2: quadrupedal locomotion.
    Quad = 2,
}
