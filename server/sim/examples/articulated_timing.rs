//! Time the articulated dynamics' first layer for one Go2 (issue 34): forward kinematics, mass
//! matrix (CRBA), bias forces (RNEA), `L^T D L` factorisation and one solve, per call, on one
//! core, in f64 and f32 (each figure the fastest of seven runs). A printed figure, not a test.
//!
//! ```sh
//! cargo run --release -p unigait-sim --example articulated_timing
//! cargo run --release -p unigait-sim --example articulated_timing -- 500000   # more calls
//! ```

use std::hint::black_box;
use std::time::Instant;

use unigait_sim::physics::articulated::{ArticulatedTree, Real, Workspace};
use unigait_sim::robot::RobotModel;

/// Sixteen spread-out states (base anywhere, joints and rates within a few rad).
fn states<T: Real>() -> Vec<(Vec<T>, Vec<T>)> {
    let mut s = 34u64;
    let mut next = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    (0..16)
        .map(|_| {
            let mut qpos = vec![next(), next(), 0.4];
            let quat = [next(), next(), next(), next()];
            let norm = quat.iter().map(|x| x * x).sum::<f64>().sqrt();
            qpos.extend(quat.iter().map(|x| x / norm));
            qpos.extend((0..12).map(|_| 1.5 * next()));
            let qvel: Vec<f64> = (0..18).map(|_| 3.0 * next()).collect();
            (
                qpos.into_iter().map(T::from_f64).collect(),
                qvel.into_iter().map(T::from_f64).collect(),
            )
        })
        .collect()
}

/// Microseconds per call of the first `stages` stages in a row (kinematics, mass matrix, bias,
/// factor, solve), timed around the whole loop so that no clock read sits inside it.
fn chain<T: Real>(tree: &ArticulatedTree<T>, stages: usize, calls: usize) -> f64 {
    let states = states::<T>();
    let mut ws = Workspace::new(tree);
    let gravity = [T::ZERO, T::ZERO, T::from_f64(-9.81)];
    let mut rhs = vec![T::ONE; tree.nv()];
    let start = Instant::now();
    for i in 0..calls {
        let (qpos, qvel) = &states[i % states.len()];
        tree.forward_kinematics(&mut ws, black_box(qpos), black_box(qvel));
        if stages > 1 {
            tree.mass_matrix(&mut ws);
        }
        if stages > 2 {
            tree.bias_forces(&mut ws, &gravity);
        }
        if stages > 3 {
            tree.factor(&mut ws);
        }
        if stages > 4 {
            rhs.copy_from_slice(ws.bias());
            tree.solve(&ws, &mut rhs);
        }
        black_box(&ws);
        black_box(&rhs);
    }
    start.elapsed().as_secs_f64() * 1e6 / calls as f64
}

fn time<T: Real>(tree: &ArticulatedTree<T>, calls: usize) {
    chain(tree, 5, calls / 4); // warm up
    // The fastest of seven runs of each chain: the machine is shared, and interference only
    // ever adds time.
    let totals: Vec<f64> = (1..=5)
        .map(|n| {
            (0..7)
                .map(|_| chain(tree, n, calls))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    let names = ["kinematics", "mass matrix", "bias", "factor", "solve"];
    for (n, name) in names.iter().enumerate() {
        let own = totals[n] - if n == 0 { 0.0 } else { totals[n - 1] };
        println!(
            "  {name:12} {own:6.3} us   (chain so far {:.3} us)",
            totals[n]
        );
    }
    println!(
        "  mass matrix + bias + factor: {:.3} us",
        totals[3] - totals[0]
    );
}

fn main() {
    let calls: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(200_000);
    let tree = match ArticulatedTree::from_robot(&RobotModel::go2(), 0.02) {
        Ok(tree) => tree,
        Err(e) => {
            eprintln!("cannot build the Go2 tree: {e}");
            std::process::exit(1);
        }
    };
    println!(
        "Go2: {} bodies, nv {}, {} stored mass-matrix entries; {calls} calls, one core",
        tree.num_bodies(),
        tree.nv(),
        tree.nnz()
    );
    println!("f64:");
    time(&tree, calls);
    println!("f32:");
    time(&tree.cast::<f32>(), calls);
}
