//! What the simulator reads back from one robot after a policy step.

use rapier3d::math::{Rotation, Vec3};

use crate::robot::{NUM_FEET, NUM_JOINTS};

/// The measured state of one robot (world frame unless noted).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotState {
    /// Trunk origin position (m).
    pub base_pos: Vec3,
    /// Trunk orientation.
    pub base_rot: Rotation,
    /// Velocity of the trunk origin (m/s).
    pub base_linvel: Vec3,
    /// Trunk angular velocity (rad/s).
    pub base_angvel: Vec3,
    /// Joint angles (rad), action order.
    pub q: [f32; NUM_JOINTS],
    /// Joint speeds (rad/s).
    pub qd: [f32; NUM_JOINTS],
    /// Foot sphere centres (m).
    pub foot_pos: [Vec3; NUM_FEET],
    /// Foot sphere centre velocities (m/s).
    pub foot_vel: [Vec3; NUM_FEET],
    /// Normal contact force on each foot (N), last physics step.
    pub foot_force: [f32; NUM_FEET],
    /// Normal contact force on the trunk (N); terminates the episode.
    pub trunk_force: f32,
    /// Normal contact force on the head (N); reported only.
    pub head_force: f32,
    /// Number of penalised bodies (thighs, calves) touching the terrain.
    pub penalised_contacts: u32,
    /// Number of contacts of other leg parts (hips) with the terrain.
    pub other_contacts: u32,
    /// Bit set of the penalised bodies in contact (scratch for counting).
    pub penalised_bodies: u32,
    /// The physics engine found this robot's state non-finite and froze it.
    pub faulted: bool,
    /// Worst joint anchor separation of this robot left by the solver during the last policy
    /// step, measured before the joint projection (m).
    pub max_joint_gap: f32,
    /// The robot gets extra solver iterations for its next physics step (legs on the terrain or
    /// joints at their stops).
    pub extra_iterations: bool,
}

impl RobotState {
    /// Forget all contacts (e.g. after a teleport).
    pub fn clear_contacts(&mut self) {
        self.foot_force = [0.0; NUM_FEET];
        self.trunk_force = 0.0;
        self.head_force = 0.0;
        self.penalised_contacts = 0;
        self.penalised_bodies = 0;
        self.other_contacts = 0;
    }

    /// Whether every measured quantity is finite.
    pub fn is_finite(&self) -> bool {
        !self.faulted
            && self.base_pos.is_finite()
            && self.base_rot.is_finite()
            && self.base_linvel.is_finite()
            && self.base_angvel.is_finite()
            && self.q.iter().chain(&self.qd).all(|v| v.is_finite())
            && self.foot_vel.iter().all(|v| v.is_finite())
    }
}

impl Default for RobotState {
    fn default() -> Self {
        Self {
            base_pos: Vec3::ZERO,
            base_rot: Rotation::IDENTITY,
            base_linvel: Vec3::ZERO,
            base_angvel: Vec3::ZERO,
            q: [0.0; NUM_JOINTS],
            qd: [0.0; NUM_JOINTS],
            foot_pos: [Vec3::ZERO; NUM_FEET],
            foot_vel: [Vec3::ZERO; NUM_FEET],
            foot_force: [0.0; NUM_FEET],
            trunk_force: 0.0,
            head_force: 0.0,
            penalised_contacts: 0,
            penalised_bodies: 0,
            other_contacts: 0,
            max_joint_gap: 0.0,
            extra_iterations: false,
            faulted: false,
        }
    }
}
