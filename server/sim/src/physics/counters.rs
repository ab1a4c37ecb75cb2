//! Where a rapier world's physics step spends its time: rapier's own stage timers (its
//! `profiler` feature) summed over steps, plus our work around its pipeline.
//!
//! Rapier's stages nest: broad and narrow phase are inside collision detection, constraint
//! assembly and resolution inside the solver. The top-level stages and rapier's remainder add up
//! to its step time; ours (torques before, bookkeeping after, read-back) lie outside it.

use rapier3d::counters::Counters;
use serde::Serialize;

/// Time (s) and work, summed over a world's physics steps since it was built.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PhysicsCounters {
    /// Physics steps of the world.
    pub world_steps: u64,
    /// Robot physics steps: each world step counts its robots.
    pub robot_steps: u64,
    /// Our whole `RobotWorld::step`, rapier's pipeline included.
    pub step_s: f64,
    /// Ours, before the pipeline: joint angles and speeds, PD, passive and stop torques.
    pub torques_s: f64,
    /// Rapier's `PhysicsPipeline::step` (its own step timer).
    pub pipeline_s: f64,
    /// Rapier: applying user changes (wake-ups, modified bodies and colliders, joint edits).
    pub user_changes_s: f64,
    /// Rapier: collision detection (broad phase, narrow phase, end-of-step AABB updates).
    pub collision_detection_s: f64,
    /// Rapier, inside collision detection: the broad phase.
    pub broad_phase_s: f64,
    /// Rapier, inside collision detection: the narrow phase (contact manifolds).
    pub narrow_phase_s: f64,
    /// Rapier: island construction (connectivity, sleep, substep groups).
    pub island_construction_s: f64,
    /// Rapier: collecting the islands' contact and joint constraints for the solver.
    pub constraints_collection_s: f64,
    /// Rapier: body updates (effective forces; integration to the final positions).
    pub update_s: f64,
    /// Rapier: the constraint solver (assembly, substeps, PGS, write-back).
    pub solver_s: f64,
    /// Rapier, inside the solver: constraint assembly.
    pub assembly_s: f64,
    /// Rapier, inside the solver: velocity resolution (substeps and PGS iterations).
    pub resolution_s: f64,
    /// Rapier: continuous collision detection (time-of-impact sweeps).
    pub ccd_s: f64,
    /// Rapier: its step time not in a stage above (kinematic velocities, soft bodies, ...).
    pub rapier_other_s: f64,
    /// Ours, after the pipeline: quarantined bodies, leg contacts, extra-iteration flags.
    pub after_s: f64,
    /// Ours, once per policy step: `RobotWorld::read_states` (poses, joints, feet, contacts).
    pub read_back_s: f64,
    /// Contact pairs in the narrow phase, summed over steps.
    pub contact_pairs: u64,
    /// Contact points the solver saw, summed over steps.
    pub contacts: u64,
    /// Constraints (contact manifolds and joints) the solver saw, summed over steps.
    pub constraints: u64,
}

impl PhysicsCounters {
    /// Add one pipeline step's counters from rapier (timers are per step: rapier resets them
    /// at the start of each).
    pub(crate) fn add_rapier(&mut self, c: &Counters) {
        let s = &c.stages;
        let stages = [
            s.user_changes.time(),
            s.collision_detection_time.time(),
            s.island_construction_time.time(),
            s.island_constraints_collection_time.time(),
            s.update_time.time(),
            s.solver_time.time(),
            c.ccd.toi_computation_time.time(),
        ]
        .map(|d| d.as_secs_f64());
        let pipeline = c.step_time().as_secs_f64();
        self.pipeline_s += pipeline;
        self.user_changes_s += stages[0];
        self.collision_detection_s += stages[1];
        self.island_construction_s += stages[2];
        self.constraints_collection_s += stages[3];
        self.update_s += stages[4];
        self.solver_s += stages[5];
        self.ccd_s += stages[6];
        self.rapier_other_s += pipeline - stages.iter().sum::<f64>();
        self.broad_phase_s +=
            (c.cd.broad_phase_time.time() + c.cd.final_broad_phase_time.time()).as_secs_f64();
        self.narrow_phase_s += c.cd.narrow_phase_time.time().as_secs_f64();
        self.assembly_s += c.solver.velocity_assembly_time.time().as_secs_f64();
        self.resolution_s += c.solver.velocity_resolution_time.time().as_secs_f64();
        self.contact_pairs += c.cd.ncontact_pairs as u64;
        self.contacts += c.solver.ncontacts as u64;
        self.constraints += c.solver.nconstraints as u64;
    }

    /// The element-wise sum of two sets (worlds added together).
    pub fn plus(&self, o: &Self) -> Self {
        self.zip(o, |a, b| a + b, |a, b| a + b)
    }

    /// The element-wise difference `self - earlier` (the steps between two readings).
    pub fn minus(&self, earlier: &Self) -> Self {
        self.zip(earlier, |a, b| a - b, u64::saturating_sub)
    }

    fn zip(&self, o: &Self, f: impl Fn(f64, f64) -> f64, n: impl Fn(u64, u64) -> u64) -> Self {
        Self {
            world_steps: n(self.world_steps, o.world_steps),
            robot_steps: n(self.robot_steps, o.robot_steps),
            step_s: f(self.step_s, o.step_s),
            torques_s: f(self.torques_s, o.torques_s),
            pipeline_s: f(self.pipeline_s, o.pipeline_s),
            user_changes_s: f(self.user_changes_s, o.user_changes_s),
            collision_detection_s: f(self.collision_detection_s, o.collision_detection_s),
            broad_phase_s: f(self.broad_phase_s, o.broad_phase_s),
            narrow_phase_s: f(self.narrow_phase_s, o.narrow_phase_s),
            island_construction_s: f(self.island_construction_s, o.island_construction_s),
            constraints_collection_s: f(self.constraints_collection_s, o.constraints_collection_s),
            update_s: f(self.update_s, o.update_s),
            solver_s: f(self.solver_s, o.solver_s),
            assembly_s: f(self.assembly_s, o.assembly_s),
            resolution_s: f(self.resolution_s, o.resolution_s),
            ccd_s: f(self.ccd_s, o.ccd_s),
            rapier_other_s: f(self.rapier_other_s, o.rapier_other_s),
            after_s: f(self.after_s, o.after_s),
            read_back_s: f(self.read_back_s, o.read_back_s),
            contact_pairs: n(self.contact_pairs, o.contact_pairs),
            contacts: n(self.contacts, o.contacts),
            constraints: n(self.constraints, o.constraints),
        }
    }
}
