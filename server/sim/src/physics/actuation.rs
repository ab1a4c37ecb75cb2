//! The joint actuator: an explicit PD law clipped to the motor limit, plus the joint's passive
//! damping and Coulomb friction (which the motor limit does not clip: they are not the motor).

/// Per-env actuator parameters (nominal values scaled by domain randomisation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorParams {
    /// PD stiffness (N m/rad).
    pub kp: f32,
    /// PD damping (N m s/rad).
    pub kd: f32,
    /// Passive viscous damping (N m s/rad).
    pub damping: f32,
    /// Passive Coulomb friction torque (N m).
    pub friction: f32,
}

/// Joint speed (rad/s) below which Coulomb friction ramps linearly instead of switching sign:
/// an ideal sign() would chatter at rest under an explicit integrator.
pub const FRICTION_RAMP_SPEED: f32 = 0.01;

/// Motor torque of the PD law, clipped to `effort` (N m): `kp (target - q) - kd qdot`.
#[inline]
pub fn pd_torque(target: f32, q: f32, qd: f32, kp: f32, kd: f32, effort: f32) -> f32 {
    (kp * (target - q) - kd * qd).clamp(-effort, effort)
}

/// Passive joint torque from viscous damping and (ramped) Coulomb friction (N m).
#[inline]
pub fn passive_torque(qd: f32, damping: f32, friction: f32) -> f32 {
    -damping * qd - friction * (qd / FRICTION_RAMP_SPEED).clamp(-1.0, 1.0)
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn pd_torque_is_the_pd_law_within_limits() {
        // 20 * (0.5 - 0.2) - 0.5 * 2 = 6 - 1 = 5
        assert!((pd_torque(0.5, 0.2, 2.0, 20.0, 0.5, 23.7) - 5.0).abs() < 1e-6);
        assert_eq!(pd_torque(10.0, 0.0, 0.0, 20.0, 0.5, 23.7), 23.7);
        assert_eq!(pd_torque(-10.0, 0.0, 0.0, 20.0, 0.5, 35.55), -35.55);
    }

    #[test]
    fn passive_torque_opposes_motion() {
        assert!((passive_torque(2.0, 0.3, 0.01) - (-0.6 - 0.01)).abs() < 1e-6);
        assert!((passive_torque(-0.005, 0.0, 0.01) - 0.005).abs() < 1e-6);
        assert_eq!(passive_torque(0.0, 0.3, 0.01), 0.0);
    }
}
