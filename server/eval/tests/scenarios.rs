//! Scenario runs with scripted policies: a policy that stands still never crosses anything, a
//! scripted fall is a failure, the transition bookkeeping adds up, the two-policy baseline
//! routes each env to its mode's policy, and the committed ONNX test policy runs end to end.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use unigait_eval::{
    EvalError, EvalOptions, NoObserver, Policies, Rollout, StepObserver, TraversalEnd, evaluate,
    scenario_names, sim_policy_spec,
};
use unigait_policy::{ConstantPolicy, ObsHistory, OnnxPolicy, Policy, PolicyError, PolicySpec};
use unigait_sim::env::{VecEnv, VecEnvOptions};
use unigait_sim::robot::RobotModel;
use unigait_sim::task::{OBS_DIM, TaskConfig};
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
    for name in ["flat_quad", "stairs_up_quad"] {
        let report = evaluate(name, &stand_still(), &options(2), &mut NoObserver).expect(name);
        let t = report.traversal.as_ref().expect("traversal report");
        assert_eq!(t.trials, 2, "{name}");
        assert_eq!(t.successes, 0, "{name}: {:?}", t.outcomes);
        assert_eq!(report.metrics["success_rate"], 0.0, "{name}");
        for o in &t.outcomes {
            assert!(o.progress_m < 1.0, "{name}: {o:?}");
            assert_ne!(o.end, TraversalEnd::Crossed);
        }
    }
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
fn transition_bookkeeping_adds_up() {
    let report = evaluate(
        "transition_biped_to_quad",
        &stand_still(),
        &options(24),
        &mut NoObserver,
    )
    .expect("runs");
    let t = report.transition.as_ref().expect("transition report");
    assert_eq!(t.envs, 24);
    assert!(t.eligible <= 24);
    // Standing still, a robot never gets onto its front legs: no eligible env is in the biped
    // posture at the switch, so there is no trial and no rate.
    assert_eq!(t.trials + t.not_in_posture_at_switch, t.eligible);
    assert_eq!(t.trials, 0);
    assert_eq!(t.success_rate, None);
    assert!(!report.metrics.contains_key("success_rate"));
    assert!(report.to_json().contains("\"transition\""));
    // The quad policy tracks nothing while standing: its error is about the command.
    assert!(report.tracking.contains_key("quad") || report.tracking.contains_key("biped"));
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
    assert_eq!(counter.steps, 500, "10 s at 50 Hz");
    assert!(
        report
            .metrics
            .contains_key("tracking/quad/lin_vel_error_mps")
    );
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
