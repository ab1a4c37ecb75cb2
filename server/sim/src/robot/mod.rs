//! The robot: its description (URDF), its config and the resolved model.

mod config;
mod description;
mod model;
mod urdf;

pub use config::{NUM_FEET, NUM_JOINTS, RobotConfig};
pub use description::{
    Geometry, Inertial, Joint, Link, RobotDescription, Shape, pose_from_xyz_rpy,
};
pub use model::{
    BodyModel, ColliderModel, ColliderRole, FootModel, GO2_URDF, JointModel, RobotModel,
    SIM_ANGLE_BOUND,
};
pub use urdf::{load_urdf, parse_urdf};
