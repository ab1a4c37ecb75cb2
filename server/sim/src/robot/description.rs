//! A robot as its URDF describes it: links with inertia and primitive shapes, revolute joints.
//!
//! Only what a simulator of a legged robot needs is kept. Frames follow URDF: each link frame sits
//! at its parent joint, and a joint's `origin` places the child frame in the parent frame.

use rapier3d::math::{Mat3, Pose, Rotation, Vec3};

/// A primitive shape, in the frame of its element's `origin`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// A box with full side lengths along x, y, z.
    Box {
        /// Full extents (m).
        size: Vec3,
    },
    /// A cylinder along the local z axis.
    Cylinder {
        /// Radius (m).
        radius: f32,
        /// Full length (m).
        length: f32,
    },
    /// A sphere.
    Sphere {
        /// Radius (m).
        radius: f32,
    },
}

/// A collision or visual element of a link.
#[derive(Clone, Debug, PartialEq)]
pub struct Geometry {
    /// The element's `name` attribute (may be empty).
    pub name: String,
    /// Pose of the shape in the link frame.
    pub origin: Pose,
    /// The shape.
    pub shape: Shape,
}

/// Mass properties of a link, in the link frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inertial {
    /// Mass (kg).
    pub mass: f32,
    /// Centre of mass in the link frame (m).
    pub com: Vec3,
    /// Inertia tensor about the centre of mass, in the link frame's axes (kg m^2).
    pub inertia: Mat3,
}

/// A rigid link.
#[derive(Clone, Debug, PartialEq)]
pub struct Link {
    /// The URDF link name.
    pub name: String,
    /// Mass properties.
    pub inertial: Inertial,
    /// Collision shapes.
    pub collisions: Vec<Geometry>,
    /// Visual shapes (primitives only).
    pub visuals: Vec<Geometry>,
}

/// A revolute joint between two links.
#[derive(Clone, Debug, PartialEq)]
pub struct Joint {
    /// The URDF joint name.
    pub name: String,
    /// Index of the parent link in [`RobotDescription::links`].
    pub parent: usize,
    /// Index of the child link in [`RobotDescription::links`].
    pub child: usize,
    /// Pose of the child frame in the parent frame at zero joint angle.
    pub origin: Pose,
    /// Unit rotation axis, in the child (= joint) frame.
    pub axis: Vec3,
    /// Lower position limit (rad).
    pub lower: f32,
    /// Upper position limit (rad).
    pub upper: f32,
    /// Effort (torque) limit (N m).
    pub effort: f32,
    /// Velocity limit (rad/s).
    pub velocity: f32,
}

/// A tree of links joined by revolute joints, rooted at `links[root]`.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotDescription {
    /// The robot's name.
    pub name: String,
    /// All links.
    pub links: Vec<Link>,
    /// All revolute joints.
    pub joints: Vec<Joint>,
    /// Index of the root link (the one that is no joint's child).
    pub root: usize,
}

impl RobotDescription {
    /// Index of the link with this name.
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l.name == name)
    }

    /// Index of the joint with this name.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Total mass of all links (kg).
    pub fn total_mass(&self) -> f32 {
        self.links.iter().map(|l| l.inertial.mass).sum()
    }
}

/// Pose from URDF `xyz` and `rpy` (fixed-axis roll about x, then pitch about y, then yaw about z).
pub fn pose_from_xyz_rpy(xyz: Vec3, rpy: Vec3) -> Pose {
    let rotation = Rotation::from_rotation_z(rpy.z)
        * Rotation::from_rotation_y(rpy.y)
        * Rotation::from_rotation_x(rpy.x);
    Pose::from_parts(xyz, rotation)
}
