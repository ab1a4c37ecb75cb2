//! Gauss-Seidel sweeps per robot step of the articulated engine: 16 robots standing on flat
//! ground, PD targets moved at random every policy step (`cargo run --release -p unigait-sim
//! --example articulated_sweeps`).
use rapier3d::math::{Pose, Vec3};
use unigait_sim::physics::articulated::ArticulatedWorld;
use unigait_sim::physics::{EngineKind, PhysicsParams, RobotPhysicalParams};
use unigait_sim::prelude::*;

fn main() {
    let model = RobotModel::go2();
    let p = PhysicsParams {
        engine: EngineKind::Articulated,
        ..PhysicsParams::default()
    };
    let n = 16;
    let mut w = ArticulatedWorld::new(&model, n, &Terrain::Flat, &p);
    let q0: [f32; NUM_JOINTS] = std::array::from_fn(|j| model.config.default_joint_pos[j]);
    for s in 0..n {
        w.set_robot_state(
            &model,
            s,
            Pose::from_translation(Vec3::new(0.0, 0.0, 0.33)),
            Vec3::ZERO,
            Vec3::ZERO,
            &q0,
        );
    }
    let act = vec![RobotPhysicalParams::nominal(&model).actuator; n];
    let mut torques = vec![0.0; n * NUM_JOINTS];
    let mut state = 1u64;
    let mut targets = vec![0.0f32; n * NUM_JOINTS];
    for step in 0..400 {
        if step % 4 == 0 {
            for (i, t) in targets.iter_mut().enumerate() {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let a = ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0;
                *t = q0[i % NUM_JOINTS] + 0.25 * a;
            }
        }
        let before = w.sweeps;
        w.step(&model, &targets, &act, &mut torques);
        if step % 50 == 49 {
            println!(
                "step {step}: sweeps per robot {}",
                (w.sweeps - before) as f64 / n as f64
            );
        }
    }
}
