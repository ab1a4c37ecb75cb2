//! Entity paths of a recording.

/// Root of the 3D scene (Z up).
pub const WORLD: &str = "world";
/// Parent of the followed env's bodies: `world/robot/<body>`.
pub const ROBOT: &str = "world/robot";
/// The terrain mesh around the followed env.
pub const TERRAIN: &str = "world/terrain";
/// Feet of the followed env, coloured by contact.
pub const FEET: &str = "world/feet";
/// Commanded velocity (world frame) as an arrow from the base.
pub const COMMAND: &str = "world/command";
/// Measured base velocity as an arrow from the base.
pub const VELOCITY: &str = "world/velocity";
/// Parent of the other recorded envs: `world/envs/<index>/{robot/<body>,feet,terrain}`.
pub const OTHER_ENVS: &str = "world/envs";
/// Total reward.
pub const REWARD_TOTAL: &str = "reward/total";
/// Parent of the active mode's task terms, `reward/active/<term>`: each logged only while
/// its mode is the current one (the same values as `reward/<term>`).
pub const REWARD_ACTIVE: &str = "reward/active";
/// Task mode (1 biped, 2 quad).
pub const MODE: &str = "mode";
/// The gait diagram: `gait/<foot>` (stance / swing) and `gait/task_mode` (quad / biped) as
/// state lanes, logged at each change.
pub const GAIT: &str = "gait";
/// Mode lane of the gait diagram (named to sort below the feet, which read top down).
pub const GAIT_MODE: &str = "gait/task_mode";
/// The followed env's mode changes and episode ends.
pub const EVENTS: &str = "events";
/// Per recorded env: falls, head hits, time-outs, mode switches and the final outcome,
/// `outcome/env<index>`.
pub const OUTCOME: &str = "outcome";

/// Entity of body `name` of the followed env.
pub fn body(name: &str) -> String {
    format!("{ROBOT}/{name}")
}

/// Series of reward term `term`.
pub fn reward(term: &str) -> String {
    format!("reward/{term}")
}

/// Series of task term `term` while its mode is active.
pub fn reward_active(term: &str) -> String {
    format!("{REWARD_ACTIVE}/{term}")
}

/// Gait lane of foot `foot` (`FL`, `FR`, `RL`, `RR`).
pub fn gait(foot: &str) -> String {
    format!("{GAIT}/{foot}")
}

/// Subtree of another recorded env (not the followed one).
pub fn other_env(index: usize) -> String {
    format!("{OTHER_ENVS}/{index}")
}

/// Outcome events of recorded env `index`.
pub fn outcome(index: usize) -> String {
    format!("{OUTCOME}/env{index}")
}
