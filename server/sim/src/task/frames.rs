//! Orientation measures that stay defined in both stances.
//!
//! Euler roll and yaw are singular at pitch = pi/2, the biped stance. We keep Euler pitch (the
//! paper's quantity, positive nose down, as legged_gym's `get_euler_xyz`), measure roll by the
//! lateral component of gravity in the base frame, and measure heading from the horizontal
//! projection of the body's x axis plus its z axis: on four legs that is the nose direction, and
//! standing on the front legs (nose down) the back faces the same way, so the heading frame
//! stays continuous through the transition.

use rapier3d::math::{Rotation, Vec2, Vec3};

/// Gravity direction in the base frame (unit; (0, 0, -1) when level).
pub fn projected_gravity(rot: Rotation) -> Vec3 {
    rot.inverse() * Vec3::NEG_Z
}

/// Euler pitch (XYZ convention, positive nose down), in [-pi/2, pi/2].
pub fn euler_pitch(rot: Rotation) -> f32 {
    let (x, y, z, w) = (rot.x, rot.y, rot.z, rot.w);
    (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin()
}

/// Unit heading direction (world xy) of the body; see the module doc.
pub fn heading_direction(rot: Rotation) -> Vec2 {
    let x = rot * Vec3::X;
    let z = rot * Vec3::Z;
    let h = Vec2::new(x.x + z.x, x.y + z.y);
    if h.length_squared() > 1e-8 {
        return h.normalize();
    }
    let fallback = Vec2::new(x.x, x.y);
    if fallback.length_squared() > 1e-8 {
        fallback.normalize()
    } else {
        Vec2::X
    }
}

/// Heading angle (rad, world, counterclockwise from +x) of the body; see [`heading_direction`].
pub fn heading_yaw(rot: Rotation) -> f32 {
    let h = heading_direction(rot);
    h.y.atan2(h.x)
}

/// The turn (rad, in [-pi, pi), counterclockwise positive) that takes heading `from` to `to`.
pub fn angle_from(from: f32, to: f32) -> f32 {
    use std::f32::consts::{PI, TAU};
    (to - from + PI).rem_euclid(TAU) - PI
}

/// The yaw-rate command that steers heading `yaw` to `target` (rad): `gain` times the turn the
/// short way round, within `range` (the mode's yaw-rate command range). The traversals steer
/// with it (decision record 0032), and training can hold a drawn heading with it (0042).
pub fn heading_hold(target: f32, yaw: f32, gain: f32, range: [f32; 2]) -> f32 {
    (gain * angle_from(yaw, target)).clamp(range[0], range[1])
}

/// A world vector's xy part expressed in the heading frame (x along the heading).
pub fn to_heading_frame(heading: Vec2, v: Vec3) -> Vec2 {
    Vec2::new(
        heading.x * v.x + heading.y * v.y,
        -heading.y * v.x + heading.x * v.y,
    )
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn angles_between_headings_take_the_short_way_round() {
        use std::f32::consts::PI;
        let close = |a: f32, b: f32| assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        close(angle_from(0.0, 0.5), 0.5);
        close(angle_from(0.5, 0.0), -0.5);
        // From 170 deg to -170 deg is 20 deg counterclockwise, not 340 clockwise.
        close(
            angle_from(170f32.to_radians(), -170f32.to_radians()),
            20f32.to_radians(),
        );
        close(angle_from(-3.0, 3.0), 6.0 - 2.0 * PI);
    }

    /// Gain 1: 0.3 rad off steers back at 0.3 rad/s; 2 rad off is clamped to the biped's 0.5;
    /// an error past pi wraps to the short way round (3.0 - (-3.0) = 6.0 is -0.28 rad).
    #[test]
    fn the_heading_hold_steers_the_short_way_within_the_range() {
        let close = |a: f32, b: f32| assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        let biped = [-0.5, 0.5];
        close(heading_hold(0.0, -0.3, 1.0, biped), 0.3);
        close(heading_hold(0.0, 0.3, 1.0, biped), -0.3);
        close(heading_hold(0.0, 2.0, 1.0, biped), -0.5);
        close(
            heading_hold(3.0, -3.0, 1.0, [-1.0, 1.0]),
            6.0 - std::f32::consts::TAU,
        );
        close(heading_hold(1.0, 1.0, 1.0, [-1.0, 1.0]), 0.0);
        // A range that is not symmetric bounds each side by its own end.
        close(heading_hold(0.0, 2.0, 1.0, [-0.2, 1.0]), -0.2);
        assert_eq!(heading_hold(0.0, 0.4, 0.0, [-1.0, 1.0]), 0.0);
    }

    #[test]
    fn the_heading_yaw_is_the_nose_on_four_legs_and_the_back_on_two() {
        let turned = Rotation::from_rotation_z(0.8);
        assert!((heading_yaw(turned) - 0.8).abs() < 1e-5);
        // Pitched nose-down onto the front legs (the biped stance), the heading stays.
        let biped = turned * Rotation::from_rotation_y(1.5);
        assert!((heading_yaw(biped) - 0.8).abs() < 1e-4);
    }

    #[test]
    fn pitch_is_positive_nose_down() {
        let r = Rotation::from_rotation_y(0.7);
        assert!((euler_pitch(r) - 0.7).abs() < 1e-5);
        // Nose down: the body x axis points below the horizon.
        assert!((r * Vec3::X).z < 0.0);
        let g = projected_gravity(Rotation::IDENTITY);
        assert!((g - Vec3::NEG_Z).length() < 1e-6);
    }

    #[test]
    fn heading_survives_the_biped_stance() {
        let yaw = 0.8f32;
        for pitch in [0.0f32, 0.5, 1.2, std::f32::consts::FRAC_PI_2 - 1e-4, 1.9] {
            let r = Rotation::from_rotation_z(yaw) * Rotation::from_rotation_y(pitch);
            let h = heading_direction(r);
            assert!((h.y.atan2(h.x) - yaw).abs() < 1e-4, "pitch {pitch}");
        }
        let v = to_heading_frame(Vec2::new(0.0, 1.0), Vec3::new(0.0, 2.0, 5.0));
        assert!((v - Vec2::new(2.0, 0.0)).length() < 1e-6);
    }
}
