//! Values derived once from the task config and the robot model, shared read-only by all envs.

use rapier3d::math::Vec3;

use super::config::TaskConfig;
use super::gait::VonMisesCdf;
use super::observation::{OBS_DIM, OBSERVATION, noise_amplitudes, scales};
use super::rewards::RewardConstants;
use crate::robot::{NUM_JOINTS, RobotModel, Shape};

/// Derived, immutable task data.
#[derive(Clone, Debug)]
pub struct TaskContext {
    /// The config.
    pub config: TaskConfig,
    /// Robot constants for the rewards.
    pub reward: RewardConstants,
    /// Von Mises CDF table for the gait reward.
    pub cdf: VonMisesCdf,
    /// Observation scale per value.
    pub obs_scale: [f32; OBS_DIM],
    /// Observation noise amplitude per value (0 when noise is off).
    pub obs_noise: [f32; OBS_DIM],
    /// Default joint angles.
    pub default_q: [f32; NUM_JOINTS],
    /// Episode length in policy steps.
    pub max_episode_steps: u32,
    /// Steps between mode draws.
    pub mode_interval: u32,
    /// Steps between command draws.
    pub command_interval: u32,
    /// Steps between pushes.
    pub push_interval: Option<u32>,
    /// Bounding spheres (body index, centre in body frame, radius) of every collider, to place
    /// robots clear of the terrain at reset.
    pub collider_bounds: Vec<(usize, Vec3, f32)>,
}

impl TaskContext {
    /// Derive everything from `config` and `model`.
    pub fn new(config: TaskConfig, model: &RobotModel) -> Self {
        let default_q: [f32; NUM_JOINTS] =
            std::array::from_fn(|j| model.config.default_joint_pos[j]);
        let k = config.rewards.soft_joint_limit;
        let soft = |j: usize, side: f32| {
            let joint = &model.joints[j];
            let (m, r) = ((joint.lower + joint.upper) / 2.0, joint.upper - joint.lower);
            m + side * 0.5 * r * k
        };
        let per_leg = model.config.joints_per_leg;
        let reward = RewardConstants {
            default_q,
            soft_lower: std::array::from_fn(|j| soft(j, -1.0)),
            soft_upper: std::array::from_fn(|j| soft(j, 1.0)),
            hips: std::array::from_fn(|leg| leg * per_leg),
            raised_left: std::array::from_fn(|i| 2 * per_leg + i),
            raised_right: std::array::from_fn(|i| 3 * per_leg + i),
            stance_feet: [0, 1],
            raised_feet: [2, 3],
            stance_legs: std::array::from_fn(|leg| std::array::from_fn(|i| leg * per_leg + i)),
            stance_leg_geometry: std::array::from_fn(|leg| {
                let joint = |i: usize| model.joints[leg * per_leg + i].origin.translation;
                [joint(1), joint(2), model.feet[leg].offset]
            }),
        };
        let scale = scales(&OBSERVATION);
        let level = if config.noise.enabled {
            config.noise.level
        } else {
            0.0
        };
        let noise = noise_amplitudes(&OBSERVATION, level);
        let collider_bounds = model
            .bodies
            .iter()
            .enumerate()
            .flat_map(|(b, body)| {
                body.colliders.iter().map(move |c| {
                    let radius = match c.geometry.shape {
                        Shape::Box { size } => size.length() / 2.0,
                        Shape::Cylinder { radius, length } => length / 2.0 + radius,
                        Shape::Sphere { radius } => radius,
                    };
                    (b, c.geometry.origin.translation, radius)
                })
            })
            .collect();
        Self {
            cdf: VonMisesCdf::new(config.gait.kappa),
            obs_scale: std::array::from_fn(|i| scale[i]),
            obs_noise: std::array::from_fn(|i| noise[i]),
            default_q,
            max_episode_steps: config.max_episode_steps(),
            mode_interval: config.mode_interval_steps(),
            command_interval: config.command_interval_steps(),
            push_interval: config.push_interval_steps(),
            reward,
            collider_bounds,
            config,
        }
    }
}
