use std::sync::Arc;
use unigait_sim::prelude::*;
fn main() {
    let model = Arc::new(RobotModel::go2());
    let mut cfg = TaskConfig::embedded_default();
    if let Ok(o) = std::env::var("OV") { cfg = cfg.with_overrides(&o).unwrap(); }
    let n = 256;
    let mut env = VecEnv::new(model.clone(), cfg, Arc::new(Terrain::Flat), VecEnvOptions { num_envs: n, seed: 1, threads: 2, physics_only: std::env::var("PO").is_ok(), autoreset: true }).unwrap();
    let mut x: u64 = 7;
    let mut events = vec![];
    for step in 0..400 {
        let a: Vec<f32> = (0..n * 12).map(|_| { x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407); ((x >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0 }).collect();
        let out = env.step(&a).unwrap().clone();
        for i in 0..n {
            let s = env.robot_state(i);
            if s.max_joint_gap > 0.005 {
                let poses = env.body_poses(i);
                let gaps: Vec<i32> = model.joints.iter().map(|j| (poses[j.parent_body].transform_point(j.origin.translation).distance(poses[j.child_body].translation) * 1e4) as i32).collect();
                events.push(format!("step {step} env {i} term {} gap {:.1}mm joints(0.1mm) {:?} z {:.2} pitch {:.2} v {:.1} w {:.1} feetF {:?} trunkF {:.0} pen {} qd {:?} q {:?} tau {:?}", out.terminated[i], s.max_joint_gap*1e3, gaps, s.base_pos.z, unigait_sim::task::euler_pitch(s.base_rot), s.base_linvel.length(), s.base_angvel.length(), s.foot_force.map(|f| f as i32), s.trunk_force, s.penalised_contacts, s.qd.map(|v| v.round() as i32), s.q.map(|v| (v*10.0).round()/10.0), out.torques[i*12..i*12+12].iter().map(|v| v.round() as i32).collect::<Vec<_>>()));
            }
        }
    }
    for e in &events { println!("{e}"); }
}
