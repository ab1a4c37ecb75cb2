//! Each reward term against a value computed by hand for a constructed state.

use rapier3d::math::{Vec2, Vec3};

use std::f32::consts::FRAC_PI_2;

use super::*;
use crate::task::gait::{VonMisesCdf, gait_coefficients};
use crate::task::reward_terms::TermGroup;

fn close(a: f32, b: f32) {
    assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} != {b}");
}

/// The indicators at the config's own upright threshold (no curriculum).
fn fixed_indicators(biped: bool, pitch: f32, cfg: &TaskConfig) -> Indicators {
    indicators(biped, pitch, cfg.rewards.upright_pitch, cfg)
}

fn zeros() -> [f32; NUM_JOINTS] {
    [0.0; NUM_JOINTS]
}

#[test]
fn common_costs() {
    close(cost_termination(true), 1.0);
    close(cost_termination(false), 0.0);
    close(cost_collision(3), 3.0);
    // 0.3^2 + 0.4^2 = 0.25; z is ignored.
    close(cost_ang_vel_xy(Vec3::new(0.3, 0.4, 9.0)), 0.25);
    let mut qd = zeros();
    qd[0] = 2.0;
    qd[5] = -1.0;
    close(cost_dof_vel(&qd), 5.0);
    // (2 - 1) / 0.02 = 50 -> 2500; (-1 - 0) / 0.02 = -50 -> 2500.
    let mut prev = zeros();
    prev[0] = 1.0;
    close(cost_dof_acc(&qd, &prev, 0.02), 5000.0);
    let mut a = zeros();
    let mut a1 = zeros();
    let mut a2 = zeros();
    a[0] = 1.0;
    a1[0] = 0.5;
    a2[0] = 0.5;
    a[1] = -1.0;
    close(cost_action_rate(&a, &a1), 0.25 + 1.0);
    // a - 2 a1 + a2 = 1 - 1 + 0.5 = 0.5; second joint -1.
    close(cost_action_smoothness(&a, &a1, &a2), 0.25 + 1.0);
    let mut tau = zeros();
    tau[2] = 3.0;
    tau[11] = -4.0;
    close(cost_torques(&tau), 25.0);
}

#[test]
fn hip_position_and_limits() {
    let q0 = [
        0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5,
    ];
    let mut q = q0;
    q[0] = 0.3; // +0.2
    q[9] = -0.4; // -0.3
    q[1] = 2.0; // not a hip: ignored
    close(cost_hip_pos(&q, &q0, &[0, 3, 6, 9]), 0.04 + 0.09);
    let lo = [-1.0; NUM_JOINTS];
    let hi = [1.0; NUM_JOINTS];
    let mut q = zeros();
    q[0] = 1.5;
    q[4] = -1.01;
    close(cost_dof_pos_limits(&q, &lo, &hi), 2.0);
}

#[test]
fn tracking_and_posture_rewards() {
    // |(1, 0) - (0.5, 0.5)|^2 = 0.5 -> exp(-4 * 0.5) with the paper's k, exp(-10 * 0.5) with 10.
    close(
        reward_tracking_lin_vel([1.0, 0.0], Vec2::new(0.5, 0.5), TRACKING_SHARPNESS),
        (-2.0f32).exp(),
    );
    close(
        reward_tracking_lin_vel([1.0, 0.0], Vec2::new(0.5, 0.5), 10.0),
        (-5.0f32).exp(),
    );
    close(reward_tracking_ang_vel(0.5, 0.0), (-1.0f32).exp());
    // (0.3 - 0.2)^2 = 0.01 -> exp(-0.02).
    close(reward_base_height(0.3, 0.2), (-0.02f32).exp());
    // Tilted normal (0.3, 0.4, .) -> exp(-10 * 0.25).
    close(
        reward_quad_base_angle(Vec3::new(0.3, 0.4, 0.866)),
        (-2.5f32).exp(),
    );
    close(cost_lin_vel_z(-0.5), 0.25);
    // Upright biped at target: 1; off by 0.5 rad in pitch: exp(-0.5).
    close(
        reward_biped_base_angle([0.0, FRAC_PI_2], 0.0, FRAC_PI_2),
        1.0,
    );
    close(
        reward_biped_base_angle([0.0, FRAC_PI_2], 0.0, FRAC_PI_2 - 0.5),
        (-0.5f32).exp(),
    );
}

#[test]
fn gait_and_clearance() {
    let coeffs = [
        GaitCoefficients {
            force: 1.0,
            speed: 0.0,
        },
        GaitCoefficients {
            force: 0.0,
            speed: 1.0,
        },
        GaitCoefficients {
            force: 0.5,
            speed: 0.5,
        },
        GaitCoefficients {
            force: 0.0,
            speed: 1.0,
        },
    ];
    let force = [50.0, 100.0, 20.0, 0.0];
    let speed = [2.0, 0.5, 1.0, 3.0];
    // FL: 1 * 50/100 = 0.5; FR: 0.5/1 = 0.5; RL: 0.5*0.2 + 0.5*1 = 0.6; RR: 3.
    close(
        gait_violation(&coeffs, &force, &speed, &[0, 1, 2, 3], 100.0, 1.0),
        4.6,
    );
    close(
        gait_violation(&coeffs, &force, &speed, &[0, 1], 100.0, 1.0),
        1.0,
    );
    close(reward_periodic_gait(1.0), (-2.0f32).exp());
    // A perfect trot instant: swing feet in the air, stance feet still.
    let cdf = VonMisesCdf::new(20.0);
    let c: [GaitCoefficients; 4] =
        std::array::from_fn(|f| gait_coefficients(&cdf, 0.2 + [0.0, 0.5, 0.5, 0.0][f], 0.4));
    let e = gait_violation(
        &c,
        &[0.0, 70.0, 70.0, 0.0],
        &[1.5, 0.0, 0.0, 1.5],
        &[0, 1, 2, 3],
        100.0,
        1.0,
    );
    assert!(e < 1e-3, "{e}");
    // Heights 0.08 (on target) and 0.0 moving at 2 m/s: (0.08)^2 * 2 = 0.0128.
    let h = [0.08, 0.0, 0.5, 0.5];
    let v = [1.0, 2.0, 0.0, 0.0];
    close(foot_clearance_error(&h, &v, 0.08, &[0, 1, 2, 3]), 0.0128);
    close(reward_foot_clearance(0.0128, 100.0), (-1.28f32).exp());
    // A front foot 4 cm short of the target at 0.8 m/s: 0.04^2 * 0.8 = 0.00128; the paper's
    // kernel keeps 88% of the term, a kernel of 400 keeps 60%.
    let short = foot_clearance_error(&[0.04, 0.08, 0.08, 0.08], &[0.8, 0.0, 0.0, 0.0], 0.08, &[0]);
    close(short, 0.00128);
    close(reward_foot_clearance(short, 100.0), 0.879_853);
    close(reward_foot_clearance(short, 400.0), 0.599_296);
}

#[test]
fn clearance_weighted_by_the_swing_phase_prices_a_low_foot_at_any_speed() {
    // A trot at phase 0.2: FL and RR are mid-swing (swing is [0, 0.4)), FR and RL mid-stance.
    let cdf = VonMisesCdf::new(20.0);
    let gait: [GaitCoefficients; 4] =
        std::array::from_fn(|f| gait_coefficients(&cdf, 0.2 + [0.0, 0.5, 0.5, 0.0][f], 0.4));
    let swing = clearance_weights(ClearanceWeighting::SwingPhase, &[0.0; 4], &gait);
    assert!(swing[0] > 0.999 && swing[3] > 0.999, "{swing:?}");
    assert!(swing[1] < 1e-3 && swing[2] < 1e-3, "{swing:?}");
    let speed = [0.7, 0.0, 0.1, 0.3];
    assert_eq!(
        clearance_weights(ClearanceWeighting::FootSpeed, &speed, &gait),
        speed
    );
    // FL swinging 3 cm high against a 12 cm target: (0.09)^2 = 0.0081 whatever its speed, and
    // exp(-100 * 0.0081) = 0.4449. Eq. 4 charges it by speed: nothing when the foot stands
    // still (a robot stalled at a riser), 0.0081 * 3 at a quick 3 m/s.
    let low = [0.03, 0.022, 0.022, 0.12];
    for v in [0.0, 1.0, 3.0] {
        let w = clearance_weights(ClearanceWeighting::SwingPhase, &[v, 0.0, 0.0, v], &gait);
        let e = foot_clearance_error(&low, &w, 0.12, &[0, 1, 2, 3]);
        close(
            e,
            0.0081 * swing[0] + (0.098f32).powi(2) * (swing[1] + swing[2]),
        );
        assert!((reward_foot_clearance(e, 100.0) - 0.4449).abs() < 2e-3);
    }
    let paper = |v: f32| {
        let w = clearance_weights(ClearanceWeighting::FootSpeed, &[v, 0.0, 0.0, v], &gait);
        reward_foot_clearance(foot_clearance_error(&low, &w, 0.12, &[0, 1, 2, 3]), 100.0)
    };
    close(paper(0.0), 1.0);
    close(paper(3.0), (-2.43f32).exp());
    // The stance feet, at rest on the ground, cost nothing under either weighting.
    let w = clearance_weights(ClearanceWeighting::SwingPhase, &[0.0; 4], &gait);
    assert!(foot_clearance_error(&low, &w, 0.12, &[1, 2]) < 1e-4);
}

/// A robot at rest: every input zero, the gait weights of a foot in stance.
fn inputs() -> RewardInputs {
    let stance = GaitCoefficients {
        force: 0.0,
        speed: 1.0,
    };
    RewardInputs {
        terminated: false,
        penalised_contacts: 0,
        head_contact: false,
        base_angvel_b: Vec3::ZERO,
        base_linvel_b: Vec3::ZERO,
        heading_linvel: Vec2::ZERO,
        yaw_rate: 0.0,
        command: [0.0; 3],
        base_height: 0.3,
        terrain_normal_b: Vec3::Z,
        pitch: 0.0,
        roll_proxy: 0.0,
        q: zeros(),
        qd: zeros(),
        qd_prev: zeros(),
        actions: [zeros(); 3],
        torques: zeros(),
        foot_force: [0.0; 4],
        foot_speed: [0.0; 4],
        foot_speed_xy: [0.0; 4],
        foot_clearance_height: [0.0; 4],
        touchdown_air_time: [0.0; 4],
        gait_quad: [stance; 4],
        gait_biped: [stance; 4],
    }
}

fn constants() -> RewardConstants {
    RewardConstants {
        default_q: zeros(),
        soft_lower: [-1.0; NUM_JOINTS],
        soft_upper: [1.0; NUM_JOINTS],
        hips: [0, 3, 6, 9],
        raised_left: [6, 7, 8],
        raised_right: [9, 10, 11],
        stance_feet: [0, 1],
        raised_feet: [2, 3],
        stance_legs: [[0, 1, 2], [3, 4, 5]],
        stance_leg_geometry: [[Vec3::ZERO; 3]; 2],
    }
}

#[test]
fn the_clearance_weighting_is_chosen_by_the_config() {
    let mut cfg = TaskConfig::default();
    cfg.rewards.foot_clearance_target = 0.12;
    let k = constants();
    let mut x = inputs();
    let cdf = VonMisesCdf::new(20.0);
    x.gait_quad =
        std::array::from_fn(|f| gait_coefficients(&cdf, 0.2 + [0.0, 0.5, 0.5, 0.0][f], 0.4));
    x.foot_clearance_height = [0.03, 0.022, 0.022, 0.03];
    x.foot_speed_xy = [0.0; 4];
    let quad = RewardTerm::QuadFootClearance as usize;
    // Standing still: Eq. 4 sees no error; the swing phase sees two feet 9 cm short.
    close(raw_terms(&x, &k, &cfg)[quad], 1.0);
    cfg.rewards.foot_clearance_weighting = ClearanceWeighting::SwingPhase;
    let paid = raw_terms(&x, &k, &cfg)[quad];
    assert!((paid - (-1.62f32).exp()).abs() < 2e-3, "{paid}");
}

#[test]
fn the_biped_may_have_its_own_clearance_target() {
    let mut cfg = TaskConfig::default();
    cfg.rewards.foot_clearance_target = 0.18;
    let k = constants();
    let mut x = inputs();
    // Eq. 4's weighting: the front feet swing at 1 m/s, 12 cm up; the rear ones stand.
    x.foot_clearance_height = [0.12, 0.12, 0.022, 0.022];
    x.foot_speed_xy = [1.0, 1.0, 0.0, 0.0];
    let (quad, biped) = (
        RewardTerm::QuadFootClearance as usize,
        RewardTerm::BipedFootClearance as usize,
    );
    // Unset, both modes price the front feet 6 cm short of 18: exp(-100 x 2 x 0.06^2).
    let short = (-0.72f32).exp();
    let terms = raw_terms(&x, &k, &cfg);
    close(terms[quad], short);
    close(terms[biped], short);
    // The biped's own 12 cm: its feet are on target; the quad's term is unchanged.
    cfg.rewards.biped_foot_clearance_target = Some(0.12);
    let terms = raw_terms(&x, &k, &cfg);
    close(terms[quad], short);
    close(terms[biped], 1.0);
    // Out of range, it is refused by name.
    cfg.rewards.biped_foot_clearance_target = Some(1.5);
    let err = cfg.validate().expect_err("1.5 m is no clearance target");
    assert!(
        err.to_string()
            .contains("rewards.biped_foot_clearance_target"),
        "{err}"
    );
    // From TOML, as a recipe stage sets it.
    let parsed = TaskConfig::default()
        .with_overrides("[rewards]\nbiped_foot_clearance_target = 0.12\n")
        .expect("valid");
    assert_eq!(parsed.rewards.biped_foot_clearance_target, Some(0.12));
}

#[test]
fn feet_air_time_charges_a_short_swing_at_touchdown_and_never_pays() {
    // FL swung 0.06 s, FR 0.30 s (longer than the target: free, no more), RL (not a stance
    // foot) 0.05 s; target 0.18 s.
    let touchdown = [0.06, 0.30, 0.05, 0.0];
    close(
        reward_feet_air_time(&touchdown, &[0, 1], 0.18, [0.4, 0.0]),
        0.06 - 0.18,
    );
    close(
        reward_feet_air_time(&[0.18, 0.25, 0.0, 0.0], &[0, 1], 0.18, [0.4, 0.0]),
        0.0,
    );
    close(
        reward_feet_air_time(&[0.06, 0.0, 0.0, 0.0], &[0, 1], 0.18, [0.0, -0.3]),
        -0.12,
    );
    // No touchdown, nothing; a command under 0.1 m/s asks for no steps.
    close(
        reward_feet_air_time(&[0.0; 4], &[0, 1], 0.18, [0.4, 0.0]),
        0.0,
    );
    close(
        reward_feet_air_time(&touchdown, &[0, 1], 0.18, [0.07, 0.07]),
        0.0,
    );
}

#[test]
fn feet_air_time_targets_the_gait_clocks_swing() {
    // Default clock: 0.45 s period, 0.4 swing: a 0.18 s swing is free, a shuffle of 0.04 s
    // pays -0.14 at its touchdown.
    let cfg = TaskConfig::default();
    let k = constants();
    let mut x = inputs();
    x.command = [0.4, 0.0, 0.0];
    let term = RewardTerm::BipedFeetAirTime as usize;
    x.touchdown_air_time = [0.18, 0.0, 0.0, 0.0];
    close(raw_terms(&x, &k, &cfg)[term], 0.0);
    x.touchdown_air_time = [0.04, 0.0, 0.0, 0.0];
    close(raw_terms(&x, &k, &cfg)[term], -0.14);
    assert_eq!(
        cfg.rewards.weights.0[term], 0.0,
        "not in Table II: off by default"
    );
}

#[test]
fn biped_terms() {
    let mut q = zeros();
    // RL (6..9) and RR (9..12): hips mirror, so 0.1 / -0.1 is symmetric.
    q[6] = 0.1;
    q[9] = -0.1;
    q[7] = 1.0;
    q[10] = 1.0;
    q[8] = -1.5;
    q[11] = -1.5;
    close(cost_biped_rear_legs(&q, &[6, 7, 8], &[9, 10, 11]), 0.0);
    q[10] = 1.5;
    q[9] = 0.1;
    close(
        cost_biped_rear_legs(&q, &[6, 7, 8], &[9, 10, 11]),
        0.04 + 0.25,
    );
    close(
        reward_upright_contacts(&[true, false, false, false], &[0, 1], &[2, 3]),
        1.0,
    );
    close(
        reward_upright_contacts(&[true, true, true, false], &[0, 1], &[2, 3]),
        0.0,
    );
    close(
        reward_upright_contacts(&[false, false, false, false], &[0, 1], &[2, 3]),
        0.0,
    );
}

#[test]
fn masks_indicators_and_ablations() {
    let mut cfg = TaskConfig::default();
    // The terms off by default get a weight, so every term shows its mask.
    cfg.rewards.weights.0[RewardTerm::BipedBodyContact as usize] = -1.0;
    cfg.rewards.weights.0[RewardTerm::BipedSidewaysReach as usize] = 1.0;
    cfg.rewards.weights.0[RewardTerm::BipedFeetAirTime as usize] = 1.0;
    let weight = |t: RewardTerm| cfg.rewards.weights.0[t as usize];
    let raw = [1.0; RewardTerm::COUNT];
    let mut terms = [0.0; RewardTerm::COUNT];
    // Quad mode: every biped term is exactly 0, every quad term is weight * dt.
    let ind = fixed_indicators(false, 0.0, &cfg);
    weigh_terms(&raw, &ind, &cfg, &mut terms);
    for t in RewardTerm::ALL {
        let expected = match t.group() {
            TermGroup::Common | TermGroup::Quad => weight(t) * 0.02,
            TermGroup::Biped | TermGroup::BipedUpright => 0.0,
        };
        close(terms[t as usize], expected);
    }
    // Biped mode below the upright pitch: quad terms and gated biped terms are 0.
    let ind = fixed_indicators(true, 1.3, &cfg);
    weigh_terms(&raw, &ind, &cfg, &mut terms);
    for t in RewardTerm::ALL {
        let expected = match t.group() {
            TermGroup::Common | TermGroup::Biped => weight(t) * 0.02,
            TermGroup::Quad | TermGroup::BipedUpright => 0.0,
        };
        close(terms[t as usize], expected);
    }
    // Above 1.4 rad the gated terms switch on.
    let ind = fixed_indicators(true, 1.45, &cfg);
    weigh_terms(&raw, &ind, &cfg, &mut terms);
    close(terms[RewardTerm::BipedTrackingLinVel as usize], 2.0 * 0.02);
    close(terms[RewardTerm::QuadTrackingLinVel as usize], 0.0);

    // "No upright indicator": gated biped terms on at any pitch, nothing else changes.
    let mut no_up = cfg.clone();
    no_up.rewards.upright_indicator = false;
    let mut with = [0.0; RewardTerm::COUNT];
    let mut without = [0.0; RewardTerm::COUNT];
    weigh_terms(&raw, &fixed_indicators(true, 0.5, &cfg), &cfg, &mut with);
    weigh_terms(
        &raw,
        &fixed_indicators(true, 0.5, &no_up),
        &no_up,
        &mut without,
    );
    for t in RewardTerm::ALL {
        let changed = with[t as usize] != without[t as usize];
        assert_eq!(
            changed,
            t.group() == TermGroup::BipedUpright,
            "{}",
            t.name()
        );
    }
    // "No task indicator": in quad mode the biped terms turn on (the gated ones still need
    // the pitch), the quad and common terms stay.
    let mut no_task = cfg.clone();
    no_task.rewards.task_indicators = false;
    weigh_terms(&raw, &fixed_indicators(false, 1.5, &cfg), &cfg, &mut with);
    weigh_terms(
        &raw,
        &fixed_indicators(false, 1.5, &no_task),
        &no_task,
        &mut without,
    );
    for t in RewardTerm::ALL {
        let changed = with[t as usize] != without[t as usize];
        let biped = matches!(t.group(), TermGroup::Biped | TermGroup::BipedUpright);
        assert_eq!(changed, biped, "{}", t.name());
    }
}

#[test]
fn body_contact_is_priced_only_in_the_biped_mode_and_only_when_asked() {
    // Head, shins or both: one support other than the feet, counted once.
    close(cost_body_contact(true, 0), 1.0);
    close(cost_body_contact(false, 1), 1.0);
    close(cost_body_contact(true, 3), 1.0);
    close(cost_body_contact(false, 0), 0.0);
    let mut raw = [0.0; RewardTerm::COUNT];
    raw[RewardTerm::BipedBodyContact as usize] = cost_body_contact(true, 0);
    let mut terms = [0.0; RewardTerm::COUNT];
    // The paper's task: weight 0, so a rest on the head costs nothing.
    let paper = TaskConfig::default();
    weigh_terms(
        &raw,
        &fixed_indicators(true, 1.5, &paper),
        &paper,
        &mut terms,
    );
    close(terms[RewardTerm::BipedBodyContact as usize], 0.0);
    // Weight -1: -1 * 0.02 per step in the biped mode at any pitch, nothing in the quad mode.
    let mut priced = TaskConfig::default();
    priced.rewards.weights.0[RewardTerm::BipedBodyContact as usize] = -1.0;
    priced.rewards.only_positive = false;
    for pitch in [0.5, 1.5] {
        let total = weigh_terms(
            &raw,
            &fixed_indicators(true, pitch, &priced),
            &priced,
            &mut terms,
        );
        close(terms[RewardTerm::BipedBodyContact as usize], -0.02);
        close(total, -0.02);
    }
    weigh_terms(
        &raw,
        &fixed_indicators(false, 0.0, &priced),
        &priced,
        &mut terms,
    );
    close(terms[RewardTerm::BipedBodyContact as usize], 0.0);
}

#[test]
fn total_is_clipped_before_termination() {
    let cfg = TaskConfig::default();
    let mut raw = [0.0; RewardTerm::COUNT];
    raw[RewardTerm::Collision as usize] = 2.0; // -1 * 0.02 * 2 = -0.04
    raw[RewardTerm::Termination as usize] = 1.0; // -0.02 * 0.02 = -0.0004
    let mut terms = [0.0; RewardTerm::COUNT];
    let total = weigh_terms(&raw, &fixed_indicators(false, 0.0, &cfg), &cfg, &mut terms);
    close(total, -0.0004);
    let mut signed = cfg.clone();
    signed.rewards.only_positive = false;
    let total = weigh_terms(
        &raw,
        &fixed_indicators(false, 0.0, &signed),
        &signed,
        &mut terms,
    );
    close(total, -0.0404);
}

#[test]
fn sideways_reach_is_the_foot_distance_from_the_abduction_axis() {
    // Go2 front-left geometry: thigh joint 9.55 cm out from the hip, thigh and calf 21.3 cm.
    let leg = [
        Vec3::new(0.0, 0.0955, 0.0),
        Vec3::new(0.0, 0.0, -0.213),
        Vec3::new(0.0, 0.0, -0.213),
    ];
    // Straight leg along -z: the foot 0.426 m from the axis.
    close(sideways_reach(0.0, 0.0, 0.0, &leg), 0.426);
    // Leg along +x (thigh at -pi/2), where a foot stands in the biped stance relative to its
    // hip: on the axis, no reach; abducted by 0.2 rad only the thigh's offset gives a lever.
    close(sideways_reach(0.0, -FRAC_PI_2, 0.0, &leg), 0.0);
    close(
        sideways_reach(0.2, -FRAC_PI_2, 0.0, &leg),
        0.2f32.sin() * 0.0955,
    );
    // Knee bent 90 degrees, thigh straight: the foot 0.213 m forward and 0.213 m down.
    close(sideways_reach(0.0, 0.0, -FRAC_PI_2, &leg), 0.213);
    // The default four-legged pose (hip 0.1, thigh 0.8, knee -1.5), worked through by hand:
    // the foot in the hip frame at (-0.015579, 0.0955, -0.311310), then
    // |sin 0.1 * 0.0955 + cos 0.1 * -0.311310| = 0.300221.
    close(sideways_reach(0.1, 0.8, -1.5, &leg), 0.300221);

    // The reward: each leg's share of the target, capped at 1, averaged over both.
    let legs = [[0, 1, 2], [3, 4, 5]];
    let geometry = [leg, [leg[0] * Vec3::new(1.0, -1.0, 1.0), leg[1], leg[2]]];
    let mut q = zeros();
    q[..3].copy_from_slice(&[0.1, 0.8, -1.5]); // FL: 0.30 m/rad, capped at the 0.1 target
    // FR: thigh along +x, knee folded back: the foot at (0.213, -0.0955, 0.213) in the hip
    // frame, 0.213 m from the axis, also capped.
    q[3..6].copy_from_slice(&[0.0, -FRAC_PI_2, -FRAC_PI_2]);
    close(reward_sideways_reach(&q, &legs, &geometry, 0.1), 1.0);
    q[3..6].copy_from_slice(&[0.0, -FRAC_PI_2, 0.0]); // FR on the axis: 0
    close(reward_sideways_reach(&q, &legs, &geometry, 0.1), 0.5);
    q[..3].copy_from_slice(&[0.0, 0.0, -FRAC_PI_2]); // FL 0.213 against a 0.426 target
    close(reward_sideways_reach(&q, &legs, &geometry, 0.426), 0.25);

    // Off in the paper's task; where weighted, paid only upright in the biped mode.
    assert_eq!(RewardTerm::BipedSidewaysReach.default_weight(), 0.0);
    let mut raw = [0.0; RewardTerm::COUNT];
    raw[RewardTerm::BipedSidewaysReach as usize] = 0.5;
    let mut cfg = TaskConfig::default();
    cfg.rewards.weights.0[RewardTerm::BipedSidewaysReach as usize] = 1.0;
    let mut terms = [0.0; RewardTerm::COUNT];
    for (biped, pitch, paid) in [(true, 1.5, 0.5 * 0.02), (true, 1.0, 0.0), (false, 1.5, 0.0)] {
        weigh_terms(
            &raw,
            &fixed_indicators(biped, pitch, &cfg),
            &cfg,
            &mut terms,
        );
        close(terms[RewardTerm::BipedSidewaysReach as usize], paid);
    }
}

#[test]
fn the_go2s_own_geometry_gives_the_default_pose_its_reach() {
    let model = crate::robot::RobotModel::go2();
    let ctx = crate::task::context::TaskContext::new(TaskConfig::default(), &model);
    let k = &ctx.reward;
    assert_eq!(k.stance_legs, [[0, 1, 2], [3, 4, 5]]);
    for (leg, side) in [(0, 1.0), (1, -1.0)] {
        let g = &k.stance_leg_geometry[leg];
        let [h, t, c] = k.stance_legs[leg];
        // The URDF's foot sits 2 mm behind the calf axis: (-0.002, 0, -0.213). Worked as
        // above, the foot is at (-0.017108, +-0.0955, -0.312598) in the hip frame and both
        // mirrored legs reach |sin 0.1 * 0.0955 - cos 0.1 * 0.312598| = 0.301503 m/rad.
        close(g[0].y, side * 0.0955);
        close(g[1].z, -0.213);
        close(g[2].x, -0.002);
        close(
            sideways_reach(k.default_q[h], k.default_q[t], k.default_q[c], g),
            0.301503,
        );
    }
}
