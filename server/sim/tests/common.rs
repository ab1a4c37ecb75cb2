//! Shared helpers for the integration tests.
#![allow(dead_code)]

use std::sync::Arc;

use unigait_sim::prelude::*;

/// A config with the robot starting in the default pose at rest, no randomisation, no noise.
pub fn calm_config(extra: &str) -> TaskConfig {
    let calm = "
[init]
hip = [0.0, 0.0]
thigh = [0.0, 0.0]
calf = [0.0, 0.0]
pitch = [0.0, 0.0]
linvel = [0.0, 0.0]
angvel = [0.0, 0.0]
[randomization]
enabled = false
[noise]
enabled = false
[env]
random_initial_episode_step = false
";
    TaskConfig::embedded_default()
        .with_overrides(calm)
        .and_then(|c| c.with_overrides(extra))
        .expect("valid test config")
}

/// A batch of `n` envs on flat ground.
pub fn batch(config: TaskConfig, n: usize, seed: u64, threads: usize) -> VecEnv {
    let options = VecEnvOptions {
        num_envs: n,
        seed,
        threads,
        physics_only: false,
        autoreset: true,
    };
    VecEnv::new(
        Arc::new(RobotModel::go2()),
        config,
        Arc::new(Terrain::Flat),
        options,
    )
    .expect("batch builds")
}

/// Deterministic pseudo-random actions in [-1, 1].
pub fn random_actions(n: usize, state: &mut u64) -> Vec<f32> {
    (0..n * NUM_JOINTS)
        .map(|_| {
            *state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((*state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

/// Go2 mass from our URDF (kg).
pub const GO2_MASS: f32 = 15.019;

/// Step `env` (2 envs or more) with zero actions (the default pose under PD) for `steps`
/// steps, asserting env 0 never falls; env 0's states from step `keep_from` on.
pub fn stand(
    env: &mut VecEnv,
    steps: usize,
    keep_from: usize,
) -> Vec<unigait_sim::physics::RobotState> {
    let zeros = vec![0.0; env.num_envs() * NUM_JOINTS];
    let mut late = Vec::new();
    for step in 0..steps {
        let out = env.step(&zeros).expect("step");
        assert_eq!(out.terminated[0], 0, "fell at step {step}");
        if step >= keep_from {
            late.push(*env.robot_state(0));
        }
    }
    late
}

/// Decision record 0035, on `config`'s engine: 8 envs run 10 random steps, then env 3's trunk
/// is set to a NaN and to a finite 500 m/s speed, one run each. The step after resets it
/// (terminated, reward 0, flagged, counted once, its new state sound and calm), with finite
/// observations, and leaves the other envs as in a clean run. Returns (speed, step) per run.
pub fn blown_up_runs(config: TaskConfig) -> Vec<(f32, StepOutput)> {
    let run = |speed: Option<f32>| {
        let mut env = batch(config.clone(), 8, 2, 1);
        let mut state = 5;
        for _ in 0..10 {
            env.step(&random_actions(8, &mut state)).expect("step");
        }
        if let Some(speed) = speed {
            env.poison_env(3, speed);
        }
        let out = env
            .step(&random_actions(8, &mut state))
            .expect("step")
            .clone();
        let reset = *env.robot_state(3);
        (out, env.nonfinite_resets(), reset)
    };
    let (clean, clean_count, _) = run(None);
    assert_eq!(clean_count, 0);
    [f32::NAN, 500.0]
        .into_iter()
        .map(|speed| {
            let (hit, hit_count, reset) = run(Some(speed));
            assert_eq!(hit_count, 1, "{speed}");
            assert!(reset.is_sound(), "{speed}: the env was not reset");
            // A reset draws the trunk velocity within 0.5 m/s per axis.
            assert!(
                reset.base_linvel.length() < 1.0,
                "{speed}: {:?}",
                reset.base_linvel
            );
            assert_eq!(hit.nonfinite[3], 1);
            assert_eq!(hit.terminated[3], 1);
            assert_eq!(hit.reward[3], 0.0);
            assert!(hit.obs.iter().chain(&hit.final_obs).all(|v| v.is_finite()));
            for i in (0..8).filter(|&i| i != 3) {
                let row = |o: &StepOutput| o.obs[i * OBS_DIM..(i + 1) * OBS_DIM].to_vec();
                assert_eq!(row(&clean), row(&hit), "{speed}: env {i} was disturbed");
            }
            (speed, hit)
        })
        .collect()
}
