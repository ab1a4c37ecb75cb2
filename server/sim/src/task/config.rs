//! The task configuration: every number of the locomotion task, with the paper's values (and our
//! documented decisions) as defaults. Plain data: derived values are methods, nothing is mutated
//! after loading.

use serde::{Deserialize, Serialize};

use super::reward_terms::RewardTerm;
use crate::error::SimError;
use crate::physics::PhysicsParams;
use crate::terrain::LevelRule;

/// A closed range `[lo, hi]` drawn uniformly.
pub type Range = [f32; 2];

/// Everything that defines a batch of envs except the robot and the terrain.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaskConfig {
    /// Physics numerics.
    pub physics: PhysicsParams,
    /// Episode, control and batching.
    pub env: EnvParams,
    /// Velocity commands.
    pub commands: CommandParams,
    /// Task modes (biped / quad).
    pub modes: ModeParams,
    /// The gait clock and the periodic reward.
    pub gait: GaitParams,
    /// Initial state distribution (Table IV).
    pub init: InitParams,
    /// Domain randomisation (Table V).
    pub randomization: RandomizationParams,
    /// Reward weights, targets and switches (Table II).
    pub rewards: RewardParams,
    /// Observation noise.
    pub noise: NoiseParams,
    /// When the terrain curriculum moves an env up or down a level (a curriculum terrain only).
    pub terrain_curriculum: LevelRule,
}

/// Episode, control and batching.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvParams {
    /// Episode length (s). Default 18 (900 policy steps).
    pub episode_length_s: f32,
    /// Physics steps per policy step. Default 4 (policy at 50 Hz).
    pub decimation: usize,
    /// Joint target = default + action_scale * action. Default 0.25.
    pub action_scale: f32,
    /// Actions are clipped to +-this. Default 100.
    pub clip_actions: f32,
    /// Observations are clipped to +-this. Default 100.
    pub clip_observations: f32,
    /// Envs per physics world. Default 32. Fixed by config, never by thread count, so results do
    /// not depend on how many threads step them.
    pub envs_per_world: usize,
    /// Spread the first episodes' start times uniformly over the episode (legged_gym's
    /// `init_at_random_ep_len`), so resets do not come in waves. Default true.
    pub random_initial_episode_step: bool,
}

impl Default for EnvParams {
    fn default() -> Self {
        Self {
            episode_length_s: 18.0,
            decimation: 4,
            action_scale: 0.25,
            clip_actions: 100.0,
            clip_observations: 100.0,
            envs_per_world: 32,
            random_initial_episode_step: true,
        }
    }
}

/// Command ranges for one task mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CommandRanges {
    /// Forward speed in the heading frame (m/s).
    pub vx: Range,
    /// Lateral speed in the heading frame (m/s).
    pub vy: Range,
    /// Yaw rate (rad/s).
    pub wz: Range,
}

/// Velocity commands.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CommandParams {
    /// Commands are redrawn every this many seconds and at reset. Default 10.
    pub resampling_time_s: f32,
    /// Ranges in quad mode. Default vx [-1, 1.5], vy [-0.5, 0.5], wz [-1, 1].
    pub quad: CommandRanges,
    /// Ranges in biped mode. Default vx [-0.5, 0.5], vy [-0.3, 0.3], wz [-0.5, 0.5].
    pub biped: CommandRanges,
    /// A command component whose magnitude is below this is set to 0. Default 0.1.
    pub zero_below: f32,
    /// Share of command draws that hold a heading instead of a yaw rate: such a draw also takes
    /// a heading uniform in [-pi, pi), and every step its yaw-rate command is `heading_gain`
    /// times the turn to that heading, within the mode's wz range (legged_gym's
    /// `heading_command`; decision record 0042). Default 0: the paper's yaw-rate commands.
    pub heading_share: f32,
    /// Yaw-rate command per radian off the held heading (1/s). Default 1, as the traversals
    /// steer (decision record 0032).
    pub heading_gain: f32,
}

impl Default for CommandParams {
    fn default() -> Self {
        Self {
            resampling_time_s: 10.0,
            quad: CommandRanges {
                vx: [-1.0, 1.5],
                vy: [-0.5, 0.5],
                wz: [-1.0, 1.0],
            },
            biped: CommandRanges {
                vx: [-0.5, 0.5],
                vy: [-0.3, 0.3],
                wz: [-0.5, 0.5],
            },
            zero_below: 0.1,
            heading_share: 0.0,
            heading_gain: 1.0,
        }
    }
}

/// Task modes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModeParams {
    /// The mode is redrawn every this many seconds and at reset. Default 6.
    pub resampling_time_s: f32,
    /// Probability of biped mode at each draw. Default 0.5.
    pub biped_probability: f32,
}

impl Default for ModeParams {
    fn default() -> Self {
        Self {
            resampling_time_s: 6.0,
            biped_probability: 0.5,
        }
    }
}

/// Gait clock and periodic reward.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GaitParams {
    /// Gait period T_gait (s). Default 0.45.
    pub period_s: f32,
    /// Swing share of each foot's cycle. Default 0.4.
    pub swing_ratio: f32,
    /// Phase offsets theta per foot (FL, FR, RL, RR) in quad mode. Default trot [0, 0.5, 0.5, 0].
    pub offsets_quad: [f32; 4],
    /// Phase offsets in biped mode (rear entries unused). Default [0, 0.5, 0, 0].
    pub offsets_biped: [f32; 4],
    /// Von Mises concentration of the phase boundaries (1/rad^2). Default 20.
    pub kappa: f32,
    /// Contact force that counts as one unit of gait violation (N). Default 100 (legged_gym's
    /// `max_contact_force`); a swing foot carrying half a stance load costs about 0.4.
    pub force_scale: f32,
    /// Foot speed that counts as one unit of gait violation (m/s). Default 1.
    pub speed_scale: f32,
}

impl Default for GaitParams {
    fn default() -> Self {
        Self {
            period_s: 0.45,
            swing_ratio: 0.4,
            offsets_quad: [0.0, 0.5, 0.5, 0.0],
            offsets_biped: [0.0, 0.5, 0.0, 0.0],
            kappa: 20.0,
            force_scale: 100.0,
            speed_scale: 1.0,
        }
    }
}

/// Initial state (Table IV). Joint ranges are offsets from the default pose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InitParams {
    /// Hip offset (rad). Default [-0.2, 0.2].
    pub hip: Range,
    /// Thigh offset (rad). Default [-1.0, 1.0].
    pub thigh: Range,
    /// Calf offset (rad). Default [-0.6, 0.6].
    pub calf: Range,
    /// Base linear velocity per axis (m/s). Default [-0.5, 0.5].
    pub linvel: Range,
    /// Base angular velocity per axis (rad/s). Default [-0.5, 0.5].
    pub angvel: Range,
    /// Base pitch, positive nose down (rad). Default [0, 1.3].
    pub pitch: Range,
    /// Base yaw (rad). Default [0, 0] (legged_gym does not turn robots at reset).
    pub yaw: Range,
    /// Clearance between the lowest robot part and the terrain at spawn (m). Default 0.02.
    pub spawn_clearance: f32,
}

impl Default for InitParams {
    fn default() -> Self {
        Self {
            hip: [-0.2, 0.2],
            thigh: [-1.0, 1.0],
            calf: [-0.6, 0.6],
            linvel: [-0.5, 0.5],
            angvel: [-0.5, 0.5],
            pitch: [0.0, 1.3],
            yaw: [0.0, 0.0],
            spawn_clearance: 0.02,
        }
    }
}

/// Domain randomisation (Table V), drawn per env at reset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RandomizationParams {
    /// Draw the values below (else the robot's nominal values). Default true.
    pub enabled: bool,
    /// The robot's friction coefficient (Table V). Default [0.2, 1.6]. The contact's
    /// coefficient combines it with `ground_friction` by `friction_combine`.
    pub friction: Range,
    /// The terrain's friction coefficient. Default 1, legged_gym's terrain.
    pub ground_friction: f32,
    /// How a contact's friction comes from the robot's and the ground's. Default `"average"`,
    /// PhysX's rule in the paper's simulator (decision record 0034).
    pub friction_combine: FrictionCombine,
    /// Payload on the trunk (kg). Default [-1, 1].
    pub payload: Range,
    /// Trunk centre-of-mass shift per axis (m). Default [-0.01, 0.01].
    pub com_offset: Range,
    /// Viscous joint damping (N m s/rad). Default [0.25, 0.35].
    pub joint_damping: Range,
    /// Coulomb joint friction torque (N m). Default [0.005, 0.01].
    pub joint_friction: Range,
    /// Rotor inertia on each joint axis (kg m^2). Default [0.015, 0.025].
    pub armature: Range,
    /// Factor on kp. Default [0.8, 1.2].
    pub kp_factor: Range,
    /// Factor on kd. Default [0.8, 1.2].
    pub kd_factor: Range,
    /// Push every this many seconds (0 = never). Default 10.
    pub push_interval_s: f32,
    /// The base's xy velocity is shifted by U(-v, v) per axis (m/s). Default 1.
    pub push_velocity: f32,
}

impl Default for RandomizationParams {
    fn default() -> Self {
        Self {
            enabled: true,
            friction: [0.2, 1.6],
            ground_friction: 1.0,
            friction_combine: FrictionCombine::Average,
            payload: [-1.0, 1.0],
            com_offset: [-0.01, 0.01],
            joint_damping: [0.25, 0.35],
            joint_friction: [0.005, 0.01],
            armature: [0.015, 0.025],
            kp_factor: [0.8, 1.2],
            kd_factor: [0.8, 1.2],
            push_interval_s: 10.0,
            push_velocity: 1.0,
        }
    }
}

/// How a contact's friction coefficient comes from the robot's and the ground's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrictionCombine {
    /// Their mean, PhysX's default: Isaac Gym's robots drawn from [0.2, 1.6] on its terrain's
    /// 1.0 touch it at [0.6, 1.3].
    #[default]
    Average,
    /// Their product: with the ground's 1.0 the robot's coefficient is the contact's (the rule
    /// before decision record 0034).
    Multiply,
}

impl FrictionCombine {
    /// The contact's coefficient for a robot's `robot` and the ground's `ground`.
    pub fn apply(self, robot: f32, ground: f32) -> f32 {
        match self {
            FrictionCombine::Average => 0.5 * (robot + ground),
            FrictionCombine::Multiply => robot * ground,
        }
    }
}

/// What weighs a foot's clearance error (h - p_des)^2 (decision record 0039).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClearanceWeighting {
    /// The foot's horizontal speed |v_xy| (Eq. 4): a swing that is low but quick costs little,
    /// because exp(-k error) averaged over a swing pays most when the error comes in bursts.
    #[default]
    FootSpeed,
    /// The gait clock's expected swing indicator of the foot (the periodic gait reward's force
    /// weight): the foot is asked to be up through its whole swing window, at any speed.
    SwingPhase,
}

/// Which legs carry the biped stance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BipedStance {
    /// Front legs carry the body, pitched nose down (the paper's Table II and Eq. 5-9).
    Front,
}

/// Reward weights, targets and switches.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RewardParams {
    /// Weight per term (Table II), before the multiplication by the policy dt. Keys are
    /// [`RewardTerm::name`]s; a missing key keeps its default.
    pub weights: RewardWeights,
    /// Quad base height target h*quad (m). Default 0.30.
    pub base_height_quad: f32,
    /// Biped base height target h*bi (m). Default 0.50: in the front-leg stance the trunk origin
    /// sits about one trunk half-length (0.19 m) above the hips, and the front legs, almost
    /// straight, hold the hips about 0.33 m up.
    pub base_height_biped: f32,
    /// Biped orientation target (roll proxy, pitch) (rad). Default (0, pi/2).
    pub biped_angle_target: [f32; 2],
    /// Pitch above which the upright indicator fires (rad). Default 1.4.
    pub upright_pitch: f32,
    /// Desired swing foot height above the highest terrain within 2 cm (m). Default 0.08.
    pub foot_clearance_target: f32,
    /// The biped's own clearance target (m); unset (the default), the biped's term uses
    /// `foot_clearance_target` as the quad's does (decision record 0041).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub biped_foot_clearance_target: Option<f32>,
    /// Radius of the terrain sampling around each foot (m). Default 0.02.
    pub foot_clearance_radius: f32,
    /// k of the foot clearance reward exp(-k error). Default 100 (Eq. 4 and 6); a steeper
    /// kernel makes a low swing cost more (decision record 0025).
    pub foot_clearance_sharpness: f32,
    /// What weighs each foot's clearance error: its horizontal speed (Eq. 4, the default) or
    /// its expected swing indicator from the gait clock (decision record 0039).
    pub foot_clearance_weighting: ClearanceWeighting,
    /// k of `quad_tracking_lin_vel`, exp(-k |v*_xy - v_xy|^2). Default 4 (the paper's).
    pub quad_tracking_lin_vel_sharpness: f32,
    /// k of `biped_tracking_lin_vel`. Default 4; a steeper kernel prices a shortfall the default
    /// pays 94% for at 0.12 m/s (the terrain recipe's stage 13).
    pub biped_tracking_lin_vel_sharpness: f32,
    /// Sideways reach per radian of hip abduction (m/rad) at which `biped_sideways_reach` pays
    /// in full. Default 0.1: a foot about 8 cm ahead of or behind its hip (0.30 on four legs at
    /// the default pose).
    pub sideways_reach_target: f32,
    /// Soft joint limits as a share of the URDF range (legged_gym `soft_dof_pos_limit`). Default 0.9.
    pub soft_joint_limit: f32,
    /// Contact force above which a foot counts as touching (N). Default 1.
    pub contact_threshold: f32,
    /// Clip the sum of all terms but termination at zero (legged_gym `only_positive_rewards`).
    /// Default true.
    pub only_positive: bool,
    /// Mask quad and biped terms with the task indicators. false = the paper's "w/o task
    /// indicator" ablation (I_1 = I_2 = 1). Default true.
    pub task_indicators: bool,
    /// Gate biped tracking and gait terms with the upright indicator. false = "w/o upright
    /// indicator" (I_up = 1). Default true.
    pub upright_indicator: bool,
    /// Legs of the biped stance. Default front.
    pub biped_stance: BipedStance,
    /// A curriculum on the upright indicator's threshold. Off by default (the paper's fixed
    /// `upright_pitch`).
    pub upright_curriculum: UprightCurriculum,
}

/// A curriculum on the upright indicator's threshold: I_up fires above a threshold that starts
/// at `start` and rises by `step` towards `upright_pitch` whenever, over the last
/// `window_steps` biped-mode env-steps of the batch, at least `promote_share` of them were above
/// it. It never falls and never passes `upright_pitch`, so from there on I_up is the paper's.
///
/// Why: with the paper's fixed 1.4 rad a CPU-sized run finds the head rest (head and front feet
/// down, pitch ~1.0) and stays there; the gated tracking and gait terms, more than half of what
/// the biped mode pays, are then seen in ~0.1% of its steps. A threshold just above where the
/// robots are pays them for a little more pitch each time
/// (docs/src/decisions/0008-upright-curriculum.md).
/// One threshold for the whole batch, so that the critic sees one reward function at a time, as
/// with legged_gym's command curriculum.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct UprightCurriculum {
    /// Use it. Default false.
    pub enabled: bool,
    /// Threshold at the start of a session (rad). Default 1.0.
    pub start: f32,
    /// Rise per promotion (rad). Default 0.05.
    pub step: f32,
    /// Share of the judged biped-mode env-steps above the threshold that promotes it.
    /// Default 0.5.
    pub promote_share: f32,
    /// Biped-mode env-steps per judgement (over the whole batch). Default 20,000, about three
    /// iterations of a 512-env x 24-step rollout with half the envs in biped mode.
    pub window_steps: u32,
}

impl Default for UprightCurriculum {
    fn default() -> Self {
        Self {
            enabled: false,
            start: 1.0,
            step: 0.05,
            promote_share: 0.5,
            window_steps: 20_000,
        }
    }
}

impl Default for RewardParams {
    fn default() -> Self {
        Self {
            weights: RewardWeights::default(),
            base_height_quad: 0.30,
            base_height_biped: 0.50,
            biped_angle_target: [0.0, std::f32::consts::FRAC_PI_2],
            upright_pitch: 1.4,
            foot_clearance_target: 0.08,
            biped_foot_clearance_target: None,
            foot_clearance_radius: 0.02,
            foot_clearance_sharpness: 100.0,
            foot_clearance_weighting: ClearanceWeighting::FootSpeed,
            quad_tracking_lin_vel_sharpness: 4.0,
            biped_tracking_lin_vel_sharpness: 4.0,
            sideways_reach_target: 0.1,
            soft_joint_limit: 0.9,
            contact_threshold: 1.0,
            only_positive: true,
            task_indicators: true,
            upright_indicator: true,
            biped_stance: BipedStance::Front,
            upright_curriculum: UprightCurriculum::default(),
        }
    }
}

/// Reward weights indexed by [`RewardTerm`].
#[derive(Clone, Debug, PartialEq)]
pub struct RewardWeights(pub [f32; RewardTerm::COUNT]);

impl Default for RewardWeights {
    fn default() -> Self {
        Self(std::array::from_fn(|i| RewardTerm::ALL[i].default_weight()))
    }
}

impl Serialize for RewardWeights {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = s.serialize_map(Some(RewardTerm::COUNT))?;
        for term in RewardTerm::ALL {
            map.serialize_entry(term.name(), &self.0[term as usize])?;
        }
        map.end()
    }
}

impl<'de> Deserialize<'de> for RewardWeights {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let map = std::collections::BTreeMap::<String, f32>::deserialize(d)?;
        let mut weights = RewardWeights::default();
        for (name, value) in map {
            let term = RewardTerm::from_name(&name).ok_or_else(|| {
                serde::de::Error::custom(format!(
                    "unknown reward term `{name}`; known terms: {}",
                    RewardTerm::ALL.map(|t| t.name()).join(", ")
                ))
            })?;
            weights.0[term as usize] = value;
        }
        Ok(weights)
    }
}

/// Observation noise (uniform, legged_gym style: value += U(-1, 1) * level * scale * n).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseParams {
    /// Add noise. Default true.
    pub enabled: bool,
    /// Global multiplier. Default 1.
    pub level: f32,
}

impl Default for NoiseParams {
    fn default() -> Self {
        Self {
            enabled: true,
            level: 1.0,
        }
    }
}

impl TaskConfig {
    /// The embedded default config (`assets/task.toml`).
    pub fn embedded_default() -> Self {
        Self::from_toml(DEFAULT_TASK_TOML).expect("the embedded task config is valid")
    }

    /// Parse and validate a TOML document; missing fields keep their defaults.
    pub fn from_toml(text: &str) -> Result<Self, SimError> {
        let config: Self =
            toml::from_str(text).map_err(|e| SimError::ConfigSyntax(e.to_string()))?;
        config.validate()?;
        Ok(config)
    }

    /// Apply a TOML override document on top of this config (keys not named keep their value).
    pub fn with_overrides(&self, text: &str) -> Result<Self, SimError> {
        let mut base =
            toml::Value::try_from(self).map_err(|e| SimError::ConfigSyntax(e.to_string()))?;
        let over: toml::Value =
            toml::from_str(text).map_err(|e| SimError::ConfigSyntax(e.to_string()))?;
        merge(&mut base, over);
        let config: Self = base
            .try_into()
            .map_err(|e: toml::de::Error| SimError::ConfigSyntax(e.to_string()))?;
        config.validate()?;
        Ok(config)
    }

    /// Whether override text `text` sets the dotted key `key` (e.g. `physics.engine`); false
    /// for text that does not parse (`with_overrides` reports that).
    pub fn overrides_set(text: &str, key: &str) -> bool {
        let Ok(value) = toml::from_str::<toml::Value>(text) else {
            return false;
        };
        key.split('.')
            .try_fold(&value, |v, part| v.get(part))
            .is_some()
    }

    /// The config as a TOML document.
    pub fn to_toml(&self) -> Result<String, SimError> {
        toml::to_string(self).map_err(|e| SimError::ConfigSyntax(e.to_string()))
    }

    /// Policy step (s): physics dt times decimation.
    pub fn policy_dt(&self) -> f32 {
        self.physics.dt * self.env.decimation as f32
    }

    /// Episode length in policy steps.
    pub fn max_episode_steps(&self) -> u32 {
        (self.env.episode_length_s / self.policy_dt())
            .round()
            .max(1.0) as u32
    }

    /// Policy steps between two draws of the task mode.
    pub fn mode_interval_steps(&self) -> u32 {
        (self.modes.resampling_time_s / self.policy_dt())
            .round()
            .max(1.0) as u32
    }

    /// Policy steps between two draws of the commands.
    pub fn command_interval_steps(&self) -> u32 {
        (self.commands.resampling_time_s / self.policy_dt())
            .round()
            .max(1.0) as u32
    }

    /// Policy steps between pushes (None: pushes off).
    pub fn push_interval_steps(&self) -> Option<u32> {
        let s = self.randomization.push_interval_s;
        (s > 0.0 && self.randomization.enabled)
            .then(|| (s / self.policy_dt()).round().max(1.0) as u32)
    }

    /// Effective reward weight of `term`: Table II weight times the policy dt.
    pub fn scaled_weight(&self, term: RewardTerm) -> f32 {
        self.rewards.weights.0[term as usize] * self.policy_dt()
    }
}

fn merge(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// The default task config, embedded at build time.
pub const DEFAULT_TASK_TOML: &str = include_str!("../../../../assets/task.toml");
