//! What the simulator reads back from one robot after a policy step.

use rapier3d::math::{Rotation, Vec3};

use crate::robot::{NUM_FEET, NUM_JOINTS};

/// Trunk speed (m/s) beyond any this task reaches: pushes add at most 1 m/s per horizontal axis
/// (the config allows 5, and spawns 5 per axis), and random actions on the whole terrain grid
/// reach 2. A faster state is a solver blow-up that has not overflowed yet (decision 0035).
pub const MAX_SOUND_BASE_SPEED: f32 = 20.0;
/// Trunk spin (rad/s) beyond any this task reaches (random actions: 9).
pub const MAX_SOUND_BASE_SPIN: f32 = 50.0;
/// Joint speed (rad/s) beyond any this task reaches (the motors' limit is 30; random actions: 16).
pub const MAX_SOUND_JOINT_SPEED: f32 = 500.0;

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

    /// Whether the state is finite and its speeds are ones a Go2 can have: the test the env
    /// resets a blow-up by, before it overflows (decision 0035). NaN fails every comparison.
    pub fn is_sound(&self) -> bool {
        self.is_finite()
            && self.base_linvel.length() <= MAX_SOUND_BASE_SPEED
            && self.base_angvel.length() <= MAX_SOUND_BASE_SPIN
            && self.qd.iter().all(|v| v.abs() <= MAX_SOUND_JOINT_SPEED)
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
