//! Joint angle and speed of an impulse (maximal-coordinate) revolute joint, read back from the
//! two bodies' states: the twist of their relative rotation about the joint axis.

use rapier3d::math::{Rotation, Vec3};

/// Angle (rad, in [-pi, pi]) of `child_rot` relative to `parent_rot` about `axis` (a unit vector in
/// the child frame, equal to the parent frame at zero angle). The swing part of the relative
/// rotation (joint drift) is ignored.
#[inline]
pub fn joint_angle(parent_rot: Rotation, child_rot: Rotation, axis: Vec3) -> f32 {
    let rel = parent_rot.inverse() * child_rot;
    let along = rel.x * axis.x + rel.y * axis.y + rel.z * axis.z;
    let mut angle = 2.0 * along.atan2(rel.w);
    if angle > std::f32::consts::PI {
        angle -= std::f32::consts::TAU;
    } else if angle < -std::f32::consts::PI {
        angle += std::f32::consts::TAU;
    }
    angle
}

/// Joint speed (rad/s): relative angular velocity projected on the world joint axis.
#[inline]
pub fn joint_speed(
    child_rot: Rotation,
    parent_angvel: Vec3,
    child_angvel: Vec3,
    axis: Vec3,
) -> f32 {
    (child_angvel - parent_angvel).dot(child_rot * axis)
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn angle_is_recovered_for_any_parent_pose() {
        let parent = Rotation::from_euler(rapier3d::math::glamx::EulerRot::XYZ, 0.3, -1.2, 2.0);
        for &q in &[-2.9f32, -1.5, 0.0, 0.7, 3.0] {
            let child = parent * Rotation::from_axis_angle(Vec3::Y, q);
            assert!(
                (joint_angle(parent, child, Vec3::Y) - q).abs() < 1e-5,
                "q = {q}"
            );
        }
    }

    #[test]
    fn speed_is_relative_rate_about_axis() {
        let child = Rotation::from_rotation_z(0.5);
        let w = joint_speed(
            child,
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(0.0, 0.0, 3.0),
            Vec3::Z,
        );
        assert!((w - 2.0).abs() < 1e-6);
    }
}
