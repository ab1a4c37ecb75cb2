//! Scenario runs with scripted policies: a policy that stands still never crosses anything, a
//! scripted fall is a failure, transition scenarios switch every env and their bookkeeping adds
//! up, a switch inside a rollout reaches the next action, the two-policy baseline routes each
//! env to its mode's policy, the committed ONNX test policy runs end to end, and a traversal
//! steers each robot back to the heading it started with and reports where each trial ended.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use unigait_eval::{
    EvalError, EvalOptions, Mode, NoObserver, Policies, Rollout, StepObserver, TraversalEnd,
    evaluate, heading_hold, probe, scenario_names, sim_policy_spec, wilson_interval,
};
use unigait_policy::{ConstantPolicy, ObsHistory, OnnxPolicy, Policy, PolicyError, PolicySpec};
use unigait_sim::env::{VecEnv, VecEnvOptions};
use unigait_sim::robot::RobotModel;
use unigait_sim::task::{OBS_DIM, OBSERVATION, TaskConfig, slice_of};
use unigait_sim::terrain::Terrain;

fn options(envs: usize) -> EvalOptions {
    EvalOptions {
        num_envs: Some(envs),
        seed: 1,
        threads: 2,
        ..EvalOptions::default()
    }
}

fn stand_still() -> Policies {
    Policies::Unified(Arc::new(ConstantPolicy::zeros(sim_policy_spec())))
}

/// Folds every leg as far as it goes, so the trunk drops onto the ground: a scripted fall.
fn collapse() -> Policies {
    // Per leg (hip, thigh, calf): thigh to its upper stop, calf to its most folded stop.
    let leg = [0.0, 100.0, -100.0];
    let action: Vec<f32> = leg.iter().copied().cycle().take(12).collect();
    Policies::Unified(Arc::new(ConstantPolicy::new(sim_policy_spec(), action)))
}

#[test]
fn standing_still_never_crosses() {
    let mut last = None;
    for (name, envs) in [("flat_quad", 2), ("slope_quad", 4)] {
        let report = evaluate(name, &stand_still(), &options(envs), &mut NoObserver).expect(name);
        let t = report.traversal.as_ref().expect("traversal report");
        assert_eq!(t.trials, envs, "{name}");
        assert_eq!(t.successes, 0, "{name}: {:?}", t.outcomes);
        let m = &report.metrics;
        assert_eq!(m["success_rate"], 0.0, "{name}");
        // Standing still is a time-out, not a fall.
        assert_eq!((m["fall_rate"], m["timeout_rate"]), (0.0, 1.0), "{name}");
        assert_eq!((t.terminations, t.timeouts), (0, envs), "{name}");
        let [low, high] = wilson_interval(0, envs).expect("trials");
        assert_eq!(m["success_rate_ci95_low"], low);
        assert_eq!(m["success_rate_ci95_high"], high);
        assert!(high > 0.3, "{envs} trials say little: {high}");
        assert_eq!(m["timeout_rate_ci95_high"], 1.0);
        assert_eq!(m["trials"], envs as f64);
        assert_eq!(m["time_limit_s"], 16.0);
        for o in &t.outcomes {
            assert!(o.progress_m < 1.0, "{name}: {o:?}");
            assert_ne!(o.end, TraversalEnd::Crossed);
            // Table V's [0.2, 1.6] on the robot, averaged with the ground's 1.0.
            assert!((0.6..=1.3).contains(&o.contact_friction), "{name}: {o:?}");
        }
        let first = t.outcomes[0].contact_friction;
        assert!(
            t.outcomes.iter().any(|o| o.contact_friction != first),
            "{name}: one draw"
        );
        last = Some(report);
    }
    // The slope's 4 trials: one each way up and down, counted by direction and by slope part.
    let report = last.expect("slope_quad ran");
    let m = &report.metrics;
    for key in ["trials_forward", "trials_backward"] {
        assert_eq!(m[key], 2.0, "{key}");
    }
    for key in [
        "success_rate_forward",
        "success_rate_backward",
        "case/up/success_rate",
        "case/down/success_rate",
        "case/up_backward/success_rate",
        "case/down_forward/success_rate_ci95_high",
    ] {
        assert!(m.contains_key(key), "no {key}: {m:?}");
    }
    let json = report.to_json();
    assert!(
        json.contains("\"success_rate_backward_ci95_low\""),
        "{json}"
    );
}

#[test]
fn a_scripted_fall_is_a_failure() {
    let report = evaluate("flat_quad", &collapse(), &options(3), &mut NoObserver).expect("runs");
    let t = report.traversal.expect("traversal report");
    assert_eq!(t.successes, 0);
    assert_eq!(
        t.terminations, 3,
        "every trial ends by a base contact: {:?}",
        t.outcomes
    );
    assert!(t.outcomes.iter().all(|o| o.end == TraversalEnd::Terminated));
    assert_eq!(report.metrics["terminations"], 3.0);
}

#[test]
fn biped_to_quad_switches_every_env() {
    let report = evaluate(
        "transition_biped_to_quad",
        &stand_still(),
        &options(3),
        &mut NoObserver,
    )
    .expect("runs");
    let t = report.transition.as_ref().expect("transition report");
    assert_eq!(t.envs, 3);
    assert_eq!(t.switched, 3, "every env switched on cue");
    assert_eq!(report.metrics["switched_envs"], 3.0);
    assert_eq!(
        t.fell_before_switch + t.not_in_posture_at_switch + t.trials,
        t.switched
    );
    // Standing still, a robot never gets onto its front legs: no env is in the biped posture
    // at the switch, so there is no trial and no rate.
    assert_eq!(t.trials, 0);
    assert_eq!(t.success_rate, None);
    assert!(!report.metrics.contains_key("success_rate"));
    assert!(report.to_json().contains("\"transition\""));
    assert!(report.to_json().contains("\"switched\": 3"));
    // The quad policy tracks nothing while standing: its error is about the command.
    assert!(report.tracking.contains_key("quad") || report.tracking.contains_key("biped"));
}

#[test]
fn quad_to_biped_switches_every_env_and_measures_each_one() {
    let report = evaluate(
        "transition_quad_to_biped",
        &stand_still(),
        &options(3),
        &mut NoObserver,
    )
    .expect("runs");
    let t = report.transition.as_ref().expect("transition report");
    assert_eq!((t.envs, t.switched), (3, 3), "{t:?}");
    assert_eq!(t.switch_s, 4.0);
    // Standing still on four legs is the quad posture: every env is a trial...
    assert_eq!(
        t.fell_before_switch + t.not_in_posture_at_switch,
        0,
        "{t:?}"
    );
    assert_eq!(t.trials, 3);
    assert_eq!(t.outcomes.len(), 3);
    for o in &t.outcomes {
        // ...commanded 1.5 m/s before and, from the switch on, the biped command drawn from
        // its pinned range (the hook redraws it as a drawn mode change would).
        assert_eq!(o.command_before, [1.5, 0.0, 0.0], "{o:?}");
        assert_eq!(o.command_after, [0.5, 0.0, 0.0], "{o:?}");
        // ...and never stands up, so none completes the transition.
        assert_eq!(o.transition_time_s, None, "{o:?}");
        assert!(!o.success);
    }
    assert_eq!(t.success_rate, Some(0.0));
    assert_eq!(report.metrics["trials"], 3.0);
    // Strictly counted too, with the interval 0 of 3 leaves open; standing on four feet
    // touches nothing else and never falls.
    let m = &report.metrics;
    assert_eq!(m["strict_success_rate"], 0.0);
    let [low, high] = wilson_interval(0, 3).expect("trials");
    assert_eq!(
        (
            m["strict_success_rate_ci95_low"],
            m["strict_success_rate_ci95_high"]
        ),
        (low, high)
    );
    assert_eq!(m["success_rate_ci95_high"], high);
    for key in [
        "body_contact_trials",
        "fall_trials",
        "fall_trials_whole_window",
    ] {
        assert_eq!(m[key], 0.0, "{key}");
    }
    assert!(t.outcomes.iter().all(|o| !o.body_contact.any()));
    // The trace covers 1 s before the switch to the end of the window, all three trials alive
    // at the switch.
    let h = &t.height_trace;
    let at_switch = h
        .t_s
        .iter()
        .position(|&x| x == 0.0)
        .expect("switch in the trace");
    assert_eq!(h.count[at_switch], 3);
    assert!(
        h.mean_m[at_switch] > 0.15,
        "standing height {}",
        h.mean_m[at_switch]
    );
}

#[test]
fn a_switch_in_a_rollout_reaches_the_next_action() {
    let cfg = TaskConfig::embedded_default()
        .with_overrides("modes.biped_probability = 0.0\nmodes.resampling_time_s = 3600.0")
        .expect("config");
    let env = VecEnv::new(
        Arc::new(RobotModel::go2()),
        cfg,
        Arc::new(Terrain::Flat),
        VecEnvOptions {
            num_envs: 3,
            seed: 2,
            threads: 1,
            ..VecEnvOptions::default()
        },
    )
    .expect("env");
    let mut rollout = Rollout::new(env);
    let quad = Arc::new(Tagged {
        value: 0.0,
        rows: AtomicUsize::new(0),
    });
    let biped = Arc::new(Tagged {
        value: 0.0,
        rows: AtomicUsize::new(0),
    });
    let policies = Policies::TwoPolicy {
        quad: quad.clone(),
        biped: biped.clone(),
    };
    for _ in 0..5 {
        rollout.step(&policies).expect("step");
    }
    assert_eq!(
        (
            quad.rows.load(Ordering::Relaxed),
            biped.rows.load(Ordering::Relaxed)
        ),
        (15, 0)
    );
    let before: Vec<Vec<f32>> = (0..3).map(|i| rollout.history().env(i).to_vec()).collect();
    rollout
        .set_modes(&[0, 1, 0], Mode::Biped, Some([0.25, 0.0, 0.0]))
        .expect("switch");
    let (mode_at, _) = slice_of(&OBSERVATION, "mode").expect("mode slice");
    let (cmd_at, _) = slice_of(&OBSERVATION, "cmd").expect("cmd slice");
    let out = rollout.env().output();
    let h = rollout.history().env(1);
    // The newest entry is the rewritten observation: biped one-hot, command 0.25 x scale 2.
    assert_eq!(&h[..OBS_DIM], &out.obs[OBS_DIM..2 * OBS_DIM]);
    assert_eq!(&h[mode_at..mode_at + 2], &[1.0, 0.0]);
    assert_eq!(h[cmd_at], 0.5);
    assert_ne!(&h[..OBS_DIM], &before[1][..OBS_DIM]);
    // Older entries and the other envs' histories are untouched.
    assert_eq!(&h[OBS_DIM..], &before[1][OBS_DIM..]);
    assert_eq!(rollout.history().env(0), &before[0][..]);
    assert_eq!(rollout.history().env(2), &before[2][..]);
    // The very next action of env 1 comes from the biped policy.
    rollout.step(&policies).expect("step");
    assert_eq!(
        (
            quad.rows.load(Ordering::Relaxed),
            biped.rows.load(Ordering::Relaxed)
        ),
        (17, 1)
    );
    let err = rollout
        .set_modes(&[1, 0], Mode::Quad, None)
        .expect_err("short mask");
    assert!(matches!(err, EvalError::Sim(_)), "{err}");
}

/// Counts the rows each policy sees and answers with its own constant.
struct Tagged {
    value: f32,
    rows: AtomicUsize,
}

impl Policy for Tagged {
    fn spec(&self) -> PolicySpec {
        sim_policy_spec()
    }

    fn act(&self, history: &[f32], batch: usize, actions: &mut [f32]) -> Result<(), PolicyError> {
        self.spec().check_batch(history, batch)?;
        self.rows.fetch_add(batch, Ordering::Relaxed);
        actions.fill(self.value);
        Ok(())
    }
}

#[test]
fn two_policies_each_see_only_their_mode() {
    let quad = Arc::new(Tagged {
        value: 0.25,
        rows: AtomicUsize::new(0),
    });
    let biped = Arc::new(Tagged {
        value: -0.5,
        rows: AtomicUsize::new(0),
    });
    let policies = Policies::TwoPolicy {
        quad: quad.clone(),
        biped: biped.clone(),
    };
    let spec = sim_policy_spec();
    let obs = vec![0.0; 3 * spec.obs_dim];
    let history = ObsHistory::new(spec, 3, &obs);
    let mut actions = vec![0.0; 3 * 12];
    policies.act(&history, &[1, 2, 1], &mut actions).unwrap();
    assert!(actions[..12].iter().all(|&a| a == -0.5));
    assert!(actions[12..24].iter().all(|&a| a == 0.25));
    assert!(actions[24..].iter().all(|&a| a == -0.5));
    assert_eq!(biped.rows.load(Ordering::Relaxed), 2);
    assert_eq!(quad.rows.load(Ordering::Relaxed), 1);
    assert_eq!(policies.kind(), "two_policy");
}

#[test]
fn unknown_scenarios_and_bad_sizes_are_refused() {
    let err = evaluate(
        "stairs_sideways",
        &stand_still(),
        &options(1),
        &mut NoObserver,
    )
    .expect_err("refused");
    assert!(matches!(err, EvalError::UnknownScenario { .. }));
    for name in scenario_names() {
        assert!(err.to_string().contains(name), "{err} lists {name}");
    }
    let err =
        evaluate("flat_quad", &stand_still(), &options(0), &mut NoObserver).expect_err("refused");
    assert!(err.to_string().contains("num_envs 0"), "{err}");
    let wrong = Policies::Unified(Arc::new(ConstantPolicy::zeros(PolicySpec {
        obs_dim: 50,
        ..sim_policy_spec()
    })));
    let err = evaluate("flat_quad", &wrong, &options(1), &mut NoObserver).expect_err("refused");
    assert!(matches!(err, EvalError::InvalidOption(_)), "{err}");
}

/// Counts what an observer is shown.
#[derive(Default)]
struct Counter {
    cases: usize,
    steps: usize,
    ends: usize,
}

impl StepObserver for Counter {
    fn begin_case(&mut self, _: usize, _: &str, env: &VecEnv) {
        assert!(env.num_envs() >= 1);
        self.cases += 1;
    }
    fn after_step(&mut self, _: usize, _: u32, _: &VecEnv) {
        self.steps += 1;
    }
    fn end_case(&mut self, _: usize) {
        self.ends += 1;
    }
}

#[test]
fn onnx_test_policy_runs_end_to_end() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/test_policy.onnx");
    let policy = OnnxPolicy::from_path(path, sim_policy_spec()).expect("test policy");
    let policies = Policies::Unified(Arc::new(policy));
    let mut counter = Counter::default();
    let report = evaluate("tracking_quad", &policies, &options(4), &mut counter).expect("runs");
    assert_eq!((counter.cases, counter.ends), (1, 1));
    assert_eq!(counter.steps, 900, "one 18 s episode at 50 Hz");
    for name in [
        "tracking/quad/lin_vel_error_mps",
        "tracking/quad/termination_rate",
        "tracking/quad/ang_vel_error_radps",
        "tracking/quad/do_nothing/lin_vel_error_mps",
        "tracking/quad/do_nothing/lin_vel_error_forward_mps",
        "tracking/quad/do_nothing/lin_vel_error_lateral_mps",
        "tracking/quad/do_nothing/ang_vel_error_radps",
        "head_hits",
        "head_contact_share",
    ] {
        assert!(report.metrics.contains_key(name), "no {name}");
    }
    let rate = report.metrics["tracking/quad/termination_rate"];
    assert!((0.0..=1.0).contains(&rate), "termination rate {rate}");
    // The error's parts along and across the heading bound it: max(|dx|, |dy|) <= |d| <= |dx| + |dy|.
    let m = |name: &str| report.metrics[&format!("tracking/quad/{name}")];
    let (all, forward, lateral) = (
        m("lin_vel_error_mps"),
        m("lin_vel_error_forward_mps"),
        m("lin_vel_error_lateral_mps"),
    );
    assert!(forward > 0.0 && lateral > 0.0, "{forward} {lateral}");
    assert!(
        forward.max(lateral) <= all + 1e-9,
        "{forward} {lateral} {all}"
    );
    assert!(all <= forward + lateral + 1e-9, "{forward} {lateral} {all}");
    let json: serde_json::Value = serde_json::from_str(&report.to_json()).expect("valid JSON");
    assert_eq!(json["scenario"], "tracking_quad");
    assert_eq!(json["policy"], "unified");
}

#[test]
fn an_env_that_resets_restarts_its_history_with_its_first_observation() {
    let env = VecEnv::new(
        Arc::new(RobotModel::go2()),
        TaskConfig::embedded_default(),
        Arc::new(Terrain::Flat),
        VecEnvOptions {
            num_envs: 2,
            seed: 5,
            threads: 1,
            ..VecEnvOptions::default()
        },
    )
    .expect("env");
    let mut rollout = Rollout::new(env);
    let policies = collapse();
    let mut reset_seen = false;
    for _ in 0..200 {
        rollout.step(&policies).expect("step");
        let out = rollout.env().output();
        for i in 0..2 {
            let obs = &out.obs[i * OBS_DIM..(i + 1) * OBS_DIM];
            let h = rollout.history().env(i);
            // o_t is always the newest observation.
            assert_eq!(&h[..OBS_DIM], obs);
            if out.terminated[i] != 0 {
                reset_seen = true;
                assert_eq!(&h[OBS_DIM..2 * OBS_DIM], obs, "o_t-1 refilled");
                assert_eq!(&h[2 * OBS_DIM..], obs, "o_t-2 refilled");
            }
        }
    }
    assert!(reset_seen, "the scripted fall ends an episode within 4 s");
}

#[test]
fn a_collapsing_robot_shows_leg_contacts_before_it_falls() {
    let env = VecEnv::new(
        Arc::new(RobotModel::go2()),
        TaskConfig::embedded_default(),
        Arc::new(Terrain::Flat),
        VecEnvOptions {
            num_envs: 2,
            seed: 5,
            threads: 1,
            ..VecEnvOptions::default()
        },
    )
    .expect("env");
    let mut rollout = Rollout::new(env);
    let (mut touched, mut fell) = (false, false);
    for _ in 0..200 {
        rollout.step(&collapse()).expect("step");
        for i in 0..2 {
            let p = probe(rollout.env(), i);
            if p.terminated {
                fell = true;
            } else if !fell && p.contact.any() {
                touched = true;
            }
        }
        if fell {
            break;
        }
    }
    assert!(fell, "the scripted fall ends an episode");
    assert!(touched, "knees or head are down before the trunk");
}

/// Records the fastest base (xy, any env) before and after the first push at 10 s.
#[derive(Default)]
struct PushWatch {
    before: f32,
    after: f32,
}

impl StepObserver for PushWatch {
    fn after_step(&mut self, _: usize, step: u32, env: &VecEnv) {
        // The push lands in step 500's task update; the next read-back shows it.
        let slot = match step {
            400..=500 => &mut self.before,
            501..=505 => &mut self.after,
            _ => return,
        };
        for i in 0..env.num_envs() {
            let v = probe(env, i).velocity_xy;
            *slot = slot.max(v[0].hypot(v[1]));
        }
    }
}

#[test]
fn push_scenarios_push_and_standing_still_scores_the_do_nothing_baseline() {
    let mut watch = PushWatch::default();
    let report = evaluate(
        "tracking_quad_push",
        &stand_still(),
        &options(4),
        &mut watch,
    )
    .expect("runs");
    assert!(watch.before < 0.1, "standing still: {}", watch.before);
    assert!(
        watch.after > 0.3,
        "pushed by up to 1 m/s per axis: {}",
        watch.after
    );
    assert!(report.notes.iter().any(|n| n.contains("pushes on")));
    // Without pushes, a robot that stands still misses by the command: its error is the
    // do-nothing baseline computed from the same commands (up to its sway).
    let report = evaluate(
        "tracking_quad",
        &stand_still(),
        &options(2),
        &mut NoObserver,
    )
    .expect("runs");
    let m = &report.metrics;
    for name in [
        "lin_vel_error_mps",
        "lin_vel_error_forward_mps",
        "lin_vel_error_lateral_mps",
        "ang_vel_error_radps",
    ] {
        let real = m[&format!("tracking/quad/{name}")];
        let idle = m[&format!("tracking/quad/do_nothing/{name}")];
        assert!(idle > 0.05, "{name}: the commands ask for motion: {idle}");
        assert!((real - idle).abs() < 0.03, "{name}: {real} vs {idle}");
    }
}

fn heading_yaw(env: &VecEnv, i: usize) -> f32 {
    unigait_sim::task::heading_yaw(env.robot_state(i).base_rot)
}

/// After every step of a traversal, checks each running env's yaw-rate command against the
/// heading hold of the heading the step started from.
#[derive(Default)]
struct HeadingCheck {
    course: Vec<f32>,
    last_yaw: Vec<f32>,
    checked: usize,
    steered: usize,
}

impl StepObserver for HeadingCheck {
    fn begin_case(&mut self, _: usize, _: &str, env: &VecEnv) {
        self.course = (0..env.num_envs()).map(|i| heading_yaw(env, i)).collect();
        self.last_yaw = self.course.clone();
    }
    fn after_step(&mut self, _: usize, _: u32, env: &VecEnv) {
        for i in 0..env.num_envs() {
            let e = env.env_state(i);
            if e.episode_step > 0 {
                // The quad's yaw-rate range is +-1 rad/s; the gain is 1.
                let expected = heading_hold(self.course[i], self.last_yaw[i], 1.0, [-1.0, 1.0]);
                assert!(
                    (e.command[2] - expected).abs() < 1e-6,
                    "env {i}: {} vs {expected}",
                    e.command[2]
                );
                assert_eq!(e.command[0], 0.8, "the forward command stays");
                self.checked += 1;
                self.steered += usize::from(e.command[2] != 0.0);
            }
            self.last_yaw[i] = heading_yaw(env, i);
        }
    }
}

#[test]
fn a_traversal_steers_each_robot_back_to_its_starting_heading() {
    let mut check = HeadingCheck::default();
    evaluate("flat_quad", &stand_still(), &options(2), &mut check).expect("flat_quad");
    assert!(check.checked > 1000, "{} checks", check.checked);
    // A robot standing on its four feet turns by float noise: every command steers a little.
    assert!(check.steered > 0, "no command ever steered");
}

/// Each env's last pose before its trial ended, measured apart from the evaluator: the base's
/// offset across the course (left of travel positive) and its heading off the starting one.
#[derive(Default)]
struct EndPose {
    direction: f32,
    course: Vec<f32>,
    last: Vec<(f32, f32)>,
    cases: Vec<(String, Vec<(f32, f32)>)>,
}

impl StepObserver for EndPose {
    fn begin_case(&mut self, _: usize, name: &str, env: &VecEnv) {
        self.direction = if name.contains("backward") { -1.0 } else { 1.0 };
        self.course = (0..env.num_envs()).map(|i| heading_yaw(env, i)).collect();
        self.last = vec![(0.0, 0.0); env.num_envs()];
        self.cases.push((name.to_string(), Vec::new()));
    }
    fn after_step(&mut self, _: usize, _: u32, env: &VecEnv) {
        for i in 0..env.num_envs() {
            let p = probe(env, i);
            if p.terminated || p.truncated {
                continue;
            }
            let mut off = heading_yaw(env, i) - self.course[i];
            while off >= std::f32::consts::PI {
                off -= std::f32::consts::TAU;
            }
            while off < -std::f32::consts::PI {
                off += std::f32::consts::TAU;
            }
            self.last[i] = (self.direction * (p.base[1] - p.origin[1]), off);
        }
    }
    fn end_case(&mut self, _: usize) {
        if let Some(case) = self.cases.last_mut() {
            case.1 = self.last.clone();
        }
    }
}

#[test]
fn a_trial_reports_where_it_ended_across_its_course() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/test_policy.onnx");
    let policy = OnnxPolicy::from_path(path, sim_policy_spec()).expect("test policy");
    let policies = Policies::Unified(Arc::new(policy));
    let mut ends = EndPose::default();
    let report = evaluate("stairs_down_quad", &policies, &options(4), &mut ends).expect("runs");
    let t = report.traversal.expect("traversal report");
    assert_eq!(ends.cases.len(), 2, "forward and backward");
    let mut off_course = 0.0f32;
    for o in &t.outcomes {
        let (_, poses) = ends
            .cases
            .iter()
            .find(|(name, _)| name == o.case)
            .expect("the case ran");
        let (lateral, heading) = poses[o.env];
        assert!((o.lateral_m - lateral).abs() < 1e-5, "{o:?} vs {lateral}");
        assert!(
            (o.heading_off_rad - heading).abs() < 1e-5,
            "{o:?} vs {heading}"
        );
        off_course = off_course.max(o.lateral_m.abs());
    }
    // The test policy is no walker: its robots end visibly off the straight line.
    assert!(off_course > 0.01, "{:?}", t.outcomes);
    // Standing still ends where it started, facing the way it started.
    let report = evaluate("flat_quad", &stand_still(), &options(2), &mut NoObserver).expect("runs");
    for o in &report.traversal.expect("traversal report").outcomes {
        assert!(o.lateral_m.abs() < 0.02, "{o:?}");
        assert!(o.heading_off_rad.abs() < 0.05, "{o:?}");
    }
}
