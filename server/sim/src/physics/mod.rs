//! Physics: robots in rapier worlds or the articulated engine, actuation, state read-back.

mod actuation;
pub mod articulated;
mod counters;
mod engine;
mod inertia;
mod joint_state;
mod params;
mod robot_state;
mod world;

pub use actuation::{ActuatorParams, FRICTION_RAMP_SPEED, passive_torque, pd_torque};
pub use counters::PhysicsCounters;
pub use engine::{EngineKind, PhysicsWorld};
pub use joint_state::{joint_angle, joint_speed};
pub use params::PhysicsParams;
pub use robot_state::{
    MAX_SOUND_BASE_SPEED, MAX_SOUND_BASE_SPIN, MAX_SOUND_JOINT_SPEED, RobotState,
};
pub use world::{CONTACT_FORCE_THRESHOLD, RobotPhysicalParams, RobotWorld};
