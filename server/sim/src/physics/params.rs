//! The physics' numerical settings (time step, solver schedule, inertia floor), part of the
//! task config's `[physics]` table.

use super::engine::EngineKind;

/// Numerical settings of the physics.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PhysicsParams {
    /// The dynamics: `"articulated"` (reduced coordinates, issue 34; default) or `"rapier"`
    /// (impulse joints). The articulated engine reads `dt` and `gravity` only; the solver
    /// schedule and the inertia floor below are rapier's.
    pub engine: EngineKind,
    /// Physics time step (s). Default 0.005 (200 Hz).
    pub dt: f32,
    /// Rapier solver iterations per step, i.e. substeps of its soft-TGS solver. Default 2:
    /// substeps re-linearise every joint and contact, PGS iterations within a substep are much
    /// cheaper; with one substep a dropped robot's trunk touches the ground on landing.
    pub solver_iterations: usize,
    /// Rapier internal PGS iterations per substep. Default 3: the worst joint anchor gap under
    /// random actions stays near 3 mm (docs/src/decisions/0002-joint-fidelity.md).
    pub pgs_iterations: usize,
    /// Gravity along -z (m/s^2). Default 9.81.
    pub gravity: f32,
    /// Extra substeps for a robot whose hips, thighs or calves touch the terrain or whose joints
    /// near their stops (a fallen or sprawled robot). Default 0: extra PGS iterations are cheaper.
    pub extra_iterations_on_leg_contact: usize,
    /// Extra PGS iterations per substep for the same robots. Default 6: contacts on the light leg
    /// links need them to keep joint anchors within 5 mm (without them a robot lying on its legs
    /// drifts up to 12 mm, with 4 up to 6 mm); about 15% of robots need them under random
    /// actions, 68% when fallen robots are never reset.
    pub extra_pgs_iterations_on_leg_contact: usize,
    /// Whether a robot whose head touches the terrain (and nothing but its feet otherwise) also
    /// gets those extra iterations. Default true.
    pub extra_iterations_on_head_contact: bool,
    /// Floor on each diagonal entry of a leg link's inertia tensor (kg m^2). Default 0.002.
    /// The Go2's hips and calves are very light about the axes they do not turn on (down to
    /// 4e-5), and an impulse solver shares the motors' reaction torques badly through such
    /// links: under the random initial states joint anchors drifted up to 10 mm at 4 iterations.
    /// With the floor the worst drift stays under 5 mm; the legs' inertia about the trunk's axes
    /// (dominated by m r^2, ~0.02 per leg) changes by under 10%.
    pub min_link_inertia: f32,
}

impl Default for PhysicsParams {
    fn default() -> Self {
        Self {
            engine: EngineKind::Articulated,
            dt: 0.005,
            solver_iterations: 2,
            pgs_iterations: 3,
            gravity: 9.81,
            extra_iterations_on_leg_contact: 0,
            extra_pgs_iterations_on_leg_contact: 6,
            extra_iterations_on_head_contact: true,
            min_link_inertia: 0.002,
        }
    }
}
