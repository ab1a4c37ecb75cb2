//! Time tract on an ONNX policy at a given batch.
//!
//! ```text
//! .venv/bin/python tests/data/make_test_policy.py --paper /tmp/paper_policy.onnx
//! cargo run --release -p unigait-policy --example bench_policy -- /tmp/paper_policy.onnx 4096
//! .venv/bin/python tests/data/bench_torch.py --onnx /tmp/paper_policy.onnx --batch 4096
//! ```
//! Prints one JSON line: the median wall time per batched call (ms), per env (us), and the
//! median CPU time of the calling thread per call (ms; tract runs on that one thread), which a
//! busy machine disturbs less than the wall time since time spent descheduled is not counted.
//! `bench_torch.py` prints the same fields for the same network and inputs.

use std::time::Instant;

use unigait_policy::{OnnxPolicy, Policy, PolicySpec};

/// CPU time consumed by the calling thread, in seconds (NaN where not measured).
fn thread_cpu_s() -> f64 {
    #[cfg(all(target_os = "linux", target_pointer_width = "64"))]
    {
        /// `struct timespec` on 64-bit Linux.
        #[repr(C)]
        struct Timespec {
            sec: i64,
            nsec: i64,
        }
        unsafe extern "C" {
            fn clock_gettime(clock: i32, ts: *mut Timespec) -> i32;
        }
        const CLOCK_THREAD_CPUTIME_ID: i32 = 3;
        let mut ts = Timespec { sec: 0, nsec: 0 };
        // SAFETY: clock_gettime (glibc/musl) writes one timespec to a valid pointer.
        if unsafe { clock_gettime(CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            return ts.sec as f64 + ts.nsec as f64 * 1e-9;
        }
    }
    f64::NAN
}

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

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
    // The inputs of `history_inputs` in tests/data/make_test_policy.py and bench_torch.py.
    let input: Vec<f32> = (0..batch)
        .flat_map(|b| (0..w).map(move |k| ((b * 53 + k * 17) % 101) as f32 / 50.0 - 1.0))
        .collect();
    let mut actions = vec![0.0; batch * policy.spec().num_actions];
    // Warm-up: the first call also builds the plans for this batch's row counts.
    let t1 = Instant::now();
    policy.act(&input, batch, &mut actions)?;
    let first_call_s = t1.elapsed().as_secs_f64();
    for _ in 0..2 {
        policy.act(&input, batch, &mut actions)?;
    }
    let mut wall = Vec::with_capacity(iterations);
    let mut cpu = Vec::with_capacity(iterations);
    for _ in 0..iterations.max(1) {
        let (t, c) = (Instant::now(), thread_cpu_s());
        policy.act(&input, batch, &mut actions)?;
        cpu.push(thread_cpu_s() - c);
        wall.push(t.elapsed().as_secs_f64());
    }
    let min = wall.iter().copied().fold(f64::INFINITY, f64::min);
    let (wall, cpu) = (median(wall), median(cpu));
    println!(
        "{{\"engine\": \"tract\", \"batch\": {batch}, \"threads\": 1, \"median_ms\": {:.3}, \"min_ms\": {:.3}, \"cpu_ms\": {:.3}, \"per_env_us\": {:.3}, \"load_s\": {load_s:.3}, \"first_call_ms\": {:.3}, \"checksum\": {:.6}}}",
        wall * 1e3,
        min * 1e3,
        cpu * 1e3,
        wall * 1e6 / batch as f64,
        first_call_s * 1e3,
        actions.iter().map(|v| *v as f64).sum::<f64>(),
    );
    Ok(())
}
