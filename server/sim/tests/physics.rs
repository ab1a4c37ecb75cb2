//! The robot in rapier against physical expectations.

mod common;

use common::*;
use rapier3d::math::Vec3;
use unigait_sim::physics::{MAX_SOUND_BASE_SPEED, MAX_SOUND_BASE_SPIN, MAX_SOUND_JOINT_SPEED};
use unigait_sim::prelude::*;
use unigait_sim::task::euler_pitch;

/// Standing at the default pose (action 0) for 10 s: the base settles at 0.269 m (the rigid
/// default pose puts it at 0.32 m; kp 20 lets the legs sag) and then stays put.
#[test]
fn standing_robot_settles_and_stays_still() {
    let mut env = batch(calm_config(""), 2, 0, 1);
    let late = stand(&mut env, 500, 250);
    let last = late.last().expect("states");
    assert!(
        (0.255..=0.285).contains(&last.base_pos.z),
        "base height {}",
        last.base_pos.z
    );
    assert!(
        euler_pitch(last.base_rot).abs() < 0.03,
        "pitch {}",
        euler_pitch(last.base_rot)
    );
    // No drift or jitter over the last 5 s.
    for s in &late {
        assert!(
            (s.base_pos - last.base_pos).length() < 1e-3,
            "drift {:?} vs {:?}",
            s.base_pos,
            last.base_pos
        );
        assert!(
            s.base_linvel.length() < 5e-3,
            "jitter {}",
            s.base_linvel.length()
        );
    }
    // The feet carry the weight.
    let weight = GO2_MASS * 9.81;
    let carried: f32 = last.foot_force.iter().sum();
    assert!(
        (carried - weight).abs() < 0.03 * weight,
        "feet carry {carried} N of {weight} N"
    );
    assert!(
        last.max_joint_gap < 1e-3,
        "joint gap {}",
        last.max_joint_gap
    );
}

/// Dropped with its feet 0.25 m above ground, the robot falls freely, lands on its feet and
/// settles in the standing band within 5 s.
#[test]
fn dropped_robot_lands_and_settles() {
    let mut env = batch(calm_config("init.spawn_clearance = 0.25"), 1, 0, 1);
    let z0 = env.robot_state(0).base_pos.z;
    assert!(z0 > 0.55, "spawned at {z0}");
    let zeros = vec![0.0; NUM_JOINTS];
    // 0.1 s of free fall: z drops by g t^2 / 2 = 0.049 m (joints do not change it).
    for _ in 0..5 {
        env.step(&zeros).expect("step");
    }
    let fallen = z0 - env.robot_state(0).base_pos.z;
    assert!((fallen - 0.049).abs() < 0.004, "fell {fallen} m in 0.1 s");
    let mut landed = false;
    for _ in 0..250 {
        let out = env.step(&zeros).expect("step");
        assert_eq!(out.terminated[0], 0, "the trunk hit the ground");
        landed |= env
            .robot_state(0)
            .foot_force
            .iter()
            .filter(|f| **f > 1.0)
            .count()
            >= 3;
    }
    assert!(landed, "never stood on its feet");
    let s = env.robot_state(0);
    assert!(
        (0.255..=0.285).contains(&s.base_pos.z),
        "settled at {}",
        s.base_pos.z
    );
    assert!(s.base_linvel.length() < 0.01);
}

/// Extreme targets (actions at the clip limit, changing sign at random every step) never drive
/// torques past the effort limits. Targets are not clamped to the joint range (as legged_gym),
/// so the motors press joints into their stops with their full torque, which the stop spring
/// (500 N m/rad, backing rapier's limit) meets at 0.07 rad for the knee's 35.55 N m; legs
/// whipped from stop to stop every step overshoot by up to 0.30 rad (measured; 0.07 when
/// targets were clamped), so the bound is 0.35 rad, still short of the +-pi wrap of the
/// measured angle.
#[test]
fn extreme_targets_respect_joint_and_torque_limits() {
    let n = 16;
    let mut env = batch(calm_config(""), n, 3, 1);
    let model = RobotModel::go2();
    let mut state = 11;
    let mut worst: f32 = 0.0;
    for _ in 0..250 {
        let actions: Vec<f32> = random_actions(n, &mut state)
            .iter()
            .map(|a| a.signum() * 100.0)
            .collect();
        env.step(&actions).expect("step");
        let out = env.output();
        for i in 0..n {
            for (j, joint) in model.joints.iter().enumerate() {
                let tau = out.torques[i * NUM_JOINTS + j];
                assert!(
                    tau.abs() <= joint.effort + 1e-4,
                    "torque {tau} on {}",
                    joint.name
                );
                let q = env.robot_state(i).q[j];
                worst = worst.max(joint.sim_lower - q).max(q - joint.sim_upper);
                assert!(
                    q >= joint.sim_lower - 0.35 && q <= joint.sim_upper + 0.35,
                    "{} at {q} outside [{}, {}]",
                    joint.name,
                    joint.sim_lower,
                    joint.sim_upper
                );
            }
        }
    }
    assert!(
        worst > 0.0,
        "no joint reached a stop: the test does not test"
    );
}

/// One thread and two threads give bit-identical trajectories.
#[test]
fn thread_count_does_not_change_results() {
    let run = |threads: usize| {
        let mut cfg = TaskConfig::embedded_default();
        cfg.env.envs_per_world = 8;
        let mut env = batch(cfg, 40, 5, threads);
        let mut state = 99;
        let mut trace = Vec::new();
        for _ in 0..60 {
            let out = env.step(&random_actions(40, &mut state)).expect("step");
            trace.extend_from_slice(&out.obs);
            trace.extend_from_slice(&out.reward);
        }
        trace.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    assert_eq!(run(1), run(2));
}

/// A physics blow-up in one env resets that env, is counted, and leaves the others untouched:
/// a non-finite state, and a finite one no Go2 reaches (500 m/s, decision 0035).
#[test]
fn blown_up_env_is_reset_and_counted() {
    for (speed, hit) in blown_up_runs(TaskConfig::embedded_default()) {
        assert!(
            hit.labels.iter().all(|v| v.is_finite()),
            "{speed}: non-finite labels"
        );
    }
}

/// A fast but physical state is not a blow-up: a trunk thrown at 10 m/s with a spinning leg
/// keeps its episode (decision 0035's bounds sit well above what the task reaches).
#[test]
fn fast_physical_states_are_sound() {
    let mut env = batch(TaskConfig::embedded_default(), 2, 2, 1);
    env.step(&[0.0; 24]).expect("step");
    let mut s = *env.robot_state(0);
    assert!(s.is_sound());
    s.base_linvel = Vec3::new(10.0, -8.0, -5.0);
    s.base_angvel = Vec3::new(0.0, 30.0, 20.0);
    s.qd[2] = 200.0;
    assert!(s.is_sound());
    s.qd[2] = -MAX_SOUND_JOINT_SPEED * 1.01;
    assert!(!s.is_sound());
    s.qd[2] = 0.0;
    s.base_angvel.x = MAX_SOUND_BASE_SPIN;
    assert!(!s.is_sound());
    s.base_angvel.x = 0.0;
    s.base_linvel.z = -MAX_SOUND_BASE_SPEED;
    assert!(!s.is_sound());
}
