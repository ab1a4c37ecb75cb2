//! A robot description resolved against its config: bodies in tree order, joints in action order,
//! feet and collider roles as indices, ready for the physics layer.

use rapier3d::math::{Pose, Rotation, Vec3};

use super::config::{NUM_FEET, NUM_JOINTS, RobotConfig};
use super::description::{Geometry, Inertial, RobotDescription};
use crate::error::SimError;

/// Effective range of a simulated joint. Revolute angles are measured in [-pi, pi], so a URDF
/// range reaching past that (the Go2 thigh goes to 260 deg) is cut 0.5 rad inside it: a joint
/// that overshoots its stop must not wrap around to the far side. The cut part of the range
/// (thigh beyond 151 deg, calf beyond -151 deg) folds the leg into the trunk and plays no role
/// in locomotion.
pub const SIM_ANGLE_BOUND: f32 = std::f32::consts::PI - 0.5;

/// What a collider's contact with the terrain means to the task.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ColliderRole {
    /// Part of the trunk: contact terminates the episode.
    Trunk,
    /// The head (Unitree's Head_upper and Head_lower). In the paper's simulator the head stays a
    /// body of its own (`dont_collapse`) that neither legged_gym's termination ("base") nor its
    /// penalty ("thigh", "calf") names: its contact neither ends the episode nor costs reward,
    /// so a robot starting nose-down can rest on its head and push up onto its front legs. It
    /// is reported (head hits are the paper's failure on biped stairs).
    Head,
    /// A penalised link (thigh, calf): contact costs a collision penalty.
    Penalised,
    /// A foot (index in leg order).
    Foot(u8),
    /// Anything else (hips).
    Other,
}

/// One collider of a body, with its role.
#[derive(Clone, Debug, PartialEq)]
pub struct ColliderModel {
    /// Shape and pose in the body frame.
    pub geometry: Geometry,
    /// Role in the task.
    pub role: ColliderRole,
}

/// One rigid body of the robot.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyModel {
    /// Link name.
    pub name: String,
    /// Parent body index (None for the trunk, which is body 0).
    pub parent: Option<usize>,
    /// Index of the joint (in action order) that moves this body relative to its parent.
    pub joint: Option<usize>,
    /// Mass properties.
    pub inertial: Inertial,
    /// Colliders.
    pub colliders: Vec<ColliderModel>,
}

/// One actuated joint, in action order.
#[derive(Clone, Debug, PartialEq)]
pub struct JointModel {
    /// Joint name.
    pub name: String,
    /// Parent body index.
    pub parent_body: usize,
    /// Child body index.
    pub child_body: usize,
    /// Child frame in the parent frame at zero angle.
    pub origin: Pose,
    /// Unit axis in the child frame (= the parent frame at zero angle, as link frames align).
    pub axis: Vec3,
    /// URDF lower limit (rad); used for soft limits in rewards.
    pub lower: f32,
    /// URDF upper limit (rad).
    pub upper: f32,
    /// Lower limit enforced by the simulator (rad).
    pub sim_lower: f32,
    /// Upper limit enforced by the simulator (rad).
    pub sim_upper: f32,
    /// Torque limit (N m).
    pub effort: f32,
    /// Velocity limit (rad/s).
    pub velocity: f32,
}

/// A foot: a sphere on a body.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FootModel {
    /// Body carrying the foot.
    pub body: usize,
    /// Sphere centre in that body's frame.
    pub offset: Vec3,
    /// Sphere radius (m).
    pub radius: f32,
}

/// The resolved robot.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotModel {
    /// Bodies; body 0 is the trunk and every parent precedes its children.
    pub bodies: Vec<BodyModel>,
    /// Joints in action order.
    pub joints: [JointModel; NUM_JOINTS],
    /// Feet in leg order.
    pub feet: [FootModel; NUM_FEET],
    /// The config it was built from.
    pub config: RobotConfig,
}

impl RobotModel {
    /// Resolve `description` with `config`, checking that every name exists.
    pub fn new(description: &RobotDescription, config: &RobotConfig) -> Result<Self, SimError> {
        let err = |m: String| SimError::Robot(m);
        if config.joint_names.len() != NUM_JOINTS {
            return Err(err(format!(
                "{} joint names given, {NUM_JOINTS} needed",
                config.joint_names.len()
            )));
        }
        if config.default_joint_pos.len() != NUM_JOINTS {
            return Err(err(format!(
                "{} default joint angles given, {NUM_JOINTS} needed",
                config.default_joint_pos.len()
            )));
        }
        if config.foot_names.len() != NUM_FEET {
            return Err(err(format!(
                "{} feet given, {NUM_FEET} needed",
                config.foot_names.len()
            )));
        }
        let trunk = description
            .link_index(&config.trunk_link)
            .ok_or_else(|| err(format!("no link named `{}`", config.trunk_link)))?;
        if trunk != description.root {
            return Err(err(format!(
                "trunk `{}` is not the root link",
                config.trunk_link
            )));
        }
        // Bodies in breadth-first order from the trunk, so parents come first.
        let mut order = vec![trunk];
        let mut i = 0;
        while i < order.len() {
            let parent = order[i];
            for j in description.joints.iter().filter(|j| j.parent == parent) {
                order.push(j.child);
            }
            i += 1;
        }
        if order.len() != description.links.len() {
            return Err(err("some links are not connected to the trunk".into()));
        }
        let body_of_link = |link: usize| order.iter().position(|&l| l == link).unwrap_or(0);

        let mut joint_order = Vec::with_capacity(NUM_JOINTS);
        for name in &config.joint_names {
            let j = description
                .joint_index(name)
                .ok_or_else(|| err(format!("no joint named `{name}`")))?;
            joint_order.push(j);
        }
        let joints: Vec<JointModel> = joint_order
            .iter()
            .map(|&j| {
                let d = &description.joints[j];
                JointModel {
                    name: d.name.clone(),
                    parent_body: body_of_link(d.parent),
                    child_body: body_of_link(d.child),
                    origin: d.origin,
                    axis: d.axis,
                    lower: d.lower,
                    upper: d.upper,
                    sim_lower: d.lower.max(-SIM_ANGLE_BOUND),
                    sim_upper: d.upper.min(SIM_ANGLE_BOUND),
                    effort: d.effort,
                    velocity: d.velocity,
                }
            })
            .collect();
        for (j, q0) in joints.iter().zip(&config.default_joint_pos) {
            if !(j.sim_lower..=j.sim_upper).contains(q0) {
                return Err(err(format!(
                    "default angle {q0} of `{}` is outside its limits",
                    j.name
                )));
            }
            if j.origin.rotation.angle_between(Rotation::IDENTITY) > 1e-6 {
                return Err(err(format!(
                    "joint `{}` has a rotated origin; only aligned link frames are supported",
                    j.name
                )));
            }
        }

        let mut feet = Vec::with_capacity(NUM_FEET);
        let mut bodies = Vec::with_capacity(order.len());
        for (b, &link) in order.iter().enumerate() {
            let l = &description.links[link];
            let parent_joint = joints.iter().position(|j| j.child_body == b);
            if b > 0 && parent_joint.is_none() {
                return Err(err(format!(
                    "link `{}` hangs on a joint that is not actuated",
                    l.name
                )));
            }
            let colliders = l
                .collisions
                .iter()
                .map(|g| {
                    let role = if let Some(f) = config.foot_names.iter().position(|n| *n == g.name)
                    {
                        ColliderRole::Foot(f as u8)
                    } else if config.head_colliders.contains(&g.name) {
                        ColliderRole::Head
                    } else if b == 0 {
                        ColliderRole::Trunk
                    } else if config
                        .penalised_links
                        .iter()
                        .any(|p| l.name.contains(p.as_str()))
                    {
                        ColliderRole::Penalised
                    } else {
                        ColliderRole::Other
                    };
                    ColliderModel {
                        geometry: g.clone(),
                        role,
                    }
                })
                .collect();
            bodies.push(BodyModel {
                name: l.name.clone(),
                parent: parent_joint.map(|j| joints[j].parent_body),
                joint: parent_joint,
                inertial: l.inertial,
                colliders,
            });
        }
        for name in &config.head_colliders {
            let found = bodies.iter().any(|body| {
                body.colliders
                    .iter()
                    .any(|c| c.geometry.name == *name && c.role == ColliderRole::Head)
            });
            if !found {
                return Err(err(format!("no head collision element named `{name}`")));
            }
        }
        for name in &config.foot_names {
            let found = bodies.iter().enumerate().find_map(|(b, body)| {
                body.colliders
                    .iter()
                    .find(|c| c.geometry.name == *name)
                    .map(|c| (b, c))
            });
            let (b, c) =
                found.ok_or_else(|| err(format!("no collision element named `{name}`")))?;
            let radius = match c.geometry.shape {
                super::description::Shape::Sphere { radius } => radius,
                _ => return Err(err(format!("foot `{name}` is not a sphere"))),
            };
            feet.push(FootModel {
                body: b,
                offset: c.geometry.origin.translation,
                radius,
            });
        }
        let joints: [JointModel; NUM_JOINTS] =
            joints.try_into().map_err(|_| err("joint count".into()))?;
        let feet: [FootModel; NUM_FEET] = feet.try_into().map_err(|_| err("foot count".into()))?;
        Ok(Self {
            bodies,
            joints,
            feet,
            config: config.clone(),
        })
    }

    /// The embedded Go2 (our URDF in `assets/go2/`, compiled in) with the default config.
    pub fn go2() -> Self {
        let description =
            super::urdf::parse_urdf(GO2_URDF).expect("the embedded Go2 URDF is valid");
        Self::new(&description, &RobotConfig::default())
            .expect("the embedded Go2 config fits its URDF")
    }

    /// Poses of all bodies in the trunk frame for the given joint angles (forward kinematics).
    pub fn forward_kinematics(&self, q: &[f32; NUM_JOINTS]) -> Vec<Pose> {
        let mut poses = vec![Pose::IDENTITY; self.bodies.len()];
        for (b, body) in self.bodies.iter().enumerate().skip(1) {
            if let (Some(p), Some(j)) = (body.parent, body.joint) {
                let joint = &self.joints[j];
                let local = Pose::from_parts(
                    joint.origin.translation,
                    Rotation::from_axis_angle(joint.axis, q[j]),
                );
                poses[b] = poses[p] * local;
            }
        }
        poses
    }

    /// Indices of the hip joints (first joint of each leg).
    pub fn hip_joints(&self) -> impl Iterator<Item = usize> + '_ {
        (0..NUM_FEET).map(|leg| leg * self.config.joints_per_leg)
    }
}

/// Our Go2 URDF, embedded so the binaries run without an assets directory.
pub const GO2_URDF: &str = include_str!("../../../../assets/go2/go2.urdf");
