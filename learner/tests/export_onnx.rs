//! The exported ONNX policy, loaded by the server's own loader (unigait-policy, tract), acts as
//! the burn networks do: the estimator fused in front of the actor, [B, 3, 53] -> [B, 12].

use unigait_learner::config::TrainConfig;
use unigait_learner::env::Dims;
use unigait_learner::learner::Learner;
use unigait_learner::nets::{Mlp, layer};
use unigait_learner::onnx::export_policy;
use unigait_learner::run::{export_checkpoint, policy_onnx};
use unigait_policy::{ModelLimits, OnnxPolicy, Policy, PolicySpec, check_model, parse_checked};

const DIMS: Dims = Dims {
    obs: 53,
    labels: 14,
    privileged: 10,
    actions: 12,
    history_length: 3,
};

/// Hand-chosen histories: zeros, ones, a ramp over [-2, 2], alternating signs, one large entry.
fn histories() -> Vec<f32> {
    let w = DIMS.history();
    let mut x = vec![0.0f32; w];
    x.extend(vec![1.0f32; w]);
    x.extend((0..w).map(|i| -2.0 + 4.0 * i as f32 / (w - 1) as f32));
    x.extend((0..w).map(|i| if i % 2 == 0 { 0.5 } else { -0.5 }));
    let mut spike = vec![0.0f32; w];
    spike[47] = 10.0; // the clock's first entry of o_t
    x.extend(spike);
    x
}

fn spec() -> PolicySpec {
    PolicySpec {
        history: 3,
        obs_dim: 53,
        num_actions: 12,
    }
}

#[test]
fn the_export_acts_as_the_burn_actor_in_the_servers_loader() {
    let learner = Learner::new(TrainConfig::default(), DIMS, 1);
    let bytes = policy_onnx(&learner).unwrap();
    // The server's checks on untrusted policies pass (op allow-list, sizes).
    let proto = parse_checked(&bytes, &ModelLimits::default()).unwrap();
    check_model(&proto, &ModelLimits::default()).unwrap();
    let policy = OnnxPolicy::from_bytes(&bytes, spec()).unwrap();
    assert_eq!(policy.input_name(), "obs_history");
    assert_eq!(policy.output_name(), "actions");
    assert_eq!(policy.fixed_batch(), None, "the batch is symbolic");
    let x = histories();
    let batch = x.len() / DIMS.history();
    let ours = learner.policy_actions(&x).unwrap();
    let theirs = policy.act_vec(&x, batch).unwrap();
    assert_eq!(ours.len(), batch * 12);
    for (i, (a, b)) in ours.iter().zip(&theirs).enumerate() {
        assert!((a - b).abs() < 1e-5, "action {i}: burn {a}, server {b}");
    }
    // One row alone gives the same as within the batch (no mixing across rows; tract plans
    // each batch size on its own, so the last bits may differ).
    let one = policy.act_vec(&x[..DIMS.history()], 1).unwrap();
    for (a, b) in one.iter().zip(&theirs[..12]) {
        assert!((a - b).abs() < 1e-6, "{one:?} vs {:?}", &theirs[..12]);
    }
    // The untrained networks do not answer zeros: the comparison compares something.
    assert!(ours.iter().any(|a| a.abs() > 1e-3));
}

/// A network small enough to compute by hand: history of 1 x 2, estimate of 1, action of 1.
/// Estimator: one layer, e = 0.5 x0 - x1 + 0.25. Actor: 3 -> [1] -> 1, h = elu(x0 + x1 + 2 e - 1),
/// a = 3 h + 0.1.
/// x = (1, 2): e = -1.25, h = elu(3 - 2.5 - 1) = elu(-0.5) = e^-0.5 - 1 = -0.393469,
/// a = -1.180408 + 0.1 = -1.080408.
/// x = (2, 0): e = 1.25, h = elu(2 + 2.5 - 1) = 3.5, a = 10.6.
#[test]
fn the_export_computes_the_hand_computed_actions() {
    let dev = unigait_learner::nets::device();
    let estimator = Mlp {
        layers: vec![layer(vec![0.5, -1.0], vec![0.25], 2, 1, &dev)],
    };
    let actor = Mlp {
        layers: vec![
            layer(vec![1.0, 1.0, 2.0], vec![-1.0], 3, 1, &dev),
            layer(vec![3.0], vec![0.1], 1, 1, &dev),
        ],
    };
    let bytes = export_policy(&estimator, &actor, 1, 2, 1, "articulated").unwrap();
    assert_eq!(
        unigait_policy::trained_engine(&bytes).unwrap().as_deref(),
        Some("articulated")
    );
    let spec = PolicySpec {
        history: 1,
        obs_dim: 2,
        num_actions: 1,
    };
    let policy = OnnxPolicy::from_bytes(&bytes, spec).unwrap();
    let a = policy.act_vec(&[1.0, 2.0, 2.0, 0.0], 2).unwrap();
    assert!((a[0] + 1.080408).abs() < 1e-5, "{a:?}");
    assert!((a[1] - 10.6).abs() < 1e-5, "{a:?}");
}

/// A checkpoint's export (what `unigait-learner export` writes) is the learner's own.
#[test]
fn a_checkpoint_exports_the_same_policy() {
    let mut cfg = TrainConfig::default();
    cfg.runner.seed = 7;
    let learner = Learner::new(cfg, DIMS, 1);
    let ck = learner.to_checkpoint().unwrap();
    assert_eq!(
        export_checkpoint(&ck).unwrap(),
        policy_onnx(&learner).unwrap()
    );
}

/// A checkpoint names the engine it trained on; one from before that was recorded, its task's
/// choice, else rapier (decision record 0026); the export is stamped with it.
#[test]
fn a_checkpoint_names_its_engine_or_its_tasks_or_rapier() {
    let plain = Learner::new(TrainConfig::default(), DIMS, 1);
    let mut old = serde_json::to_value(&plain.to_checkpoint().unwrap().header).unwrap();
    old.as_object_mut().unwrap().remove("physics_engine");
    let old: unigait_learner::checkpoint::Header = serde_json::from_value(old).unwrap();
    assert_eq!(old.physics_engine, "");
    assert_eq!(old.trained_engine(), "rapier");

    let mut cfg = TrainConfig::default();
    cfg.env.task = toml::from_str("[physics]\nengine = \"articulated\"\n").unwrap();
    let mut ck = Learner::new(cfg, DIMS, 1).to_checkpoint().unwrap();
    assert_eq!(ck.header.physics_engine, "articulated");
    ck.header.physics_engine = String::new();
    assert_eq!(ck.header.trained_engine(), "articulated");
    ck.header.physics_engine = "rapier".into();
    assert_eq!(ck.header.trained_engine(), "rapier");
    let onnx = export_checkpoint(&ck).unwrap();
    assert_eq!(
        unigait_policy::trained_engine(&onnx).unwrap().as_deref(),
        Some("rapier")
    );
}
