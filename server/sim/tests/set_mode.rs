//! `VecEnv::set_mode` / `set_modes`: a caller's mode switch on real rollouts. The switched env's
//! observation row shows the new mode, clock and command at once, its next reward is masked for
//! the new mode, every other env stays bit-identical to a run without the call, the thread count
//! does not matter, and bad requests are errors.

mod common;

use std::f32::consts::TAU;

use common::*;
use unigait_sim::SimError;
use unigait_sim::prelude::*;
use unigait_sim::task::{OBSERVATION, TermGroup, slice_of};

/// Pinned quad mode, nothing redrawn during the test.
const QUAD_ONLY: &str = "
modes.biped_probability = 0.0
modes.resampling_time_s = 3600.0
commands.resampling_time_s = 3600.0
";

fn range(name: &str) -> std::ops::Range<usize> {
    let (offset, size) = slice_of(&OBSERVATION, name).expect("known slice");
    offset..offset + size
}

fn obs_row(out: &StepOutput, env: usize) -> &[f32] {
    &out.obs[env * OBS_DIM..(env + 1) * OBS_DIM]
}

/// Every per-env array of `out` restricted to env `i`, as bit patterns (so NaN == NaN and
/// -0.0 != 0.0: "bit-identical" means exactly that).
fn env_bits(out: &StepOutput, i: usize) -> Vec<u32> {
    let mut bits = Vec::new();
    for (v, dim) in [
        (&out.obs, OBS_DIM),
        (&out.labels, LABEL_DIM),
        (&out.privileged, PRIVILEGED_DIM),
        (&out.reward, 1),
        (&out.reward_terms, RewardTerm::COUNT),
        (&out.final_obs, OBS_DIM),
        (&out.final_labels, LABEL_DIM),
        (&out.final_privileged, PRIVILEGED_DIM),
        (&out.torques, NUM_JOINTS),
    ] {
        bits.extend(v[i * dim..(i + 1) * dim].iter().map(|x| x.to_bits()));
    }
    bits.extend([
        u32::from(out.terminated[i]),
        u32::from(out.truncated[i]),
        out.episode_length[i],
        u32::from(out.mode[i]),
        out.terrain_level[i],
        u32::from(out.nonfinite[i]),
    ]);
    bits
}

/// The clock slice o_t should hold for `mode` at `episode_step` (unscaled: scale 1).
fn expected_clock(cfg: &TaskConfig, mode: TaskMode, episode_step: u32) -> [f32; 4] {
    let phase = (episode_step as f32 * cfg.policy_dt() / cfg.gait.period_s).rem_euclid(1.0);
    let (offsets, biped) = match mode {
        TaskMode::Biped => (cfg.gait.offsets_biped, true),
        TaskMode::Quad => (cfg.gait.offsets_quad, false),
    };
    std::array::from_fn(|f| {
        if biped && f >= 2 {
            0.0
        } else {
            (TAU * (phase + offsets[f])).sin()
        }
    })
}

#[test]
fn the_switched_row_shows_the_new_mode_clock_and_command_at_once() {
    // Noise on: the body slices must keep the noisy reading the policy was already given.
    let cfg = calm_config(&format!("{QUAD_ONLY}\n[noise]\nenabled = true"));
    let mut env = batch(cfg.clone(), 4, 3, 1);
    for _ in 0..7 {
        env.step(&[0.0; 4 * NUM_JOINTS]).expect("step");
    }
    let before = env.output().clone();
    assert_eq!(
        &obs_row(&before, 1)[range("mode")],
        &[0.0, 1.0],
        "starts in quad"
    );
    let step = env.env_state(1).episode_step;
    assert_eq!(step, 7);

    let command = [0.3, -0.1, 0.2];
    env.set_mode(1, TaskMode::Biped, Some(command))
        .expect("set_mode");
    let out = env.output();
    let row = obs_row(out, 1);
    assert_eq!(env.env_state(1).mode, TaskMode::Biped);
    assert_eq!(env.env_state(1).command, command);
    assert_eq!(out.mode[1], TaskMode::Biped as u8);
    assert_eq!(&row[range("mode")], &[1.0, 0.0]);
    // Command scales of the observation table: 2, 2, 0.25.
    assert_eq!(&row[range("cmd")], &[0.6, -0.2, 0.05]);
    // The clock runs on (same episode step), read with the biped offsets: rear feet 0.
    let clock = &row[range("clock")];
    let want = expected_clock(&cfg, TaskMode::Biped, step);
    for f in 0..4 {
        assert!(
            (clock[f] - want[f]).abs() < 1e-6,
            "clock {clock:?} vs {want:?}"
        );
    }
    assert_eq!(&clock[2..], &[0.0, 0.0]);
    let quad_clock = expected_clock(&cfg, TaskMode::Quad, step);
    assert!(
        (obs_row(&before, 1)[range("clock")][2] - quad_clock[2]).abs() < 1e-6
            && quad_clock[2].abs() > 0.1,
        "the quad clock had a live rear foot: the rewrite changed something"
    );
    assert_eq!(&row[range("ratio")], &[0.4, 0.6]);
    // The body slices (orientation .. last action) keep their exact noisy values.
    let body = range("phi").start..range("last_action").end;
    assert_eq!(&row[body.clone()], &obs_row(&before, 1)[body]);
    // The rest of the env's row (labels, reward of the last step, ...) is untouched.
    let (b, a) = (env_bits(&before, 1), env_bits(out, 1));
    let obs_bits = OBS_DIM;
    let mode_entry = a.len() - 3;
    for k in (obs_bits..a.len()).filter(|&k| k != mode_entry) {
        assert_eq!(a[k], b[k], "entry {k} of env 1's row changed");
    }
    for i in [0, 2, 3] {
        assert_eq!(env_bits(out, i), env_bits(&before, i), "env {i}");
    }

    // The switch holds through the next step: the command is not redrawn (not due) and the
    // clock moves on with the biped offsets.
    env.step(&[0.0; 4 * NUM_JOINTS]).expect("step");
    let out = env.output();
    let row = obs_row(out, 1);
    assert_eq!(out.mode[1], TaskMode::Biped as u8);
    assert_eq!(&row[range("mode")], &[1.0, 0.0]);
    assert_eq!(&row[range("cmd")], &[0.6, -0.2, 0.05]);
    let want = expected_clock(&cfg, TaskMode::Biped, step + 1);
    for f in 0..4 {
        assert!((row[range("clock")][f] - want[f]).abs() < 1e-6);
    }
}

#[test]
fn without_a_command_a_change_draws_one_from_the_new_modes_ranges() {
    let cfg = calm_config(&format!(
        "{QUAD_ONLY}
commands.quad = {{ vx = [1.2, 1.2], vy = [0.0, 0.0], wz = [0.0, 0.0] }}
commands.biped = {{ vx = [0.35, 0.35], vy = [-0.2, -0.2], wz = [0.0, 0.0] }}"
    ));
    let mut env = batch(cfg, 2, 9, 1);
    assert_eq!(env.env_state(0).command, [1.2, 0.0, 0.0]);
    env.step(&[0.0; 2 * NUM_JOINTS]).expect("step");
    env.set_mode(0, TaskMode::Biped, None).expect("set_mode");
    assert_eq!(env.env_state(0).command, [0.35, -0.2, 0.0]);
    assert_eq!(&obs_row(env.output(), 0)[range("cmd")], &[0.7, -0.4, 0.0]);
    // Already in biped mode: no change, so the command stays (here: the caller's).
    env.set_mode(0, TaskMode::Biped, Some([0.1, 0.0, 0.0]))
        .expect("set_mode");
    env.set_mode(0, TaskMode::Biped, None).expect("set_mode");
    assert_eq!(env.env_state(0).command, [0.1, 0.0, 0.0]);
    // And back: the quad range again.
    env.set_mode(0, TaskMode::Quad, None).expect("set_mode");
    assert_eq!(env.env_state(0).command, [1.2, 0.0, 0.0]);
    assert_eq!(&obs_row(env.output(), 0)[range("mode")], &[0.0, 1.0]);
    assert_eq!(env.env_state(1).command, [1.2, 0.0, 0.0], "env 1 untouched");
}

#[test]
fn other_envs_stay_bit_identical_to_a_run_without_the_call() {
    // Randomisation and noise on, random actions (some robots fall and reset): every env's
    // random stream is busy, so a stray draw from another env's stream would show.
    let cfg = TaskConfig::embedded_default()
        .with_overrides("modes.resampling_time_s = 0.3\ncommands.resampling_time_s = 0.2")
        .expect("config");
    let n = 6;
    let mut plain = batch(cfg.clone(), n, 11, 1);
    let mut switched = batch(cfg, n, 11, 1);
    let mut seed = 5u64;
    for step in 0..40 {
        let actions = random_actions(n, &mut seed);
        plain.step(&actions).expect("step");
        switched.step(&actions).expect("step");
        if step == 10 {
            let to = match switched.env_state(2).mode {
                TaskMode::Biped => TaskMode::Quad,
                TaskMode::Quad => TaskMode::Biped,
            };
            switched.set_mode(2, to, None).expect("set_mode");
            assert_eq!(switched.output().mode[2], to as u8);
        }
        for i in (0..n).filter(|&i| i != 2) {
            assert_eq!(
                env_bits(switched.output(), i),
                env_bits(plain.output(), i),
                "env {i} after step {step}"
            );
        }
    }
    // Same actions, so env 2's body did the same; only its task differed.
    let labels = |o: &StepOutput| o.labels[2 * LABEL_DIM..3 * LABEL_DIM].to_vec();
    assert_eq!(labels(switched.output()), labels(plain.output()));
}

#[test]
fn the_next_reward_uses_the_new_modes_masks() {
    let cfg = calm_config(QUAD_ONLY);
    let mut plain = batch(cfg.clone(), 2, 4, 1);
    let mut switched = batch(cfg, 2, 4, 1);
    for _ in 0..5 {
        plain.step(&[0.0; 2 * NUM_JOINTS]).expect("step");
        switched.step(&[0.0; 2 * NUM_JOINTS]).expect("step");
    }
    switched
        .set_mode(0, TaskMode::Biped, None)
        .expect("set_mode");
    // The switch itself pays nothing: the last reward stays as earned.
    assert_eq!(switched.output().reward, plain.output().reward);
    plain.step(&[0.0; 2 * NUM_JOINTS]).expect("step");
    switched.step(&[0.0; 2 * NUM_JOINTS]).expect("step");
    let terms = |o: &StepOutput| o.reward_terms[..RewardTerm::COUNT].to_vec();
    let (p, s) = (terms(plain.output()), terms(switched.output()));
    let sum = |t: &[f32], group: TermGroup| -> f32 {
        RewardTerm::ALL
            .iter()
            .filter(|term| term.group() == group)
            .map(|&term| t[term as usize].abs())
            .sum()
    };
    // Without the call: quad terms pay, biped terms are masked out; with it, the reverse.
    assert!(sum(&p, TermGroup::Quad) > 0.0, "{p:?}");
    assert_eq!(sum(&p, TermGroup::Biped), 0.0, "{p:?}");
    assert_eq!(sum(&s, TermGroup::Quad), 0.0, "{s:?}");
    assert!(sum(&s, TermGroup::Biped) > 0.0, "{s:?}");
    // Standing on four legs: not upright, so the upright-gated biped terms stay masked.
    assert_eq!(sum(&s, TermGroup::BipedUpright), 0.0, "{s:?}");
    // Same body, same actions: the common terms are the same.
    for term in RewardTerm::ALL {
        if term.group() == TermGroup::Common {
            assert_eq!(s[term as usize], p[term as usize], "{}", term.name());
        }
    }
    assert_ne!(switched.output().reward[0], plain.output().reward[0]);
    assert_eq!(switched.output().reward[1], plain.output().reward[1]);
}

#[test]
fn set_modes_does_not_depend_on_the_thread_count() {
    // Two envs per world: three groups, stepped by one or two threads.
    let cfg = TaskConfig::embedded_default()
        .with_overrides("env.envs_per_world = 2")
        .expect("config");
    let n = 6;
    let mask = [1, 0, 0, 1, 1, 0];
    let outputs: Vec<StepOutput> = [1, 2]
        .into_iter()
        .map(|threads| {
            let mut env = batch(cfg.clone(), n, 21, threads);
            let mut seed = 8u64;
            for step in 0..12 {
                env.step(&random_actions(n, &mut seed)).expect("step");
                if step == 4 {
                    env.set_modes(&mask, TaskMode::Biped, None)
                        .expect("set_modes");
                    for (i, &m) in mask.iter().enumerate() {
                        if m != 0 {
                            assert_eq!(env.output().mode[i], TaskMode::Biped as u8);
                        }
                    }
                }
            }
            env.output().clone()
        })
        .collect();
    for i in 0..n {
        assert_eq!(
            env_bits(&outputs[0], i),
            env_bits(&outputs[1], i),
            "env {i}"
        );
    }
}

#[test]
fn bad_requests_are_errors_and_change_nothing() {
    let mut env = batch(calm_config(QUAD_ONLY), 3, 1, 1);
    env.step(&[0.0; 3 * NUM_JOINTS]).expect("step");
    let before = env.output().clone();
    for bad in [3, 4, usize::MAX] {
        let err = env
            .set_mode(bad, TaskMode::Biped, None)
            .expect_err("out of range");
        assert!(matches!(err, SimError::InvalidConfig { .. }), "{err}");
        let text = err.to_string();
        assert!(
            text.contains(&bad.to_string()) && text.contains("num_envs = 3"),
            "{text}"
        );
    }
    let err = env
        .set_mode(0, TaskMode::Biped, Some([0.2, f32::NAN, 0.0]))
        .expect_err("non-finite command");
    assert!(
        matches!(
            err,
            SimError::NonFinite {
                index: 1,
                env: 0,
                ..
            }
        ),
        "{err}"
    );
    let err = env
        .set_modes(&[1, 0], TaskMode::Biped, None)
        .expect_err("short mask");
    assert!(
        matches!(
            err,
            SimError::Shape {
                got: 2,
                expected: 3,
                ..
            }
        ),
        "{err}"
    );
    let err = env
        .set_modes(&[0, 1, 0], TaskMode::Biped, Some([f32::INFINITY, 0.0, 0.0]))
        .expect_err("non-finite command");
    assert!(matches!(err, SimError::NonFinite { env: 1, .. }), "{err}");
    assert_eq!(env.output(), &before);
    assert!((0..3).all(|i| env.env_state(i).mode == TaskMode::Quad));
}
