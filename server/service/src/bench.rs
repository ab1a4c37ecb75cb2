//! `unigait-server bench`: env steps per second of the simulation core, in process.

use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use unigait_sim::physics::{EngineKind, PhysicsCounters};
use unigait_sim::prelude::*;
use unigait_sim::task::projected_gravity;

/// Which actions the benchmark sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BenchActions {
    /// All zeros: hold the default pose.
    Stand,
    /// Uniform in [-1, 1] per joint, new every step (joint targets +-0.25 rad around default).
    Random,
}

/// Benchmark settings.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchArgs {
    /// Number of envs.
    #[arg(long, default_value_t = 512)]
    pub envs: usize,
    /// Policy steps to time (after a warm-up of 20).
    #[arg(long, default_value_t = 200)]
    pub steps: usize,
    /// Worker threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Actions to send.
    #[arg(long, value_enum, default_value_t = BenchActions::Random)]
    pub actions: BenchActions,
    /// Bare physics (no observations, rewards or episodes).
    #[arg(long)]
    pub physics_only: bool,
    /// Terrain: flat, curriculum (the mixed grid), or one type pinned at `--level`
    /// (slope_up, slope_down, rough_slope, stairs_up, stairs_down, obstacles).
    #[arg(long, default_value = "flat")]
    pub terrain: String,
    /// Level of a pinned terrain type (0 .. 9), or the highest starting level of the curriculum.
    #[arg(long, default_value_t = 0)]
    pub level: u32,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The loop MuJoCo's side of the comparison runs (`python -m unigait mujoco-bench`): every
    /// robot starts at the default pose, level and at rest, and a robot that falls (trunk origin
    /// less than 0.15 m above the ground or up axis tilted past 60 degrees) is put back at once.
    /// Without it, robots start in the task's random states (Table IV) and only the task's
    /// terminations reset them, so fallen robots resting on their heads stay in the batch.
    #[arg(long)]
    pub reference_loop: bool,
    /// Build the robots without their joints (13 free bodies each, torques still applied): the
    /// cost of rapier's pipeline outside the joint solver (rapier's engine only). The robots fall apart: not a
    /// simulation of the Go2.
    #[arg(long)]
    pub no_joints: bool,
    /// A TOML fragment overriding the task config, e.g. 'physics.solver_iterations = 8'.
    #[arg(long = "set")]
    pub overrides: Vec<String>,
    /// Print JSON only.
    #[arg(long)]
    pub json: bool,
}

/// What the benchmark measured.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    /// Policy (env) steps per second, all envs together.
    pub env_steps_per_sec: f64,
    /// Physics steps per second (env steps x decimation).
    pub physics_steps_per_sec: f64,
    /// Env steps per second divided by the thread count.
    pub env_steps_per_sec_per_thread: f64,
    /// Number of envs.
    pub envs: usize,
    /// Worker threads.
    pub threads: usize,
    /// Actions sent.
    pub actions: BenchActions,
    /// Timed policy steps.
    pub steps: usize,
    /// Bare physics or the full task.
    pub physics_only: bool,
    /// Terrain name.
    pub terrain: String,
    /// Worst joint anchor separation seen at any step (m).
    pub max_joint_gap_m: f32,
    /// Mean share of envs given extra solver iterations (legs on the ground, joints at stops).
    pub extra_iteration_share: f64,
    /// Envs reset after a physics blow-up.
    pub nonfinite_resets: u64,
    /// The comparison loop (`--reference-loop`) was run.
    pub reference_loop: bool,
    /// Robots put back after a fall during the timed steps (`--reference-loop` only).
    pub fall_resets: u64,
    /// Share of step time in physics (CPU time over groups).
    pub physics_share: f64,
    /// Wall time of the timed steps (s).
    pub wall_s: f64,
    /// The robots had no joints (`--no-joints`).
    pub no_joints: bool,
    /// Where a robot physics step's time went (us), from rapier's stage timers and ours.
    pub us_per_robot_step: StageMicros,
    /// Contact points the solver saw, per robot physics step.
    pub contacts_per_robot_step: f64,
    /// Contact pairs (collider pairs near enough to test) per robot physics step.
    pub contact_pairs_per_robot_step: f64,
    /// Constraints (contact manifolds and joints) the solver saw, per robot physics step.
    pub constraints_per_robot_step: f64,
}

/// Microseconds per robot physics step by stage, over the timed steps. Indented names in
/// the docs are parts of the stage above them.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StageMicros {
    /// Wall time times threads: everything, fall resets and the task included.
    pub wall: f64,
    /// The env layer's physics stage: actions to targets, the world's steps, the read-back.
    pub physics_stage: f64,
    /// Our `RobotWorld::step`: torques + rapier's pipeline + after.
    pub step: f64,
    /// Ours, before the pipeline: joint angles and speeds, PD, passive and stop torques.
    pub torques: f64,
    /// Rapier's pipeline step, the sum of the next seven stages and `rapier_other`.
    pub pipeline: f64,
    /// Rapier: user changes.
    pub user_changes: f64,
    /// Rapier: collision detection (broad + narrow phase and AABB updates).
    pub collision_detection: f64,
    /// Rapier, part of collision detection: broad phase.
    pub broad_phase: f64,
    /// Rapier, part of collision detection: narrow phase.
    pub narrow_phase: f64,
    /// Rapier: island construction.
    pub island_construction: f64,
    /// Rapier: collecting the constraints.
    pub constraints_collection: f64,
    /// Rapier: body updates (forces, integration to final positions).
    pub update: f64,
    /// Rapier: the solver.
    pub solver: f64,
    /// Rapier, part of the solver: constraint assembly.
    pub assembly: f64,
    /// Rapier, part of the solver: velocity resolution (substeps, PGS).
    pub resolution: f64,
    /// Rapier: CCD.
    pub ccd: f64,
    /// Rapier: the pipeline's time outside its timed stages.
    pub rapier_other: f64,
    /// Ours, after the pipeline: quarantine, leg contacts, extra-iteration flags.
    pub after: f64,
    /// Ours, once per policy step: reading the states back (spread over its physics steps).
    pub read_back: f64,
}

impl StageMicros {
    /// The timed steps' counters `c`, with the env layer's physics time and the wall time
    /// times threads (s), per robot physics step.
    fn per_robot_step(c: &PhysicsCounters, physics_stage_s: f64, wall_cpu_s: f64) -> Self {
        let us = |seconds: f64| seconds * 1e6 / c.robot_steps.max(1) as f64;
        Self {
            wall: us(wall_cpu_s),
            physics_stage: us(physics_stage_s),
            step: us(c.step_s),
            torques: us(c.torques_s),
            pipeline: us(c.pipeline_s),
            user_changes: us(c.user_changes_s),
            collision_detection: us(c.collision_detection_s),
            broad_phase: us(c.broad_phase_s),
            narrow_phase: us(c.narrow_phase_s),
            island_construction: us(c.island_construction_s),
            constraints_collection: us(c.constraints_collection_s),
            update: us(c.update_s),
            solver: us(c.solver_s),
            assembly: us(c.assembly_s),
            resolution: us(c.resolution_s),
            ccd: us(c.ccd_s),
            rapier_other: us(c.rapier_other_s),
            after: us(c.after_s),
            read_back: us(c.read_back_s),
        }
    }
}

/// `--reference-loop`'s start state: the default pose, level, at rest (Table IV's ranges
/// collapsed to zero); the robots' physical randomisation stays.
const REFERENCE_START: &str = "
[init]
hip = [0.0, 0.0]
thigh = [0.0, 0.0]
calf = [0.0, 0.0]
linvel = [0.0, 0.0]
angvel = [0.0, 0.0]
pitch = [0.0, 0.0]
yaw = [0.0, 0.0]
";

/// A robot has fallen when its trunk origin is this close to the ground (m)...
const FALLEN_HEIGHT_M: f32 = 0.15;
/// ... or its up axis has tilted this far: cos 60 degrees.
const FALLEN_UP_Z: f32 = 0.5;

/// Put fallen robots back at their start state; returns how many. `mask` is scratch, one entry
/// per env.
fn reset_fallen(env: &mut VecEnv, mask: &mut [u8]) -> Result<u64> {
    let mut count = 0;
    for (i, m) in mask.iter_mut().enumerate() {
        let s = env.robot_state(i);
        let ground = env.terrain().height(s.base_pos.x, s.base_pos.y);
        // The base's up axis in the world has the same z as gravity's, negated, in the base.
        let up_z = -projected_gravity(s.base_rot).z;
        let down = s.base_pos.z - ground < FALLEN_HEIGHT_M || up_z < FALLEN_UP_Z;
        *m = u8::from(down);
        count += u64::from(down);
    }
    if count > 0 {
        env.reset_envs(mask)?;
    }
    Ok(count)
}

/// Run the benchmark.
pub fn run(args: &BenchArgs) -> Result<BenchReport> {
    let threads = if args.threads == 0 {
        std::thread::available_parallelism()?.get()
    } else {
        args.threads
    };
    let model = Arc::new(RobotModel::go2());
    let mut config = TaskConfig::embedded_default();
    if args.reference_loop {
        config = config.with_overrides(REFERENCE_START)?;
    }
    for o in &args.overrides {
        config = config.with_overrides(o)?;
    }
    if args.no_joints && config.physics.engine != EngineKind::Rapier {
        anyhow::bail!(
            "--no-joints removes rapier's impulse joints; the articulated engine's joints are its \
             coordinates: add --set 'physics.engine = \"rapier\"'"
        );
    }
    let decimation = config.env.decimation;
    let selection = unigait_proto::v1::TerrainConfig {
        kind: args.terrain.clone(),
        level: args.level,
        initial_levels: Vec::new(),
        initial_mode_levels: Vec::new(),
        columns: Vec::new(),
    };
    let (terrain, _) = unigait_server::terrain_for(
        Some(&selection),
        args.seed,
        args.envs,
        &unigait_server::CostCaps::default(),
    )?;
    let options = VecEnvOptions {
        num_envs: args.envs,
        seed: args.seed,
        threads,
        physics_only: args.physics_only,
        autoreset: true,
    };
    let mut env = VecEnv::new(model, config, terrain, options)?;
    if args.no_joints {
        env.remove_joints();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let n = args.envs * NUM_JOINTS;
    // A pool of action batches, drawn before timing so the RNG is not measured.
    let pool: Vec<Vec<f32>> = match args.actions {
        BenchActions::Stand => vec![vec![0.0; n]],
        BenchActions::Random => (0..16)
            .map(|_| (0..n).map(|_| rng.random_range(-1.0..=1.0)).collect())
            .collect(),
    };
    let mut max_gap: f32 = 0.0;
    let mut fallen = vec![0u8; args.envs];
    for i in 0..20 {
        env.step(&pool[i % pool.len()])?;
        max_gap = max_gap.max(env.max_joint_gap());
        if args.reference_loop {
            reset_fallen(&mut env, &mut fallen)?;
        }
    }
    let mut extra_share = 0.0;
    let mut fall_resets = 0;
    let before = env.stage_times();
    let counters_before = env.physics_counters();
    let start = Instant::now();
    for i in 0..args.steps {
        env.step(&pool[i % pool.len()])?;
        max_gap = max_gap.max(env.max_joint_gap());
        extra_share += env.extra_iteration_share();
        if args.reference_loop {
            fall_resets += reset_fallen(&mut env, &mut fallen)?;
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let after = env.stage_times();
    let (physics, task) = (after.physics - before.physics, after.task - before.task);
    let counters = env.physics_counters().minus(&counters_before);
    let per_step = |n: u64| n as f64 / counters.robot_steps.max(1) as f64;
    let env_steps = (args.envs * args.steps) as f64 / wall;
    Ok(BenchReport {
        env_steps_per_sec: env_steps,
        physics_steps_per_sec: env_steps * decimation as f64,
        env_steps_per_sec_per_thread: env_steps / threads as f64,
        envs: args.envs,
        threads,
        actions: args.actions,
        steps: args.steps,
        physics_only: args.physics_only,
        terrain: args.terrain.clone(),
        max_joint_gap_m: max_gap,
        extra_iteration_share: extra_share / args.steps.max(1) as f64,
        nonfinite_resets: env.nonfinite_resets(),
        reference_loop: args.reference_loop,
        fall_resets,
        physics_share: if physics + task > 0.0 {
            physics / (physics + task)
        } else {
            1.0
        },
        wall_s: wall,
        no_joints: args.no_joints,
        us_per_robot_step: StageMicros::per_robot_step(&counters, physics, wall * threads as f64),
        contacts_per_robot_step: per_step(counters.contacts),
        contact_pairs_per_robot_step: per_step(counters.contact_pairs),
        constraints_per_robot_step: per_step(counters.constraints),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reference_args(actions: BenchActions, overrides: Vec<String>) -> BenchArgs {
        BenchArgs {
            envs: 8,
            steps: 10,
            threads: 1,
            actions,
            physics_only: true,
            terrain: "flat".into(),
            level: 0,
            seed: 3,
            reference_loop: true,
            no_joints: false,
            overrides,
            json: true,
        }
    }

    #[test]
    fn reference_loop_keeps_standing_robots() {
        let report = run(&reference_args(BenchActions::Stand, vec![])).expect("bench");
        assert!(report.reference_loop);
        assert_eq!(report.fall_resets, 0);
        assert_eq!(report.extra_iteration_share, 0.0);
    }

    /// rapier's engine: the contact and constraint counts below are its solver's.
    fn rapier() -> Vec<String> {
        vec!["physics.engine = \"rapier\"".to_string()]
    }

    #[test]
    fn standing_robots_have_eight_contacts_and_twelve_joints() {
        let report = run(&reference_args(BenchActions::Stand, rapier())).expect("bench");
        // One point per manifold on the plane: the 4 feet, and the 4 lower shin capsules
        // (`*_calflower1`), about 18 mm above the ground at the default pose, inside rapier's
        // 20 mm contact prediction distance. The solver adds the 12 joints to those 8.
        assert_eq!(report.contacts_per_robot_step, 8.0);
        assert_eq!(report.constraints_per_robot_step, 20.0);
        let us = &report.us_per_robot_step;
        // Rapier's stages lie inside its step, and its step inside ours.
        assert!(us.rapier_other >= 0.0, "{us:?}");
        assert!(
            us.step >= us.torques + us.pipeline + us.after - 1e-9,
            "{us:?}"
        );
        assert!(us.collision_detection >= us.broad_phase + us.narrow_phase - 1e-9);
        assert!(us.solver >= us.assembly + us.resolution - 1e-9);
        assert!(us.physics_stage >= us.step + us.read_back - 1e-9);
    }

    #[test]
    fn no_joints_is_refused_on_the_articulated_engine() {
        let mut args = reference_args(BenchActions::Stand, vec![]);
        args.no_joints = true;
        let err = run(&args).expect_err("no joints to remove").to_string();
        assert!(err.contains("physics.engine = \"rapier\""), "{err}");
    }

    #[test]
    fn without_joints_the_solver_sees_only_contacts() {
        let mut args = reference_args(BenchActions::Stand, rapier());
        args.no_joints = true;
        let report = run(&args).expect("bench");
        assert!(report.no_joints);
        // Free bodies: every constraint is a contact manifold, none a joint (with joints there
        // are 12 more than the manifolds, as above). The legs fall apart, so the trunks fall
        // and robots are put back: more than one contact a manifold is possible, not fewer.
        assert!(report.constraints_per_robot_step > 0.0);
        assert!(report.contacts_per_robot_step >= report.constraints_per_robot_step);
        assert!(report.fall_resets > 0);
    }

    #[test]
    fn reference_loop_puts_back_robots_tilted_past_60_degrees() {
        // Start every robot pitched 1.2 rad (69 degrees): each step finds all of them fallen and
        // puts them back at that same start, so every env is reset at every timed step.
        let tilted = vec!["init.pitch = [1.2, 1.2]".to_string()];
        let report = run(&reference_args(BenchActions::Stand, tilted)).expect("bench");
        assert_eq!(report.fall_resets, 8 * 10);
        // 0.9 rad (52 degrees) is not a fall at the start: the first steps reset nobody.
        let leaning = vec!["init.pitch = [0.9, 0.9]".to_string()];
        let mut args = reference_args(BenchActions::Stand, leaning);
        args.steps = 1;
        let report = run(&args).expect("bench");
        assert!(report.fall_resets < 8, "{} resets", report.fall_resets);
    }
}
