//! Evaluate a policy in-process (no server) and print the JSON report.
//!
//! ```text
//! cargo run --release -p unigait-eval --example eval_policy -- SCENARIO POLICY.onnx|zeros [ENVS] [SEED]
//! ```

use std::sync::Arc;

use unigait_eval::{EvalOptions, NoObserver, Policies, evaluate, sim_policy_spec};
use unigait_policy::{ConstantPolicy, OnnxPolicy, Policy};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scenario, policy, rest @ ..] = args.as_slice() else {
        return Err("usage: eval_policy SCENARIO POLICY.onnx|zeros [ENVS] [SEED]".into());
    };
    let policy: Arc<dyn Policy> = if policy == "zeros" {
        Arc::new(ConstantPolicy::zeros(sim_policy_spec()))
    } else {
        Arc::new(OnnxPolicy::from_path(policy, sim_policy_spec())?)
    };
    let options = EvalOptions {
        num_envs: rest.first().map(|s| s.parse()).transpose()?,
        seed: rest.get(1).map(|s| s.parse()).transpose()?.unwrap_or(0),
        ..EvalOptions::default()
    };
    let report = evaluate(
        scenario,
        &Policies::Unified(policy),
        &options,
        &mut NoObserver,
    )?;
    println!("{}", report.to_json());
    Ok(())
}
