//! `unigait-server bench`: env steps per second of the simulation core, in process.

use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use unigait_sim::prelude::*;

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
    /// Share of step time in physics (CPU time over groups).
    pub physics_share: f64,
    /// Wall time of the timed steps (s).
    pub wall_s: f64,
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
    for o in &args.overrides {
        config = config.with_overrides(o)?;
    }
    let decimation = config.env.decimation;
    let selection = unigait_proto::v1::TerrainConfig {
        kind: args.terrain.clone(),
        level: args.level,
    };
    let (terrain, _) = crate::terrain::terrain_for(Some(&selection), args.seed)?;
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
    for i in 0..20 {
        env.step(&pool[i % pool.len()])?;
        max_gap = max_gap.max(env.max_joint_gap());
    }
    let mut extra_share = 0.0;
    let before = env.stage_times();
    let start = Instant::now();
    for i in 0..args.steps {
        env.step(&pool[i % pool.len()])?;
        max_gap = max_gap.max(env.max_joint_gap());
        extra_share += env.extra_iteration_share();
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
        physics_share: if physics + task > 0.0 {
            physics / (physics + task)
        } else {
            1.0
        },
        wall_s: wall,
    })
}
