//! `unigait-server bench`: env steps per second of the simulation core, in process.

use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
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
    let decimation = config.env.decimation;
    let selection = unigait_proto::v1::TerrainConfig {
        kind: args.terrain.clone(),
        level: args.level,
    };
    let (terrain, _) = unigait_server::terrain_for(Some(&selection), args.seed)?;
    let options = VecEnvOptions {
        num_envs: args.envs,
        seed: args.seed,
        threads,
        physics_only: args.physics_only,
        autoreset: true,
    };
    let mut env = VecEnv::new(model, config, terrain, options)?;
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
