//! `unigait-server probe`: how learnable the task's start is, before any learning.
//!
//! Every env holds the default stance (all-zero actions) from the Table IV initial states, and
//! the probe reports how many episodes a termination ends within the first 10 and 100 policy
//! steps, overall and by the task mode the episode started in. A policy that outputs zeros is
//! roughly where PPO starts (a zero-mean Gaussian), so these shares bound how much signal the
//! first iterations can see.

use std::sync::Arc;

use anyhow::Result;
use serde::Serialize;
use unigait_sim::prelude::*;

/// Probe settings.
#[derive(Clone, Debug, clap::Args)]
pub struct ProbeArgs {
    /// Number of envs (each contributes its first episode).
    #[arg(long, default_value_t = 1024)]
    pub envs: usize,
    /// Policy steps to follow each env's first episode.
    #[arg(long, default_value_t = 100)]
    pub steps: u32,
    /// Seed.
    #[arg(long, default_value_t = 3)]
    pub seed: u64,
    /// Worker threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// A TOML fragment overriding the task config (repeatable).
    #[arg(long = "set")]
    pub overrides: Vec<String>,
}

/// Shares of first episodes ended by a termination.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TerminationShares {
    /// Episodes counted.
    pub episodes: usize,
    /// Share terminated within 10 policy steps.
    pub within_10: f64,
    /// Share terminated within `steps` policy steps.
    pub within_steps: f64,
}

/// What the probe measured.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeReport {
    /// Envs probed.
    pub envs: usize,
    /// Policy steps followed.
    pub steps: u32,
    /// Seed.
    pub seed: u64,
    /// All first episodes.
    pub all: TerminationShares,
    /// First episodes that started in biped mode.
    pub biped: TerminationShares,
    /// First episodes that started in quad mode.
    pub quad: TerminationShares,
    /// Share of envs whose head touched the ground at some step of the probe.
    pub head_contact_share: f64,
}

/// Run the probe.
pub fn run(args: &ProbeArgs) -> Result<ProbeReport> {
    let threads = if args.threads == 0 {
        std::thread::available_parallelism()?.get()
    } else {
        args.threads
    };
    let mut config = TaskConfig::embedded_default();
    // Every env starts its episode at step 0, so "within N steps" means what it says.
    config = config.with_overrides("env.random_initial_episode_step = false")?;
    for o in &args.overrides {
        config = config.with_overrides(o)?;
    }
    let options = VecEnvOptions {
        num_envs: args.envs,
        seed: args.seed,
        threads,
        physics_only: false,
        autoreset: true,
    };
    let mut env = VecEnv::new(
        Arc::new(RobotModel::go2()),
        config,
        Arc::new(Terrain::Flat),
        options,
    )?;
    let start_mode: Vec<u8> = env.output().mode.clone();
    // Step at which each env's first episode ended by a termination (None: still running).
    let mut ended: Vec<Option<u32>> = vec![None; args.envs];
    let mut finished = vec![false; args.envs];
    let mut head = vec![false; args.envs];
    let zeros = vec![0.0; args.envs * NUM_JOINTS];
    for step in 1..=args.steps {
        let out = env.step(&zeros)?;
        for i in 0..args.envs {
            if finished[i] {
                continue;
            }
            head[i] |= out.head_contact[i] != 0;
            if out.terminated[i] != 0 {
                ended[i] = Some(step);
            }
            if out.terminated[i] != 0 || out.truncated[i] != 0 {
                finished[i] = true;
            }
        }
    }
    let shares = |filter: &dyn Fn(usize) -> bool| {
        let picked: Vec<usize> = (0..args.envs).filter(|&i| filter(i)).collect();
        let n = picked.len().max(1) as f64;
        let within = |limit: u32| {
            picked
                .iter()
                .filter(|&&i| ended[i].is_some_and(|s| s <= limit))
                .count() as f64
                / n
        };
        TerminationShares {
            episodes: picked.len(),
            within_10: within(10),
            within_steps: within(args.steps),
        }
    };
    let biped = TaskMode::Biped as u8;
    Ok(ProbeReport {
        envs: args.envs,
        steps: args.steps,
        seed: args.seed,
        all: shares(&|_| true),
        biped: shares(&|i| start_mode[i] == biped),
        quad: shares(&|i| start_mode[i] != biped),
        head_contact_share: head.iter().filter(|&&h| h).count() as f64 / args.envs.max(1) as f64,
    })
}
