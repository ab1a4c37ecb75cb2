//! Reward terms as small pure functions (`reward_*` >= 0 pays, `cost_*` >= 0 is penalised by a
//! negative weight), and their weighted, masked sum.

use rapier3d::math::{Vec2, Vec3};

use super::config::{ClearanceWeighting, TaskConfig};
use super::gait::GaitCoefficients;
use super::reward_terms::{Indicators, RewardTerm};
use crate::robot::{NUM_FEET, NUM_JOINTS};

/// legged_gym's tracking kernel width: exp(-|e|^2 / 0.25) = exp(-4 |e|^2), as the paper writes.
pub const TRACKING_SHARPNESS: f32 = 4.0;

/// Everything the rewards of one env at one step depend on.
#[derive(Clone, Debug, PartialEq)]
pub struct RewardInputs {
    /// The episode ended by a trunk contact this step (not a time-out).
    pub terminated: bool,
    /// Number of thighs and calves touching the terrain.
    pub penalised_contacts: u32,
    /// The head touches the terrain (contact force above the threshold).
    pub head_contact: bool,
    /// Base angular velocity in the base frame (rad/s).
    pub base_angvel_b: Vec3,
    /// Base linear velocity in the base frame (m/s).
    pub base_linvel_b: Vec3,
    /// Base velocity in the heading frame, xy (m/s).
    pub heading_linvel: Vec2,
    /// Yaw rate: angular velocity about world z (rad/s).
    pub yaw_rate: f32,
    /// Commands (vx, vy in the heading frame; wz).
    pub command: [f32; 3],
    /// Base height above the terrain under it (m).
    pub base_height: f32,
    /// Terrain normal under the base, in the base frame.
    pub terrain_normal_b: Vec3,
    /// Euler pitch, positive nose down (rad).
    pub pitch: f32,
    /// Lateral component of gravity in the base frame: the roll measure that stays defined when
    /// the body stands vertical.
    pub roll_proxy: f32,
    /// Joint angles, speeds and speeds one policy step earlier.
    pub q: [f32; NUM_JOINTS],
    /// Joint speeds (rad/s).
    pub qd: [f32; NUM_JOINTS],
    /// Joint speeds at the previous policy step (rad/s).
    pub qd_prev: [f32; NUM_JOINTS],
    /// Actions a_t, a_{t-1}, a_{t-2}.
    pub actions: [[f32; NUM_JOINTS]; 3],
    /// Motor torques (N m).
    pub torques: [f32; NUM_JOINTS],
    /// Foot contact forces (N).
    pub foot_force: [f32; NUM_FEET],
    /// Foot speeds (m/s).
    pub foot_speed: [f32; NUM_FEET],
    /// Foot horizontal speeds (m/s).
    pub foot_speed_xy: [f32; NUM_FEET],
    /// Foot sole height above the highest terrain within the sampling radius (m).
    pub foot_clearance_height: [f32; NUM_FEET],
    /// Air time (s) of each foot's swing that ended at this step, 0 for a foot that did not
    /// touch down ([`crate::task::FeetAirTime`]).
    pub touchdown_air_time: [f32; NUM_FEET],
    /// Gait weights per foot for the quad offsets.
    pub gait_quad: [GaitCoefficients; NUM_FEET],
    /// Gait weights per foot for the biped offsets.
    pub gait_biped: [GaitCoefficients; NUM_FEET],
}

/// Robot constants the rewards need.
#[derive(Clone, Debug, PartialEq)]
pub struct RewardConstants {
    /// Default joint angles.
    pub default_q: [f32; NUM_JOINTS],
    /// Soft lower joint limits.
    pub soft_lower: [f32; NUM_JOINTS],
    /// Soft upper joint limits.
    pub soft_upper: [f32; NUM_JOINTS],
    /// Hip joint indices.
    pub hips: [usize; NUM_FEET],
    /// Joint indices of the left and right raised (rear) legs: hip, thigh, calf each.
    pub raised_left: [usize; 3],
    /// Joint indices of the right raised leg.
    pub raised_right: [usize; 3],
    /// Feet of the biped stance (front: FL, FR).
    pub stance_feet: [usize; 2],
    /// Feet raised in the biped stance (rear: RL, RR).
    pub raised_feet: [usize; 2],
    /// Joint indices (hip, thigh, calf) of the stance legs (front: FL, FR).
    pub stance_legs: [[usize; 3]; 2],
    /// Per stance leg: the thigh joint's origin in the hip link, the knee's in the thigh link
    /// and the foot centre in the calf link (URDF geometry; the thigh and knee axes are y).
    pub stance_leg_geometry: [[Vec3; 3]; 2],
}

fn sq_sum(v: impl IntoIterator<Item = f32>) -> f32 {
    v.into_iter().map(|x| x * x).sum()
}

/// 1 when the episode ended by termination (not time-out).
pub fn cost_termination(terminated: bool) -> f32 {
    f32::from(u8::from(terminated))
}

/// Number of penalised bodies in contact.
pub fn cost_collision(contacts: u32) -> f32 {
    contacts as f32
}

/// |omega_xy|^2 in the base frame: roll and pitch rates.
pub fn cost_ang_vel_xy(w: Vec3) -> f32 {
    w.x * w.x + w.y * w.y
}

/// |qdot|^2.
pub fn cost_dof_vel(qd: &[f32; NUM_JOINTS]) -> f32 {
    sq_sum(qd.iter().copied())
}

/// |qddot|^2 with qddot = (qdot - qdot_prev) / dt.
pub fn cost_dof_acc(qd: &[f32; NUM_JOINTS], qd_prev: &[f32; NUM_JOINTS], dt: f32) -> f32 {
    sq_sum(qd.iter().zip(qd_prev).map(|(a, b)| (a - b) / dt))
}

/// |a_t - a_{t-1}|^2.
pub fn cost_action_rate(a: &[f32; NUM_JOINTS], a1: &[f32; NUM_JOINTS]) -> f32 {
    sq_sum(a.iter().zip(a1).map(|(x, y)| x - y))
}

/// |a_t - 2 a_{t-1} + a_{t-2}|^2.
pub fn cost_action_smoothness(
    a: &[f32; NUM_JOINTS],
    a1: &[f32; NUM_JOINTS],
    a2: &[f32; NUM_JOINTS],
) -> f32 {
    sq_sum((0..NUM_JOINTS).map(|i| a[i] - 2.0 * a1[i] + a2[i]))
}

/// |tau|^2.
pub fn cost_torques(tau: &[f32; NUM_JOINTS]) -> f32 {
    sq_sum(tau.iter().copied())
}

/// |q_hip - q0_hip|^2: hips kept at their default abduction.
pub fn cost_hip_pos(
    q: &[f32; NUM_JOINTS],
    q0: &[f32; NUM_JOINTS],
    hips: &[usize; NUM_FEET],
) -> f32 {
    sq_sum(hips.iter().map(|&i| q[i] - q0[i]))
}

/// Number of joints outside their soft limits.
pub fn cost_dof_pos_limits(
    q: &[f32; NUM_JOINTS],
    lo: &[f32; NUM_JOINTS],
    hi: &[f32; NUM_JOINTS],
) -> f32 {
    (0..NUM_JOINTS)
        .filter(|&i| q[i] < lo[i] || q[i] > hi[i])
        .count() as f32
}

/// exp(-k |v*_xy - v_xy|^2) in the heading frame; the paper's k is 4 ([`TRACKING_SHARPNESS`]).
pub fn reward_tracking_lin_vel(cmd: [f32; 2], v: Vec2, sharpness: f32) -> f32 {
    (-sharpness * ((cmd[0] - v.x).powi(2) + (cmd[1] - v.y).powi(2))).exp()
}

/// exp(-4 (w*_z - w_z)^2).
pub fn reward_tracking_ang_vel(cmd: f32, wz: f32) -> f32 {
    (-TRACKING_SHARPNESS * (cmd - wz).powi(2)).exp()
}

/// exp(-2 (h* - h)^2).
pub fn reward_base_height(target: f32, h: f32) -> f32 {
    (-2.0 * (target - h).powi(2)).exp()
}

/// exp(-10 |n_b,xy|^2): trunk parallel to the terrain under it (Eq. 3).
pub fn reward_quad_base_angle(n_b: Vec3) -> f32 {
    (-10.0 * (n_b.x * n_b.x + n_b.y * n_b.y)).exp()
}

/// v_z^2 (base frame).
pub fn cost_lin_vel_z(vz: f32) -> f32 {
    vz * vz
}

/// Gait violation E = sum over `feet` of w_force * F / F_scale + w_speed * |v| / v_scale (>= 0).
pub fn gait_violation(
    coeffs: &[GaitCoefficients; NUM_FEET],
    force: &[f32; NUM_FEET],
    speed: &[f32; NUM_FEET],
    feet: &[usize],
    force_scale: f32,
    speed_scale: f32,
) -> f32 {
    feet.iter()
        .map(|&f| {
            coeffs[f].force * force[f] / force_scale + coeffs[f].speed * speed[f] / speed_scale
        })
        .sum()
}

/// exp(-2 E): 1 for a perfect gait.
pub fn reward_periodic_gait(violation: f32) -> f32 {
    (-2.0 * violation).exp()
}

/// Clearance error sum over `feet` of (h_i - target)^2 w_i (Eq. 4 with w_i = |v_xy,i|; heights
/// already measured from the highest terrain around each foot). `weight` is what
/// [`ClearanceWeighting`] picks: the feet's horizontal speeds or their expected swing indicators.
pub fn foot_clearance_error(
    height: &[f32; NUM_FEET],
    weight: &[f32; NUM_FEET],
    target: f32,
    feet: &[usize],
) -> f32 {
    feet.iter()
        .map(|&f| (height[f] - target).powi(2) * weight[f])
        .sum()
}

/// Each foot's weight on its clearance error under `weighting`, for the gait of the term's mode.
pub fn clearance_weights(
    weighting: ClearanceWeighting,
    speed_xy: &[f32; NUM_FEET],
    gait: &[GaitCoefficients; NUM_FEET],
) -> [f32; NUM_FEET] {
    match weighting {
        ClearanceWeighting::FootSpeed => *speed_xy,
        ClearanceWeighting::SwingPhase => gait.map(|c| c.force),
    }
}

/// exp(-sharpness error): the paper's sharpness is 100 (Eq. 4 and 6).
pub fn reward_foot_clearance(error: f32, sharpness: f32) -> f32 {
    (-sharpness * error).exp()
}

/// legged_gym's feet air time, capped: the sum over `feet` that touched down at this step of
/// min(air time, `target`) - `target` (s), and 0 when the commanded speed |v*_xy| is below
/// 0.1 m/s (standing still needs no steps). A swing as long as the target is free and a longer
/// one earns nothing more, so the term cannot pay for hops.
pub fn reward_feet_air_time(
    touchdown_air_time: &[f32; NUM_FEET],
    feet: &[usize],
    target: f32,
    command_xy: [f32; 2],
) -> f32 {
    if command_xy[0].hypot(command_xy[1]) <= 0.1 {
        return 0.0;
    }
    feet.iter()
        .filter(|&&f| touchdown_air_time[f] > 0.0)
        .map(|&f| touchdown_air_time[f].min(target) - target)
        .sum()
}

/// exp(-2 |phi*_xy - phi_xy|^2) with (roll proxy, pitch).
pub fn reward_biped_base_angle(target: [f32; 2], roll_proxy: f32, pitch: f32) -> f32 {
    (-2.0 * ((target[0] - roll_proxy).powi(2) + (target[1] - pitch).powi(2))).exp()
}

/// |q_left - mirror(q_right)|^2 of the raised legs: hips mirror (opposite sign), thighs and
/// calves equal, so a symmetric pose costs 0.
pub fn cost_biped_rear_legs(q: &[f32; NUM_JOINTS], left: &[usize; 3], right: &[usize; 3]) -> f32 {
    (q[left[0]] + q[right[0]]).powi(2)
        + (q[left[1]] - q[right[1]]).powi(2)
        + (q[left[2]] - q[right[2]]).powi(2)
}

/// Sideways reach of one leg's foot per radian of its hip abduction (m/rad): the foot's
/// distance from the abduction axis (the base's x axis) along the base's z axis. Thigh and knee
/// turn about y; `geometry` is (thigh joint origin, knee origin, foot centre), each in its
/// parent link.
pub fn sideways_reach(hip: f32, thigh: f32, knee: f32, geometry: &[Vec3; 3]) -> f32 {
    let about_y = |angle: f32, v: Vec3| {
        let (s, c) = angle.sin_cos();
        Vec3::new(c * v.x + s * v.z, v.y, -s * v.x + c * v.z)
    };
    let [thigh_origin, knee_origin, foot] = *geometry;
    // The foot in the hip link's frame, then turned by the abduction about x.
    let p = thigh_origin + about_y(thigh, knee_origin + about_y(knee, foot));
    let (s, c) = hip.sin_cos();
    (s * p.y + c * p.z).abs()
}

/// Mean over the stance legs of their sideways reach as a share of `target`, each capped at 1.
pub fn reward_sideways_reach(
    q: &[f32; NUM_JOINTS],
    legs: &[[usize; 3]; 2],
    geometry: &[[Vec3; 3]; 2],
    target: f32,
) -> f32 {
    let share = |leg: usize| {
        let [h, t, k] = legs[leg];
        (sideways_reach(q[h], q[t], q[k], &geometry[leg]) / target).min(1.0)
    };
    (share(0) + share(1)) / 2.0
}

/// 1 when a stance foot touches the ground and no raised foot does.
pub fn reward_upright_contacts(
    contact: &[bool; NUM_FEET],
    stance: &[usize; 2],
    raised: &[usize; 2],
) -> f32 {
    let stance_down = stance.iter().any(|&f| contact[f]);
    let raised_up = raised.iter().all(|&f| !contact[f]);
    f32::from(u8::from(stance_down && raised_up))
}

/// 1 while the head or any thigh or calf touches the terrain (a support other than the feet;
/// the trunk's contact ends the episode).
pub fn cost_body_contact(head_contact: bool, penalised_contacts: u32) -> f32 {
    f32::from(u8::from(head_contact || penalised_contacts > 0))
}

/// Unweighted, unmasked value of every term.
pub fn raw_terms(
    x: &RewardInputs,
    k: &RewardConstants,
    cfg: &TaskConfig,
) -> [f32; RewardTerm::COUNT] {
    let r = &cfg.rewards;
    let g = &cfg.gait;
    let dt = cfg.policy_dt();
    let all_feet = [0, 1, 2, 3];
    let contact: [bool; NUM_FEET] = std::array::from_fn(|f| x.foot_force[f] > r.contact_threshold);
    let cmd_xy = [x.command[0], x.command[1]];
    let mut v = [0.0; RewardTerm::COUNT];
    for term in RewardTerm::ALL {
        v[term as usize] = match term {
            RewardTerm::Termination => cost_termination(x.terminated),
            RewardTerm::Collision => cost_collision(x.penalised_contacts),
            RewardTerm::AngVelXy => cost_ang_vel_xy(x.base_angvel_b),
            RewardTerm::DofVel => cost_dof_vel(&x.qd),
            RewardTerm::DofAcc => cost_dof_acc(&x.qd, &x.qd_prev, dt),
            RewardTerm::ActionRate => cost_action_rate(&x.actions[0], &x.actions[1]),
            RewardTerm::ActionSmoothness => {
                cost_action_smoothness(&x.actions[0], &x.actions[1], &x.actions[2])
            }
            RewardTerm::Torques => cost_torques(&x.torques),
            RewardTerm::HipPos => cost_hip_pos(&x.q, &k.default_q, &k.hips),
            RewardTerm::DofPosLimits => cost_dof_pos_limits(&x.q, &k.soft_lower, &k.soft_upper),
            RewardTerm::QuadTrackingLinVel => {
                reward_tracking_lin_vel(cmd_xy, x.heading_linvel, r.quad_tracking_lin_vel_sharpness)
            }
            RewardTerm::BipedTrackingLinVel => reward_tracking_lin_vel(
                cmd_xy,
                x.heading_linvel,
                r.biped_tracking_lin_vel_sharpness,
            ),
            RewardTerm::QuadTrackingAngVel | RewardTerm::BipedTrackingAngVel => {
                reward_tracking_ang_vel(x.command[2], x.yaw_rate)
            }
            RewardTerm::QuadBaseHeight => reward_base_height(r.base_height_quad, x.base_height),
            RewardTerm::QuadBaseAngle => reward_quad_base_angle(x.terrain_normal_b),
            RewardTerm::QuadLinVelZ => cost_lin_vel_z(x.base_linvel_b.z),
            RewardTerm::QuadPeriodicGait => reward_periodic_gait(gait_violation(
                &x.gait_quad,
                &x.foot_force,
                &x.foot_speed,
                &all_feet,
                g.force_scale,
                g.speed_scale,
            )),
            RewardTerm::QuadFootClearance => reward_foot_clearance(
                foot_clearance_error(
                    &x.foot_clearance_height,
                    &clearance_weights(r.foot_clearance_weighting, &x.foot_speed_xy, &x.gait_quad),
                    r.foot_clearance_target,
                    &all_feet,
                ),
                r.foot_clearance_sharpness,
            ),
            RewardTerm::BipedBaseHeight => reward_base_height(r.base_height_biped, x.base_height),
            RewardTerm::BipedBaseAngle => {
                reward_biped_base_angle(r.biped_angle_target, x.roll_proxy, x.pitch)
            }
            RewardTerm::BipedPeriodicGait => reward_periodic_gait(gait_violation(
                &x.gait_biped,
                &x.foot_force,
                &x.foot_speed,
                &k.stance_feet,
                g.force_scale,
                g.speed_scale,
            )),
            RewardTerm::BipedFootClearance => reward_foot_clearance(
                foot_clearance_error(
                    &x.foot_clearance_height,
                    &clearance_weights(r.foot_clearance_weighting, &x.foot_speed_xy, &x.gait_biped),
                    r.biped_foot_clearance_target
                        .unwrap_or(r.foot_clearance_target),
                    &k.stance_feet,
                ),
                r.foot_clearance_sharpness,
            ),
            RewardTerm::BipedFeetAirTime => reward_feet_air_time(
                &x.touchdown_air_time,
                &k.stance_feet,
                g.period_s * g.swing_ratio,
                cmd_xy,
            ),
            RewardTerm::BipedRearLegs => {
                cost_biped_rear_legs(&x.q, &k.raised_left, &k.raised_right)
            }
            RewardTerm::BipedUprightContacts => {
                reward_upright_contacts(&contact, &k.stance_feet, &k.raised_feet)
            }
            RewardTerm::BipedBodyContact => cost_body_contact(x.head_contact, x.penalised_contacts),
            RewardTerm::BipedSidewaysReach => reward_sideways_reach(
                &x.q,
                &k.stance_legs,
                &k.stance_leg_geometry,
                r.sideways_reach_target,
            ),
        };
    }
    v
}

/// The indicators for a mode (`biped`) and a pitch, with the config's ablation switches. I_up
/// fires above `upright_pitch`: the config's `rewards.upright_pitch`, or where the upright
/// curriculum has got to.
pub fn indicators(biped: bool, pitch: f32, upright_pitch: f32, cfg: &TaskConfig) -> Indicators {
    let r = &cfg.rewards;
    let (i1, i2) = if r.task_indicators {
        (f32::from(u8::from(biped)), f32::from(u8::from(!biped)))
    } else {
        (1.0, 1.0)
    };
    let up = if r.upright_indicator {
        f32::from(u8::from(pitch > upright_pitch))
    } else {
        1.0
    };
    Indicators {
        biped: i1,
        quad: i2,
        upright: up,
    }
}

/// Weighted, masked terms (weight * dt * mask * raw) into `terms`; returns the total reward:
/// the sum of all but termination, clipped at 0 when `only_positive`, plus termination.
pub fn weigh_terms(
    raw: &[f32; RewardTerm::COUNT],
    ind: &Indicators,
    cfg: &TaskConfig,
    terms: &mut [f32],
) -> f32 {
    let mut sum = 0.0;
    for term in RewardTerm::ALL {
        let value = cfg.scaled_weight(term) * ind.mask(term.group()) * raw[term as usize];
        terms[term as usize] = value;
        if term != RewardTerm::Termination {
            sum += value;
        }
    }
    if cfg.rewards.only_positive {
        sum = sum.max(0.0);
    }
    sum + terms[RewardTerm::Termination as usize]
}

#[cfg(test)]
#[path = "rewards_test.rs"]
mod test;
