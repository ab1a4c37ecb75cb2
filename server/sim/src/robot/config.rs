//! The few robot facts the simulator needs beyond its URDF: joint order, feet, gains, default pose.

use serde::{Deserialize, Serialize};

/// Number of actuated joints of a quadruped (3 per leg).
pub const NUM_JOINTS: usize = 12;
/// Number of feet.
pub const NUM_FEET: usize = 4;

/// Robot-specific configuration, resolved against a [`super::RobotDescription`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotConfig {
    /// Joint names in the order used everywhere (observations, actions, torques): FL, FR, RL, RR,
    /// each hip, thigh, calf.
    pub joint_names: Vec<String>,
    /// Names of the foot collision elements (spheres), in leg order FL, FR, RL, RR.
    pub foot_names: Vec<String>,
    /// The trunk link: its contact with the terrain terminates an episode.
    pub trunk_link: String,
    /// Names of the head's collision elements: their terrain contact is reported, neither
    /// terminating nor penalised (the paper's simulator keeps the head a separate body that
    /// neither its termination nor its penalty list names).
    pub head_colliders: Vec<String>,
    /// Substrings of link names whose terrain contact is penalised (legged_gym `penalize_contacts_on`).
    pub penalised_links: Vec<String>,
    /// Joint angles at action zero (rad), in `joint_names` order.
    pub default_joint_pos: Vec<f32>,
    /// PD stiffness (N m/rad).
    pub kp: f32,
    /// PD damping (N m s/rad).
    pub kd: f32,
    /// Rotor inertia reflected on each joint axis when randomisation is off (kg m^2); the middle of
    /// the paper's identified range [0.015, 0.025].
    pub armature: f32,
    /// Viscous joint damping when randomisation is off (N m s/rad); middle of [0.25, 0.35].
    pub joint_damping: f32,
    /// Coulomb joint friction torque when randomisation is off (N m); middle of [0.005, 0.01].
    pub joint_friction: f32,
    /// Hip joints lie within this many joint indices: index `3 * leg` is the hip of each leg.
    pub joints_per_leg: usize,
}

impl Default for RobotConfig {
    fn default() -> Self {
        let legs = ["FL", "FR", "RL", "RR"];
        let parts = ["hip", "thigh", "calf"];
        Self {
            joint_names: legs
                .iter()
                .flat_map(|l| parts.iter().map(move |p| format!("{l}_{p}_joint")))
                .collect(),
            foot_names: legs.iter().map(|l| format!("{l}_foot")).collect(),
            trunk_link: "base".into(),
            head_colliders: vec!["base_head_upper".into(), "base_head_lower".into()],
            penalised_links: vec!["thigh".into(), "calf".into()],
            default_joint_pos: vec![
                0.1, 0.8, -1.5, // FL
                -0.1, 0.8, -1.5, // FR
                0.1, 1.0, -1.5, // RL
                -0.1, 1.0, -1.5, // RR
            ],
            kp: 20.0,
            kd: 0.5,
            armature: 0.02,
            joint_damping: 0.3,
            joint_friction: 0.0075,
            joints_per_leg: 3,
        }
    }
}
