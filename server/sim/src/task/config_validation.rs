//! Validation of the task configuration: every number checked against its allowed range, so
//! that a bad value from a client is an error naming the field, never a panic in the step.

use super::config::{Range, TaskConfig};
use super::reward_terms::RewardTerm;
use crate::error::SimError;

fn check_range(field: &str, r: Range, lo: f32, hi: f32) -> Result<(), SimError> {
    if !(r[0].is_finite() && r[1].is_finite() && r[0] <= r[1] && r[0] >= lo && r[1] <= hi) {
        return Err(SimError::invalid(
            field,
            format!("{r:?}"),
            format!("need lo <= hi within [{lo}, {hi}]"),
        ));
    }
    Ok(())
}

fn check(field: &str, v: f32, lo: f32, hi: f32) -> Result<(), SimError> {
    if !(v.is_finite() && v >= lo && v <= hi) {
        return Err(SimError::invalid(
            field,
            v,
            format!("allowed range [{lo}, {hi}]"),
        ));
    }
    Ok(())
}

/// Checks an integer setting (an iteration count) against its allowed range.
fn check_count(field: &str, v: usize, lo: usize, hi: usize) -> Result<(), SimError> {
    if !(lo..=hi).contains(&v) {
        return Err(SimError::invalid(
            field,
            v,
            format!("allowed range [{lo}, {hi}]"),
        ));
    }
    Ok(())
}

impl TaskConfig {
    /// Check every value against its allowed range.
    pub fn validate(&self) -> Result<(), SimError> {
        self.terrain_curriculum.validate()?;
        let p = &self.physics;
        check("physics.dt", p.dt, 1e-4, 0.02)?;
        check_count("physics.solver_iterations", p.solver_iterations, 1, 64)?;
        check_count("physics.pgs_iterations", p.pgs_iterations, 1, 64)?;
        check("physics.gravity", p.gravity, 0.0, 100.0)?;
        check_count(
            "physics.extra_iterations_on_leg_contact",
            p.extra_iterations_on_leg_contact,
            0,
            64,
        )?;
        check_count(
            "physics.extra_pgs_iterations_on_leg_contact",
            p.extra_pgs_iterations_on_leg_contact,
            0,
            64,
        )?;
        check("physics.min_link_inertia", p.min_link_inertia, 0.0, 1.0)?;
        let e = &self.env;
        check("env.episode_length_s", e.episode_length_s, 0.02, 3600.0)?;
        if !(1..=100).contains(&e.decimation) {
            return Err(SimError::invalid(
                "env.decimation",
                e.decimation,
                "allowed range [1, 100]",
            ));
        }
        if !(1..=4096).contains(&e.envs_per_world) {
            return Err(SimError::invalid(
                "env.envs_per_world",
                e.envs_per_world,
                "allowed range [1, 4096]",
            ));
        }
        check("env.action_scale", e.action_scale, 0.0, 10.0)?;
        check("env.clip_actions", e.clip_actions, 0.0, 1e6)?;
        check("env.clip_observations", e.clip_observations, 0.0, 1e6)?;
        let c = &self.commands;
        check(
            "commands.resampling_time_s",
            c.resampling_time_s,
            0.02,
            3600.0,
        )?;
        check("commands.zero_below", c.zero_below, 0.0, 10.0)?;
        check("commands.heading_share", c.heading_share, 0.0, 1.0)?;
        check("commands.heading_gain", c.heading_gain, 0.0, 100.0)?;
        for (mode, r) in [("quad", &c.quad), ("biped", &c.biped)] {
            check_range(&format!("commands.{mode}.vx"), r.vx, -10.0, 10.0)?;
            check_range(&format!("commands.{mode}.vy"), r.vy, -10.0, 10.0)?;
            check_range(&format!("commands.{mode}.wz"), r.wz, -10.0, 10.0)?;
        }
        check(
            "modes.resampling_time_s",
            self.modes.resampling_time_s,
            0.02,
            3600.0,
        )?;
        check(
            "modes.biped_probability",
            self.modes.biped_probability,
            0.0,
            1.0,
        )?;
        let g = &self.gait;
        check("gait.period_s", g.period_s, 0.05, 10.0)?;
        check("gait.swing_ratio", g.swing_ratio, 0.0, 1.0)?;
        check("gait.kappa", g.kappa, 0.1, 1000.0)?;
        check("gait.force_scale", g.force_scale, 1e-3, 1e6)?;
        check("gait.speed_scale", g.speed_scale, 1e-3, 1e6)?;
        for (i, o) in g.offsets_quad.iter().chain(&g.offsets_biped).enumerate() {
            check(&format!("gait.offsets[{i}]"), *o, 0.0, 1.0)?;
        }
        let i = &self.init;
        check_range("init.hip", i.hip, -3.2, 3.2)?;
        check_range("init.thigh", i.thigh, -3.2, 3.2)?;
        check_range("init.calf", i.calf, -3.2, 3.2)?;
        // Well under the trunk speed the env resets as a blow-up (20 m/s, decision 0035).
        check_range("init.linvel", i.linvel, -5.0, 5.0)?;
        check_range("init.angvel", i.angvel, -10.0, 10.0)?;
        check_range("init.pitch", i.pitch, -1.6, 1.6)?;
        check_range("init.yaw", i.yaw, -3.2, 3.2)?;
        check("init.spawn_clearance", i.spawn_clearance, 0.0, 2.0)?;
        let r = &self.randomization;
        check_range("randomization.friction", r.friction, 0.0, 10.0)?;
        check(
            "randomization.ground_friction",
            r.ground_friction,
            0.0,
            10.0,
        )?;
        check_range("randomization.payload", r.payload, -5.0, 20.0)?;
        check_range("randomization.com_offset", r.com_offset, -0.1, 0.1)?;
        check_range("randomization.joint_damping", r.joint_damping, 0.0, 10.0)?;
        check_range("randomization.joint_friction", r.joint_friction, 0.0, 10.0)?;
        check_range("randomization.armature", r.armature, 0.0, 1.0)?;
        check_range("randomization.kp_factor", r.kp_factor, 0.0, 10.0)?;
        check_range("randomization.kd_factor", r.kd_factor, 0.0, 10.0)?;
        check(
            "randomization.push_interval_s",
            r.push_interval_s,
            0.0,
            3600.0,
        )?;
        check("randomization.push_velocity", r.push_velocity, 0.0, 5.0)?;
        let w = &self.rewards;
        for term in RewardTerm::ALL {
            check(
                &format!("rewards.weights.{}", term.name()),
                w.weights.0[term as usize],
                -1e6,
                1e6,
            )?;
        }
        check("rewards.base_height_quad", w.base_height_quad, 0.0, 2.0)?;
        check("rewards.base_height_biped", w.base_height_biped, 0.0, 2.0)?;
        check("rewards.upright_pitch", w.upright_pitch, 0.0, 1.6)?;
        let uc = &w.upright_curriculum;
        check(
            "rewards.upright_curriculum.start",
            uc.start,
            0.0,
            w.upright_pitch,
        )?;
        check("rewards.upright_curriculum.step", uc.step, 1e-3, 1.6)?;
        check(
            "rewards.upright_curriculum.promote_share",
            uc.promote_share,
            0.0,
            1.0,
        )?;
        check_count(
            "rewards.upright_curriculum.window_steps",
            uc.window_steps as usize,
            1,
            100_000_000,
        )?;
        check(
            "rewards.foot_clearance_target",
            w.foot_clearance_target,
            0.0,
            1.0,
        )?;
        if let Some(target) = w.biped_foot_clearance_target {
            check("rewards.biped_foot_clearance_target", target, 0.0, 1.0)?;
        }
        check(
            "rewards.foot_clearance_radius",
            w.foot_clearance_radius,
            0.0,
            0.5,
        )?;
        check(
            "rewards.foot_clearance_sharpness",
            w.foot_clearance_sharpness,
            1.0,
            1.0e5,
        )?;
        check(
            "rewards.quad_tracking_lin_vel_sharpness",
            w.quad_tracking_lin_vel_sharpness,
            0.1,
            1.0e3,
        )?;
        check(
            "rewards.biped_tracking_lin_vel_sharpness",
            w.biped_tracking_lin_vel_sharpness,
            0.1,
            1.0e3,
        )?;
        check(
            "rewards.sideways_reach_target",
            w.sideways_reach_target,
            1e-3,
            1.0,
        )?;
        check("rewards.soft_joint_limit", w.soft_joint_limit, 0.0, 1.0)?;
        check("rewards.contact_threshold", w.contact_threshold, 0.0, 1e4)?;
        check("noise.level", self.noise.level, 0.0, 100.0)?;
        Ok(())
    }
}
