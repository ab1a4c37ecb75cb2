//! Time tract on an ONNX policy at a given batch.
//!
//! ```text
//! .venv/bin/python tests/data/make_test_policy.py --paper /tmp/paper_policy.onnx
//! cargo run --release -p unigait-policy --example bench_policy -- /tmp/paper_policy.onnx 4096
//! .venv/bin/python tests/data/bench_torch.py --batch 4096     # the same network in torch
//! ```
//! Prints one JSON line: the median time per batched call (ms) and per env (us).

use std::time::Instant;

use unigait_policy::{OnnxPolicy, Policy, PolicySpec};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .ok_or("usage: bench_policy POLICY.onnx [BATCH] [ITERATIONS]")?;
    let batch: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(4096);
    let iterations: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(20);
    let t0 = Instant::now();
    let policy = OnnxPolicy::from_path(&path, PolicySpec::default())?;
    let load_s = t0.elapsed().as_secs_f64();
    let w = policy.spec().input_width();
    let input: Vec<f32> = (0..batch * w)
        .map(|k| ((k * 17) % 101) as f32 / 50.0 - 1.0)
        .collect();
    let mut actions = vec![0.0; batch * policy.spec().num_actions];
    for _ in 0..3 {
        policy.act(&input, batch, &mut actions)?;
    }
    let mut times: Vec<f64> = (0..iterations.max(1))
        .map(|_| {
            let t = Instant::now();
            policy
                .act(&input, batch, &mut actions)
                .map(|_| t.elapsed().as_secs_f64())
        })
        .collect::<Result<_, _>>()?;
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    println!(
        "{{\"engine\": \"tract\", \"batch\": {batch}, \"median_ms\": {:.3}, \"min_ms\": {:.3}, \"per_env_us\": {:.3}, \"load_s\": {load_s:.3}, \"threads\": 1}}",
        median * 1e3,
        times[0] * 1e3,
        median * 1e6 / batch as f64
    );
    Ok(())
}
