//! The articulated engine (`physics.engine = "articulated"`) against physical expectations.

mod common;

use std::sync::Arc;

use common::*;
use rapier3d::math::{Pose, Vec3};
use rapier3d::prelude::LockedAxes;
use unigait_sim::physics::articulated::ArticulatedWorld;
use unigait_sim::physics::{
    ActuatorParams, EngineKind, MAX_SOUND_BASE_SPEED, MAX_SOUND_BASE_SPIN, MAX_SOUND_JOINT_SPEED,
    PhysicsParams, RobotPhysicalParams,
};
use unigait_sim::prelude::*;
use unigait_sim::task::euler_pitch;
use unigait_sim::terrain::{TerrainCollider, TerrainKind, TerrainSpec, TerrainType};

const ENGINE: &str = "physics.engine = \"articulated\"\n";
/// Gravity and step as the config's f32 9.81 and 0.005 give them.
const G: f64 = 9.8100004196167;
const H: f64 = 0.004999999888241291;

fn articulated(extra: &str) -> TaskConfig {
    calm_config(&format!("{ENGINE}{extra}"))
}

fn params() -> PhysicsParams {
    PhysicsParams {
        engine: EngineKind::Articulated,
        ..PhysicsParams::default()
    }
}

fn default_q(model: &RobotModel) -> [f32; NUM_JOINTS] {
    std::array::from_fn(|j| model.config.default_joint_pos[j])
}

/// One robot in its own articulated world over flat ground, at `z` in the default pose.
fn lone_robot(model: &RobotModel, z: f32) -> ArticulatedWorld {
    let mut world = ArticulatedWorld::new(model, 1, &Terrain::Flat, &params());
    let base = Pose::from_translation(Vec3::new(0.0, 0.0, z));
    world.set_robot_state(model, 0, base, Vec3::ZERO, Vec3::ZERO, &default_q(model));
    world
}

#[test]
fn the_config_selects_the_engine() {
    let c = articulated("");
    assert_eq!(c.physics.engine, EngineKind::Articulated);
    // The default, in the code and in the embedded task file alike (issue 34's gates held).
    assert_eq!(
        TaskConfig::embedded_default().physics.engine,
        EngineKind::Articulated
    );
    assert_eq!(
        TaskConfig::default().physics.engine,
        EngineKind::Articulated
    );
    let rapier = TaskConfig::embedded_default()
        .with_overrides("physics.engine = \"rapier\"")
        .expect("rapier stays an option");
    assert_eq!(rapier.physics.engine, EngineKind::Rapier);
    assert!(
        TaskConfig::embedded_default()
            .with_overrides("physics.engine = \"mujoco\"")
            .is_err()
    );
}

/// Free fall from rest at the default pose with the PD holding it: semi-implicit Euler gives
/// exactly `v_n = -g h n` and `z_n = z_0 - g h^2 n (n + 1) / 2`; the joints do not move (gravity
/// accelerates every body alike); the energy changes by exactly the integrator's
/// `-m g^2 h^2 n / 2` (3.6 J of 722 J gained as kinetic energy over 1 s).
#[test]
fn free_fall_follows_semi_implicit_euler() {
    let model = RobotModel::go2();
    let mut world = lone_robot(&model, 10.0);
    let act = [RobotPhysicalParams::nominal(&model).actuator];
    let targets = default_q(&model);
    let mut torques = [0.0; NUM_JOINTS];
    let e0 = world.mechanical_energy(0);
    let q0 = world.state(0).0.to_vec();
    let n = 200;
    for _ in 0..n {
        world.step(&model, &targets, &act, &mut torques);
    }
    let (qpos, qvel) = world.state(0);
    let nf = n as f64;
    let z = 10.0 - G * H * H * nf * (nf + 1.0) / 2.0;
    assert!((qpos[2] - z).abs() < 1e-9, "z {} vs {z}", qpos[2]);
    assert!((qvel[2] + G * H * nf).abs() < 1e-9, "vz {}", qvel[2]);
    for k in [0, 1, 3, 4, 5, 6] {
        assert!((qpos[k] - q0[k]).abs() < 1e-9, "qpos[{k}] moved");
    }
    for k in 7..19 {
        assert!((qpos[k] - q0[k]).abs() < 1e-9, "joint {k} moved");
    }
    let mass: f64 = 15.019;
    let expected = -0.5 * mass * G * G * H * H * nf;
    let de = world.mechanical_energy(0) - e0;
    assert!(
        (de - expected).abs() < 1e-3,
        "energy change {de} J, expected {expected} J"
    );
}

/// Worst change of the mechanical energy (J) over 2 s of legs swinging freely from a bent pose,
/// the trunk held still in the air, with time step `dt`; and the fastest thigh rate seen.
fn free_swing(dt: f32) -> (f64, f64) {
    let model = RobotModel::go2();
    let p = PhysicsParams { dt, ..params() };
    let mut world = ArticulatedWorld::new(&model, 1, &Terrain::Flat, &p);
    world.lock_trunk(0, LockedAxes::all());
    world.set_limits_enabled(false);
    let mut q = default_q(&model);
    // Thighs swung 0.6 rad forward, calves half-bent.
    for leg in 0..4 {
        q[3 * leg + 1] = -0.6;
        q[3 * leg + 2] = -1.2;
    }
    let base = Pose::from_translation(Vec3::new(0.0, 0.0, 5.0));
    world.set_robot_state(&model, 0, base, Vec3::ZERO, Vec3::ZERO, &q);
    let free = [ActuatorParams {
        kp: 0.0,
        kd: 0.0,
        damping: 0.0,
        friction: 0.0,
    }];
    let mut torques = [0.0; NUM_JOINTS];
    let e0 = world.mechanical_energy(0);
    let (mut worst, mut swing): (f64, f64) = (0.0, 0.0);
    for _ in 0..(2.0 / dt).round() as usize {
        world.step(&model, &q, &free, &mut torques);
        worst = worst.max((world.mechanical_energy(0) - e0).abs());
        swing = swing.max(world.state(0).1[7].abs());
    }
    assert!((world.state(0).0[2] - 5.0).abs() < 1e-12, "the trunk moved");
    (worst, swing)
}

/// The trunk held still in the air, no motor, no damping or friction, no stops: the legs swing
/// (thighs past 4 rad/s, some 1.2 J of kinetic energy) and the energy error of semi-implicit
/// Euler stays bounded and first order in the step: under 0.1 J at 5 ms (measured 0.059 J), and
/// between 0.35 and 0.65 of that at 2.5 ms.
#[test]
fn undamped_swinging_legs_conserve_energy() {
    let (coarse, swing) = free_swing(0.005);
    let (fine, _) = free_swing(0.0025);
    println!(
        "worst energy change {coarse} J at 5 ms, {fine} J at 2.5 ms; thigh up to {swing} rad/s"
    );
    assert!(swing > 4.0, "the legs did not swing (thigh rate {swing})");
    assert!(coarse < 0.1, "energy changed by up to {coarse} J");
    let ratio = fine / coarse;
    assert!(
        (0.35..=0.65).contains(&ratio),
        "halving the step scaled the error by {ratio}"
    );
}

/// Dropped with its feet 0.25 m above ground: free fall for 0.1 s, lands on its feet, and rests
/// in the standing band with every foot sphere less than 3 mm into the ground.
#[test]
fn dropped_robot_comes_to_rest_on_flat_ground() {
    let model = RobotModel::go2();
    let mut env = batch(articulated("init.spawn_clearance = 0.25"), 1, 0, 1);
    let z0 = env.robot_state(0).base_pos.z;
    let zeros = vec![0.0; NUM_JOINTS];
    for _ in 0..5 {
        env.step(&zeros).expect("step");
    }
    let fallen = z0 - env.robot_state(0).base_pos.z;
    // 20 physics steps: g h^2 20 21 / 2 = 0.0515 m.
    assert!((fallen - 0.0515).abs() < 1e-3, "fell {fallen} m in 0.1 s");
    for step in 0..250 {
        let out = env.step(&zeros).expect("step");
        assert_eq!(out.terminated[0], 0, "the trunk hit the ground at {step}");
    }
    let s = env.robot_state(0);
    let weight = GO2_MASS * 9.81;
    let carried: f32 = s.foot_force.iter().sum();
    let sink = (0..NUM_FEET)
        .map(|f| model.feet[f].radius - s.foot_pos[f].z)
        .fold(f32::MIN, f32::max);
    println!(
        "rest: base {} m, feet carry {carried} N, deepest foot {sink} m, |v| {}",
        s.base_pos.z,
        s.base_linvel.length()
    );
    assert!(
        (0.24..=0.30).contains(&s.base_pos.z),
        "settled at {}",
        s.base_pos.z
    );
    assert!(sink < 3e-3, "a foot is {sink} m into the ground");
    assert!(s.base_linvel.length() < 0.01, "still moving");
    assert!(
        (carried - weight).abs() < 0.03 * weight,
        "feet carry {carried} N of {weight} N"
    );
}

/// Zero actions hold the default pose: after 10 s the robot stands still (no drift over the last
/// 5 s beyond 1 mm), level, at the rapier engine's height (0.269 m), joints within 0.35 rad of
/// their default angles (kp 20 lets the legs sag: a calf holding ~6 N m sits 0.3 rad off), and
/// the feet carry the weight.
#[test]
fn pd_holds_the_default_standing_pose() {
    let model = RobotModel::go2();
    let mut env = batch(articulated(""), 2, 0, 1);
    let late = stand(&mut env, 500, 250);
    let last = late.last().expect("states");
    println!(
        "standing: base {} m, pitch {}, q {:?}",
        last.base_pos.z,
        euler_pitch(last.base_rot),
        last.q
    );
    assert!(
        (0.255..=0.285).contains(&last.base_pos.z),
        "base height {}",
        last.base_pos.z
    );
    assert!(euler_pitch(last.base_rot).abs() < 0.03);
    for s in &late {
        assert!(
            (s.base_pos - last.base_pos).length() < 1e-3,
            "drift {:?} vs {:?}",
            s.base_pos,
            last.base_pos
        );
    }
    for (j, q) in last.q.iter().enumerate() {
        let d = (q - model.config.default_joint_pos[j]).abs();
        assert!(d < 0.35, "joint {j} is {d} rad from its default");
    }
    let weight = GO2_MASS * 9.81;
    let carried: f32 = last.foot_force.iter().sum();
    assert!(
        (carried - weight).abs() < 0.03 * weight,
        "feet carry {carried} N of {weight} N"
    );
}

/// Actions at the clip limit, changing sign at random every step: torques never pass the effort
/// limits, and no joint goes more than 0.04 rad past a stop (measured 0.028: a calf whipped into
/// its stop at 30-55 rad/s is caught by the speculative row, then the soft row; the rapier engine
/// overshoots by up to 0.30 rad).
#[test]
fn joint_limits_hold_under_extreme_targets() {
    let n = 8;
    let mut env = batch(articulated(""), n, 3, 1);
    let model = RobotModel::go2();
    let mut state = 11;
    let mut worst: f32 = 0.0;
    for _ in 0..200 {
        let actions: Vec<f32> = random_actions(n, &mut state)
            .iter()
            .map(|a| a.signum() * 100.0)
            .collect();
        let out = env.step(&actions).expect("step").clone();
        for i in 0..n {
            let s = env.robot_state(i);
            for (j, joint) in model.joints.iter().enumerate() {
                let over = (joint.sim_lower - s.q[j]).max(s.q[j] - joint.sim_upper);
                worst = worst.max(over);
                let t = out.torques[i * NUM_JOINTS + j];
                assert!(
                    t.abs() <= joint.effort + 1e-4,
                    "torque {t} on {}",
                    joint.name
                );
            }
        }
    }
    println!("worst overshoot past a stop: {worst} rad");
    assert!(worst < 0.04, "a joint went {worst} rad past its stop");
}

fn trace(threads: usize) -> Vec<u32> {
    let mut cfg = TaskConfig::embedded_default()
        .with_overrides(ENGINE)
        .expect("config");
    cfg.env.envs_per_world = 8;
    let mut env = batch(cfg, 24, 5, threads);
    let mut state = 99;
    let mut out = Vec::new();
    for _ in 0..40 {
        let o = env.step(&random_actions(24, &mut state)).expect("step");
        out.extend_from_slice(&o.obs);
        out.extend_from_slice(&o.reward);
    }
    out.iter().map(|v| v.to_bits()).collect()
}

/// Randomised parameters, random actions: the same bits with one, two or three threads.
#[test]
fn bit_identical_across_thread_counts() {
    let one = trace(1);
    assert_eq!(one, trace(2));
    assert_eq!(one, trace(3));
}

/// A blown-up robot (non-finite, or finite at 500 m/s: decision 0035) is reported, reset and
/// counted; the others are untouched.
#[test]
fn blown_up_env_is_quarantined_and_reset() {
    let cfg = TaskConfig::embedded_default()
        .with_overrides(ENGINE)
        .expect("config");
    assert_eq!(blown_up_runs(cfg).len(), 2);
}

/// Every terrain type, on the triangle mesh and on the heightfield, at a hard level: robots
/// under random actions for 2 s stay finite, stand on the terrain (feet loaded at the start,
/// the base above the terrain) and are never reset for non-finite physics.
#[test]
fn every_terrain_type_runs() {
    for collider in [
        TerrainCollider::Trimesh,
        TerrainCollider::Heightfield { subdivisions: 2 },
    ] {
        for terrain_type in TerrainType::ALL {
            let spec = TerrainSpec {
                kind: TerrainKind::Pinned {
                    terrain_type,
                    level: 6,
                },
                types: vec![terrain_type],
                collider,
                ..TerrainSpec::default()
            };
            let terrain = Terrain::from_spec(&spec, 3).expect("terrain");
            let options = VecEnvOptions {
                num_envs: 4,
                seed: 1,
                threads: 1,
                physics_only: false,
                autoreset: true,
            };
            let mut env = VecEnv::new(
                Arc::new(RobotModel::go2()),
                articulated(""),
                Arc::new(terrain),
                options,
            )
            .expect("batch");
            let zeros = vec![0.0; 4 * NUM_JOINTS];
            for _ in 0..50 {
                env.step(&zeros).expect("step");
            }
            let name = format!("{terrain_type} ({collider:?})");
            for i in 0..4 {
                let s = env.robot_state(i);
                let load: f32 = s.foot_force.iter().sum();
                assert!(load > 50.0, "{name}: env {i} stands on {load} N");
            }
            let mut state = 7;
            for _ in 0..100 {
                let actions: Vec<f32> = random_actions(4, &mut state)
                    .iter()
                    .map(|a| 0.5 * a)
                    .collect();
                env.step(&actions).expect("step");
                for i in 0..4 {
                    // A foot tunnelling into the terrain would drag the base down through it.
                    let p = env.robot_state(i).base_pos;
                    let above = p.z - env.terrain().height(p.x, p.y);
                    assert!(
                        above > 0.05,
                        "{name}: env {i}'s base is {above} m above the terrain"
                    );
                }
            }
            assert_eq!(env.nonfinite_resets(), 0, "{name}");
        }
    }
}

/// The whole curriculum grid up to its hardest level, random actions at full scale for 4 s:
/// feet leave the mesh and land again (parry's mesh caches must stay in step with the contacts
/// the engine keeps), robots fall and are reset, and nothing goes non-finite. In both engines
/// the fastest trunk, spin and joint stay under half of decision 0035's blow-up bounds.
#[test]
fn random_actions_on_the_curriculum_grid() {
    for engine in ["articulated", "rapier"] {
        let spec = TerrainSpec {
            kind: TerrainKind::Curriculum { max_init_level: 9 },
            ..TerrainSpec::default()
        };
        let terrain = Terrain::from_spec(&spec, 5).expect("terrain");
        let options = VecEnvOptions {
            num_envs: 32,
            seed: 2,
            threads: 1,
            physics_only: false,
            autoreset: true,
        };
        let cfg = TaskConfig::embedded_default()
            .with_overrides(&format!("physics.engine = \"{engine}\"\n"))
            .expect("config");
        let mut env = VecEnv::new(Arc::new(RobotModel::go2()), cfg, Arc::new(terrain), options)
            .expect("batch");
        let mut state = 3;
        let mut fastest = [0.0f32; 3];
        for _ in 0..200 {
            env.step(&random_actions(32, &mut state)).expect("step");
            for i in 0..32 {
                let s = env.robot_state(i);
                let joint = s.qd.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                let seen = [s.base_linvel.length(), s.base_angvel.length(), joint];
                for (f, v) in fastest.iter_mut().zip(seen) {
                    *f = f.max(v);
                }
            }
        }
        println!(
            "{engine}: fastest trunk {:.2} m/s, spin {:.1} rad/s, joint {:.1} rad/s",
            fastest[0], fastest[1], fastest[2]
        );
        assert_eq!(env.nonfinite_resets(), 0, "{engine}");
        assert!(
            fastest[0] < MAX_SOUND_BASE_SPEED / 2.0,
            "{engine}: {fastest:?}"
        );
        assert!(
            fastest[1] < MAX_SOUND_BASE_SPIN / 2.0,
            "{engine}: {fastest:?}"
        );
        assert!(
            fastest[2] < MAX_SOUND_JOINT_SPEED / 2.0,
            "{engine}: {fastest:?}"
        );
    }
}
