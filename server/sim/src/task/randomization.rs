//! Domain randomisation (Table V) as a pure function of the ranges and an RNG.

use rand::{Rng, RngExt};
use rapier3d::math::Vec3;

use super::config::{RandomizationParams, Range};
use crate::physics::{ActuatorParams, RobotPhysicalParams};
use crate::robot::RobotConfig;

/// The randomised values of one env, drawn at reset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Randomization {
    /// Friction coefficient, U(friction).
    pub friction: f32,
    /// Trunk payload (kg), U(payload).
    pub payload: f32,
    /// Trunk CoM shift (m), U(com_offset) per axis.
    pub com_offset: Vec3,
    /// Joint damping (N m s/rad), U(joint_damping).
    pub joint_damping: f32,
    /// Joint friction (N m), U(joint_friction).
    pub joint_friction: f32,
    /// Armature (kg m^2), U(armature).
    pub armature: f32,
    /// kp factor, U(kp_factor).
    pub kp_factor: f32,
    /// kd factor, U(kd_factor).
    pub kd_factor: f32,
}

/// Uniform draw from a closed range.
pub fn uniform(rng: &mut impl Rng, r: Range) -> f32 {
    if r[1] > r[0] {
        rng.random_range(r[0]..=r[1])
    } else {
        r[0]
    }
}

/// `value` mapped linearly from `range` to [-1, 1]; 0 for a range of zero width.
pub fn unit_scale(value: f32, range: Range) -> f32 {
    let width = range[1] - range[0];
    if width > 0.0 {
        2.0 * (value - range[0]) / width - 1.0
    } else {
        0.0
    }
}

impl Randomization {
    /// The robot's nominal values (randomisation off).
    pub fn nominal(robot: &RobotConfig) -> Self {
        Self {
            friction: 1.0,
            payload: 0.0,
            com_offset: Vec3::ZERO,
            joint_damping: robot.joint_damping,
            joint_friction: robot.joint_friction,
            armature: robot.armature,
            kp_factor: 1.0,
            kd_factor: 1.0,
        }
    }

    /// Draw one env's values (or the nominal ones when `params.enabled` is false).
    pub fn sample(params: &RandomizationParams, robot: &RobotConfig, rng: &mut impl Rng) -> Self {
        if !params.enabled {
            return Self::nominal(robot);
        }
        Self {
            friction: uniform(rng, params.friction),
            payload: uniform(rng, params.payload),
            com_offset: Vec3::new(
                uniform(rng, params.com_offset),
                uniform(rng, params.com_offset),
                uniform(rng, params.com_offset),
            ),
            joint_damping: uniform(rng, params.joint_damping),
            joint_friction: uniform(rng, params.joint_friction),
            armature: uniform(rng, params.armature),
            kp_factor: uniform(rng, params.kp_factor),
            kd_factor: uniform(rng, params.kd_factor),
        }
    }

    /// The physical parameters these values give the robot; its contacts' friction combines
    /// the drawn coefficient with the ground's as `ranges` says.
    pub fn physical_params(
        &self,
        robot: &RobotConfig,
        ranges: &RandomizationParams,
    ) -> RobotPhysicalParams {
        RobotPhysicalParams {
            actuator: ActuatorParams {
                kp: robot.kp * self.kp_factor,
                kd: robot.kd * self.kd_factor,
                damping: self.joint_damping,
                friction: self.joint_friction,
            },
            armature: self.armature,
            payload: self.payload,
            com_offset: self.com_offset,
            friction: ranges
                .friction_combine
                .apply(self.friction, ranges.ground_friction),
        }
    }

    /// The privileged vector s_t, in [`super::observation::PRIVILEGED`] order, each value
    /// mapped from its range in `ranges` to [-1, 1] (the middle of a range is 0; a range of
    /// zero width gives 0).
    pub fn privileged(
        &self,
        ranges: &RandomizationParams,
    ) -> [f32; super::observation::PRIVILEGED_DIM] {
        let r = ranges;
        [
            unit_scale(self.friction, r.friction),
            unit_scale(self.payload, r.payload),
            unit_scale(self.com_offset.x, r.com_offset),
            unit_scale(self.com_offset.y, r.com_offset),
            unit_scale(self.com_offset.z, r.com_offset),
            unit_scale(self.joint_damping, r.joint_damping),
            unit_scale(self.joint_friction, r.joint_friction),
            unit_scale(self.armature, r.armature),
            unit_scale(self.kp_factor, r.kp_factor),
            unit_scale(self.kd_factor, r.kd_factor),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::task::FrictionCombine;

    fn drawn(friction: f32) -> Randomization {
        Randomization {
            friction,
            ..Randomization::nominal(&RobotConfig::default())
        }
    }

    #[test]
    fn the_contact_friction_combines_the_robots_with_the_grounds() {
        let robot = RobotConfig::default();
        let mut ranges = RandomizationParams::default();
        // Isaac Gym's rule on its terrain's 1.0: Table V's ends 0.2 and 1.6 touch at 0.6, 1.3.
        assert_eq!(ranges.friction_combine, FrictionCombine::Average);
        let contact = |r: &RandomizationParams, mu| drawn(mu).physical_params(&robot, r).friction;
        assert!((contact(&ranges, 0.2) - 0.6).abs() < 1e-6);
        assert!((contact(&ranges, 1.6) - 1.3).abs() < 1e-6);
        ranges.ground_friction = 0.4;
        assert!((contact(&ranges, 0.2) - 0.3).abs() < 1e-6);
        ranges.friction_combine = FrictionCombine::Multiply;
        assert!((contact(&ranges, 0.2) - 0.08).abs() < 1e-6);
        ranges.ground_friction = 1.0;
        assert!((contact(&ranges, 0.2) - 0.2).abs() < 1e-6);
        // The nominal robot touches at 1 either way; s_t keeps the robot's own coefficient.
        let nominal = Randomization::nominal(&robot);
        for rule in [FrictionCombine::Average, FrictionCombine::Multiply] {
            ranges.friction_combine = rule;
            assert_eq!(nominal.physical_params(&robot, &ranges).friction, 1.0);
        }
        assert_eq!(drawn(0.2).privileged(&ranges)[0], -1.0);
    }
}
