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
