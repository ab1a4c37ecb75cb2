//! The task's episode logic and observation layout on real rollouts.

mod common;

use std::f32::consts::TAU;

use common::*;
use unigait_sim::prelude::*;
use unigait_sim::task::{OBSERVATION, PRIVILEGED, heading_direction, slice_of, to_heading_frame};

fn obs_slice(out: &StepOutput, env: usize, name: &str) -> Vec<f32> {
    let (offset, size) = slice_of(&OBSERVATION, name).expect("known slice");
    out.obs[env * OBS_DIM + offset..env * OBS_DIM + offset + size].to_vec()
}

/// Each named slice of o_t holds what its name says (noise off).
#[test]
fn observation_slices_hold_what_they_name() {
    for (biped_probability, mode) in [(1.0, TaskMode::Biped), (0.0, TaskMode::Quad)] {
        let cfg = calm_config(&format!("modes.biped_probability = {biped_probability}"));
        let mut env = batch(cfg, 3, 1, 1);
        for _ in 0..7 {
            env.step(&[0.0; 3 * NUM_JOINTS]).expect("step");
        }
        let out = env.output();
        let state = env.env_state(1);
        assert_eq!(state.mode, mode);
        let one_hot = obs_slice(out, 1, "mode");
        assert_eq!(
            one_hot,
            if mode == TaskMode::Biped {
                vec![1.0, 0.0]
            } else {
                vec![0.0, 1.0]
            }
        );
        // Phase after 7 steps of 0.02 s with T = 0.45 s.
        let phase = (7.0 * 0.02 / 0.45f32).fract();
        let offsets = if mode == TaskMode::Biped {
            [0.0, 0.5, 0.0, 0.0]
        } else {
            [0.0, 0.5, 0.5, 0.0]
        };
        let clock = obs_slice(out, 1, "clock");
        for f in 0..4 {
            let expected = if mode == TaskMode::Biped && f >= 2 {
                0.0
            } else {
                (TAU * (phase + offsets[f])).sin()
            };
            assert!(
                (clock[f] - expected).abs() < 1e-5,
                "clock[{f}] {} vs {expected}",
                clock[f]
            );
        }
        assert_eq!(obs_slice(out, 1, "ratio"), vec![0.4, 0.6]);
        let cmd = obs_slice(out, 1, "cmd");
        let expected = [
            state.command[0] * 2.0,
            state.command[1] * 2.0,
            state.command[2] * 0.25,
        ];
        assert_eq!(cmd, expected.to_vec());
        // Standing level: gravity along -z in the base frame, pitch about 0.
        let phi = obs_slice(out, 1, "phi");
        assert!(
            phi[0].abs() < 0.05 && phi[1].abs() < 0.1 && (phi[2] + 1.0).abs() < 0.02,
            "phi {phi:?}"
        );
        let q = obs_slice(out, 1, "q");
        let s = env.robot_state(1);
        for ((qj, sj), q0) in q
            .iter()
            .zip(&s.q)
            .zip(&env.model().config.default_joint_pos)
        {
            assert!((qj - (sj - q0)).abs() < 1e-6);
        }
        assert_eq!(obs_slice(out, 1, "last_action"), vec![0.0; 12]);
    }
}

/// Commands change only every 10 s (or with the mode), modes only every 6 s.
#[test]
fn modes_and_commands_are_redrawn_on_schedule() {
    let cfg = calm_config("[env]\nepisode_length_s = 30.0");
    let n = 8;
    let mut env = batch(cfg, n, 5, 1);
    let mut last: Vec<_> = (0..n)
        .map(|i| (env.env_state(i).mode, env.env_state(i).command))
        .collect();
    let mut mode_changes = 0;
    for step in 1..=1100u32 {
        env.step(&vec![0.0; n * NUM_JOINTS]).expect("step");
        for (i, prev) in last.iter_mut().enumerate() {
            let s = env.env_state(i);
            if env.output().terminated[i] == 1 {
                *prev = (s.mode, s.command);
                continue;
            }
            assert_eq!(s.episode_step, step, "env {i} restarted unexpectedly");
            if s.mode != prev.0 {
                assert_eq!(step % 300, 0, "env {i} changed mode at step {step}");
                mode_changes += 1;
            }
            if s.command != prev.1 {
                assert!(
                    step % 500 == 0 || s.mode != prev.0,
                    "env {i} changed command at step {step}"
                );
            }
            *prev = (s.mode, s.command);
        }
    }
    assert!(mode_changes > 0, "no mode ever changed");
}

/// Initial states and randomised values fall in their ranges and differ between envs.
#[test]
fn initial_states_and_randomisation_are_in_range_and_vary() {
    let n = 32;
    let env = batch(TaskConfig::embedded_default(), n, 11, 1);
    let out = env.output();
    let ranges: [(&str, f32, f32); 8] = [
        ("friction", 0.2, 1.6),
        ("payload", -1.0, 1.0),
        ("com_offset", -0.01, 0.01),
        ("joint_damping", 0.25, 0.35),
        ("joint_friction", 0.005, 0.01),
        ("armature", 0.015, 0.025),
        ("kp_factor", 0.8, 1.2),
        ("kd_factor", 0.8, 1.2),
    ];
    // s_t carries each value mapped from its Table V range to [-1, 1]; the raw value is
    // recovered from it.
    for (name, lo, hi) in ranges {
        let (offset, size) = slice_of(&PRIVILEGED, name).expect("slice");
        let mut seen = Vec::new();
        for i in 0..n {
            for k in 0..size {
                let v = out.privileged[i * PRIVILEGED_DIM + offset + k];
                assert!((-1.0..=1.0).contains(&v), "{name} = {v} outside [-1, 1]");
                let raw = lo + (v + 1.0) * 0.5 * (hi - lo);
                assert!(
                    (lo..=hi).contains(&raw),
                    "{name} = {raw} outside [{lo}, {hi}]"
                );
                seen.push(v);
            }
        }
        seen.sort_by(f32::total_cmp);
        seen.dedup();
        assert!(seen.len() > n / 2, "{name} barely varies: {seen:?}");
    }
    let model = env.model();
    for i in 0..n {
        let s = env.robot_state(i);
        let pitch = unigait_sim::task::euler_pitch(s.base_rot);
        assert!((-1e-4..=1.3 + 1e-4).contains(&pitch), "pitch {pitch}");
        for j in 0..NUM_JOINTS {
            let offset = s.q[j] - model.config.default_joint_pos[j];
            let bound = [0.2, 1.0, 0.6][j % 3] + 1e-4;
            assert!(offset.abs() <= bound, "joint {j} offset {offset}");
        }
    }
}

/// Time-outs are truncations with the final observation kept; trunk contacts are terminations
/// (head contacts are not: see the learnability tests).
#[test]
fn termination_and_truncation_are_told_apart() {
    let mut env = batch(calm_config("[env]\nepisode_length_s = 0.2"), 2, 1, 1);
    let zeros = vec![0.0; 2 * NUM_JOINTS];
    for step in 1..=10 {
        env.step(&zeros).expect("step");
        let out = env.output();
        assert_eq!(out.terminated, vec![0, 0]);
        assert_eq!(
            out.truncated,
            if step == 10 { vec![1, 1] } else { vec![0, 0] }
        );
    }
    let out = env.output();
    assert_eq!(out.episode_length, vec![10, 10]);
    assert_ne!(out.final_obs[..OBS_DIM], out.obs[..OBS_DIM]);
    assert_eq!(out.reward_terms[RewardTerm::Termination as usize], 0.0);

    // Set down nose up (pitch -1.5) with limp joints: it topples onto its trunk.
    let mut env = batch(calm_config("init.pitch = [-1.5, -1.5]"), 4, 2, 1);
    let mut terminated = false;
    for _ in 0..100 {
        env.step(&[0.0; 4 * NUM_JOINTS]).expect("step");
        let out = env.output();
        for i in 0..4 {
            if out.terminated[i] == 1 {
                terminated = true;
                assert_eq!(out.truncated[i], 0);
                let term =
                    out.reward_terms[i * RewardTerm::COUNT + RewardTerm::Termination as usize];
                assert!(
                    (term - (-0.02 * 0.02)).abs() < 1e-9,
                    "termination term {term}"
                );
            }
        }
    }
    assert!(terminated, "no robot landed on its trunk");
}

/// The embedded TOML and the code's defaults agree (one source of defaults, checked).
#[test]
fn embedded_config_equals_code_defaults() {
    assert_eq!(TaskConfig::embedded_default(), TaskConfig::default());
}

/// The upright curriculum moves I_up's threshold up one step per judged window while the robots
/// are above it, gates the biped tracking term with the threshold in force, stops once they are
/// below it, and with the curriculum off the threshold is the config's, fixed.
#[test]
fn upright_curriculum_raises_the_threshold_while_robots_are_above_it() {
    use rapier3d::math::{Pose, Rotation, Vec3};
    let n = 8;
    let pitch = 0.83;
    let curriculum = "
[modes]
biped_probability = 1.0
[rewards.upright_curriculum]
enabled = true
start = 0.5
step = 0.1
promote_share = 0.5
window_steps = 16
";
    let model = RobotModel::go2();
    let q: [f32; NUM_JOINTS] = std::array::from_fn(|j| model.config.default_joint_pos[j]);
    let zeros = vec![0.0; n * NUM_JOINTS];
    let lin = RewardTerm::BipedTrackingLinVel as usize;
    let mut env = batch(calm_config(curriculum), n, 0, 1);
    assert_eq!(env.output().upright_pitch, 0.5);
    let mut thresholds = Vec::new();
    for _ in 0..12 {
        let before = env.output().upright_pitch;
        // Each robot held 2 m up at the same nose-down pitch, at rest: one policy step of free
        // fall with the joints at their targets leaves the pitch where it was.
        for i in 0..n {
            let p = env.robot_state(i).base_pos;
            let base = Pose::from_parts(Vec3::new(p.x, p.y, 2.0), Rotation::from_rotation_y(pitch));
            env.teleport_env(i, base, &q);
        }
        let out = env.step(&zeros).expect("step").clone();
        for i in 0..n {
            assert_eq!(out.mode[i], 1, "biped mode throughout");
            let gated = out.reward_terms[i * RewardTerm::COUNT + lin];
            assert_eq!(
                gated > 0.0,
                pitch > before,
                "I_up at threshold {before}: {gated}"
            );
        }
        thresholds.push(out.upright_pitch);
    }
    // A window is 16 biped env-steps = 2 steps of 8 envs, all above until the threshold passes
    // 0.83: 0.5 -> 0.6 -> 0.7 -> 0.8 -> 0.9, then no more.
    let expected = [0.5, 0.6, 0.6, 0.7, 0.7, 0.8, 0.8, 0.9, 0.9, 0.9, 0.9, 0.9];
    for (got, want) in thresholds.iter().zip(expected) {
        assert!((got - want).abs() < 1e-5, "{thresholds:?}");
    }

    let mut fixed = batch(calm_config("[modes]\nbiped_probability = 1.0\n"), n, 0, 1);
    for _ in 0..4 {
        assert_eq!(fixed.step(&zeros).expect("step").upright_pitch, 1.4);
    }
}

/// `rewards.biped_tracking_lin_vel_sharpness` reaches the biped's velocity term: the same robots,
/// held upright 2 m up and falling freely for one step, are paid exp(-k |v* - v|^2) with k = 10
/// where the default k = 4 pays more, by exactly exp(-6 |v* - v|^2).
#[test]
fn the_biped_velocity_kernel_takes_its_sharpness_from_the_config() {
    use rapier3d::math::{Pose, Rotation, Vec3};
    let n = 4;
    let model = RobotModel::go2();
    let q: [f32; NUM_JOINTS] = std::array::from_fn(|j| model.config.default_joint_pos[j]);
    let zeros = vec![0.0; n * NUM_JOINTS];
    let lin = RewardTerm::BipedTrackingLinVel as usize;
    let paid = |extra: &str| {
        let mut env = batch(
            calm_config(&format!("[modes]\nbiped_probability = 1.0\n{extra}")),
            n,
            0,
            1,
        );
        for i in 0..n {
            let p = env.robot_state(i).base_pos;
            let base = Pose::from_parts(Vec3::new(p.x, p.y, 2.0), Rotation::from_rotation_y(1.55));
            env.teleport_env(i, base, &q);
        }
        let out = env.step(&zeros).expect("step").clone();
        (0..n)
            .map(|i| {
                let s = env.robot_state(i);
                let v = to_heading_frame(heading_direction(s.base_rot), s.base_linvel);
                let c = env.env_state(i).command;
                let e2 = (c[0] - v.x).powi(2) + (c[1] - v.y).powi(2);
                (out.reward_terms[i * RewardTerm::COUNT + lin], e2)
            })
            .collect::<Vec<_>>()
    };
    let default = paid("");
    let steep = paid("[rewards]\nbiped_tracking_lin_vel_sharpness = 10.0\n");
    for ((d, e2), (s, e2_again)) in default.iter().zip(&steep) {
        assert!(
            (e2 - e2_again).abs() < 1e-6,
            "the same motion: {e2} vs {e2_again}"
        );
        assert!(*d > 0.0, "upright and paid");
        let want = d * (-6.0 * e2).exp();
        assert!(
            (s - want).abs() <= 1e-6 * d.max(1e-3),
            "{s} vs {want} (k = 4 paid {d})"
        );
    }
}

/// `rewards.foot_clearance_weighting` reaches the env's clearance term (decision record 0039):
/// quad robots standing still on flat ground are paid the whole term under Eq. 4, their feet not
/// moving, and under the swing window exp(-100 sum_f (h_f - 0.12)^2 w_f), w_f each foot's swing
/// weight at the env's gait phase, as a stalled robot would be charged.
#[test]
fn the_swing_window_charges_a_standing_robots_low_feet() {
    use unigait_sim::task::{VonMisesCdf, gait_coefficients};
    let n = 2;
    let zeros = vec![0.0; n * NUM_JOINTS];
    let term = RewardTerm::QuadFootClearance;
    let paid = |weighting: &str| {
        let cfg = calm_config(&format!(
            "[modes]\nbiped_probability = 0.0\n[rewards]\nfoot_clearance_target = 0.12\n\
             foot_clearance_weighting = \"{weighting}\"\n"
        ));
        let mut env = batch(cfg.clone(), n, 0, 1);
        let mut out = env.step(&zeros).expect("step").clone();
        // Settled on the default pose, at a phase where both trot pairs' weights differ.
        for _ in 0..60 {
            out = env.step(&zeros).expect("step").clone();
        }
        let cdf = VonMisesCdf::new(cfg.gait.kappa);
        (0..n)
            .map(|i| {
                let s = env.robot_state(i);
                let phase = env.env_state(i).gait_phase(&cfg);
                let error: f32 = (0..4)
                    .map(|f| {
                        let w = gait_coefficients(
                            &cdf,
                            phase + cfg.gait.offsets_quad[f],
                            cfg.gait.swing_ratio,
                        )
                        .force;
                        let h = s.foot_pos[f].z;
                        assert!((0.015..0.03).contains(&h), "a standing foot's centre: {h}");
                        (h - 0.12).powi(2) * w
                    })
                    .sum();
                let raw = out.reward_terms[i * RewardTerm::COUNT + term as usize]
                    / cfg.scaled_weight(term);
                (raw, (-100.0 * error).exp(), error)
            })
            .collect::<Vec<_>>()
    };
    for (raw, _, _) in paid("foot_speed") {
        assert!(
            raw > 0.95,
            "feet all but still cost next to nothing under Eq. 4: {raw}"
        );
    }
    for (raw, want, error) in paid("swing_phase") {
        assert!(
            error > 0.005,
            "a trot always has feet in their swing window: {error}"
        );
        assert!((raw - want).abs() < 1e-4, "{raw} vs {want}");
        assert!(raw < 0.6, "feet 10 cm short through their swing: {raw}");
    }
}

/// The feet-air-time term (decision record 0040) reads the env's own contacts: a standing robot
/// is charged nothing; a front foot held up 0.1 s is charged once, at the step it comes down,
/// what its air time falls short of the clock's 0.18 s swing; one held up 0.24 s is charged
/// nothing. The ablation switches unmask the two-legged term on four legs.
#[test]
fn feet_air_time_charges_a_short_swing_once_at_its_touchdown() {
    let cfg = calm_config(
        "[modes]\nbiped_probability = 0.0\n[commands]\nzero_below = 0.0\n\
         quad = { vx = [0.4, 0.4], vy = [0.0, 0.0], wz = [0.0, 0.0] }\n\
         [rewards]\ntask_indicators = false\nupright_indicator = false\n\
         [rewards.weights]\nbiped_feet_air_time = 1.0\n",
    );
    let term = RewardTerm::BipedFeetAirTime;
    let dt = cfg.policy_dt();
    // (steps charged and what, steps FL spent without contact) with FL's calf folded over `held`.
    let run = |held: std::ops::Range<usize>| {
        let mut env = batch(cfg.clone(), 1, 0, 1);
        let stand = vec![0.0; NUM_JOINTS];
        let mut lift = stand.clone();
        lift[2] = -4.0; // FL calf: one radian more knee flexion folds the foot up
        let (mut charged, mut up_steps) = (Vec::new(), 0);
        for step in 0..120 {
            let action = if held.contains(&step) { &lift } else { &stand };
            let out = env.step(action).expect("step");
            let paid = out.reward_terms[term as usize] / cfg.scaled_weight(term);
            if step < 30 {
                continue; // settling from the spawn drop
            }
            up_steps += usize::from(env.robot_state(0).foot_force[0] <= 1.0);
            if paid != 0.0 {
                charged.push((step, paid));
            }
        }
        (charged, up_steps)
    };
    let (charged, up_steps) = run(60..65);
    assert_eq!(charged.len(), 1, "one touchdown, one charge: {charged:?}");
    let (step, paid) = charged[0];
    assert!(
        (65..75).contains(&step),
        "it comes down once let go: {step}"
    );
    // The swing's air time: the steps without contact (the first filtered) plus the step of
    // the touchdown itself.
    let air = up_steps as f32 * dt;
    assert!(air < 0.18, "a short swing: {up_steps} steps");
    assert!(
        (paid - (air - 0.18)).abs() <= dt + 1e-5,
        "charged {paid} for {up_steps} steps up"
    );
    let (charged, up_steps) = run(60..72);
    assert!(
        up_steps >= 10,
        "a swing as long as the clock's: {up_steps} steps"
    );
    assert!(charged.is_empty(), "costs nothing: {charged:?}");
}

/// `commands.heading_share = 1` (decision record 0042): every command draw holds a heading of
/// its own, and after every step each env's yaw-rate command, in o_t too, is the heading hold
/// of that heading from where the body now faces, within its mode's range, while the robots
/// turn under random actions.
#[test]
fn a_held_heading_steers_the_yaw_rate_command_every_step() {
    use unigait_sim::task::{heading_hold, heading_yaw};
    let cfg = calm_config("[commands]\nheading_share = 1.0\nheading_gain = 2.0");
    let n = 16;
    let mut env = batch(cfg.clone(), n, 3, 1);
    let mut rng = 7u64;
    let mut targets = Vec::new();
    let mut steered = 0;
    for _ in 0..400 {
        let out = env
            .step(&random_actions(n, &mut rng))
            .expect("step")
            .clone();
        for i in 0..n {
            let s = env.env_state(i);
            let target = s.held_heading.expect("every draw holds a heading");
            targets.push(target);
            let range = match s.mode {
                TaskMode::Biped => cfg.commands.biped.wz,
                TaskMode::Quad => cfg.commands.quad.wz,
            };
            let yaw = heading_yaw(env.robot_state(i).base_rot);
            let want = heading_hold(target, yaw, 2.0, range);
            assert!(
                (s.command[2] - want).abs() < 1e-6,
                "env {i}: wz {} vs {want}",
                s.command[2]
            );
            assert_eq!(obs_slice(&out, i, "cmd")[2], s.command[2] * 0.25);
            steered += usize::from(want != 0.0 && want.abs() < range[1]);
        }
    }
    assert!(steered > 0, "no command ever steered inside its range");
    let (lo, hi) = targets
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &t| (a.min(t), b.max(t)));
    assert!(lo < -2.0 && hi > 2.0, "headings drawn over [{lo}, {hi}]");
}

/// At `heading_share` 0.5 about half the draws hold a heading; at 0 none does, and the commands
/// are the paper task's draws whatever the gain (the random stream is untouched).
#[test]
fn the_heading_share_decides_how_many_draws_hold_a_heading() {
    let n = 256;
    let held = |extra: &str| {
        let env = batch(calm_config(&format!("[commands]\n{extra}")), n, 11, 1);
        let count = (0..n)
            .filter(|&i| env.env_state(i).held_heading.is_some())
            .count();
        let commands: Vec<_> = (0..n).map(|i| env.env_state(i).command).collect();
        (count, commands)
    };
    let (half, _) = held("heading_share = 0.5");
    assert!(
        (90..=166).contains(&half),
        "{half} of {n} draws hold a heading"
    );
    let (none, commands) = held("heading_share = 0.0\nheading_gain = 3.0");
    let (_, paper) = held("");
    assert_eq!(none, 0);
    assert_eq!(commands, paper);
}

/// A caller's command (`set_mode` with a command) is kept as given: no held heading steers it.
#[test]
fn a_callers_command_is_not_steered() {
    let cfg = calm_config("[commands]\nheading_share = 1.0");
    let n = 4;
    let mut env = batch(cfg, n, 5, 1);
    let given = [0.3, 0.0, 0.2];
    env.set_mode(0, TaskMode::Quad, Some(given))
        .expect("set_mode");
    assert_eq!(env.env_state(0).held_heading, None);
    let mut rng = 1u64;
    for _ in 0..50 {
        env.step(&random_actions(n, &mut rng)).expect("step");
        assert_eq!(env.env_state(0).command, given);
        assert!(env.env_state(1).held_heading.is_some());
    }
}
