//! The simulation choices the paper's gaits depend on, as its simulator (Isaac Gym + legged_gym
//! with Unitree's Go2 URDF) makes them: unclamped joint targets, a head that is not the trunk,
//! shin colliders on the calves, and armature on the joint coordinate only.

mod common;

use std::f32::consts::FRAC_PI_2;

use common::*;
use rapier3d::math::{Pose, Rotation, Vec3};
use rapier3d::prelude::{ColliderBuilder, LockedAxes};
use unigait_sim::physics::{PhysicsParams, RobotPhysicalParams, RobotState, RobotWorld};
use unigait_sim::prelude::*;

const FL_HIP: usize = 0;
const FL_THIGH: usize = 1;
const FL_CALF: usize = 2;

fn default_q(model: &RobotModel) -> [f32; NUM_JOINTS] {
    std::array::from_fn(|j| model.config.default_joint_pos[j])
}

/// The base pose that puts the robot's lowest collider (bounding spheres of every collider,
/// feet included) `gap` above the plane z = 0, with orientation `rot` and joints `q`.
fn pose_with_lowest_point(
    model: &RobotModel,
    rot: Rotation,
    q: &[f32; NUM_JOINTS],
    gap: f32,
) -> Pose {
    let local = model.forward_kinematics(q);
    let mut lowest = f32::INFINITY;
    for (b, body) in model.bodies.iter().enumerate() {
        for c in &body.colliders {
            let centre = rot * local[b].transform_point(c.geometry.origin.translation);
            let reach = match c.geometry.shape {
                unigait_sim::robot::Shape::Sphere { radius } => radius,
                unigait_sim::robot::Shape::Cylinder { radius, length } => {
                    // A capsule: the lowest of its two end spheres.
                    let axis = rot * local[b].rotation * c.geometry.origin.rotation * Vec3::Z;
                    radius + 0.5 * length * axis.z.abs()
                }
                unigait_sim::robot::Shape::Box { size } => {
                    let r = rot * local[b].rotation * c.geometry.origin.rotation;
                    let half = size * 0.5;
                    (r * Vec3::X).z.abs() * half.x
                        + (r * Vec3::Y).z.abs() * half.y
                        + (r * Vec3::Z).z.abs() * half.z
                }
            };
            lowest = lowest.min(centre.z - reach);
        }
    }
    Pose::from_parts(Vec3::new(0.0, 0.0, gap - lowest), rot)
}

/// A joint target beyond the joint's range is not clamped to it: the motor pushes with its
/// full, effort-limited torque (35.55 N m at the knee). Clamped at the stop, the knee's
/// extension torque at the default angle (-1.5 rad, stop at -0.838) would be
/// kp x 0.662 = 13.2 N m.
#[test]
fn target_beyond_the_range_gives_the_full_motor_torque() {
    let model = RobotModel::go2();
    let mut env = batch(calm_config(""), 1, 0, 1);
    let mut actions = vec![0.0; NUM_JOINTS];
    actions[FL_CALF] = 100.0; // target -1.5 + 25 rad: far past the upper stop
    actions[FL_THIGH] = -100.0; // far past the lower stop
    let out = env.step(&actions).expect("step");
    let knee = &model.joints[FL_CALF];
    let thigh = &model.joints[FL_THIGH];
    assert_eq!(out.torques[FL_CALF], knee.effort, "knee torque");
    assert_eq!(out.torques[FL_THIGH], -thigh.effort, "thigh torque");
    assert!((knee.effort - 35.55).abs() < 1e-4);
}

/// Static feasibility of the biped stance: the trunk held upright nose-down (pitch pi/2, free
/// to move vertically only), one front foot on the ground carrying the whole robot, the
/// weakest gains of Table V (kp and kd x 0.8). With the policy's targets (the knee pushed to
/// extend) the leg holds the body up; with the targets clamped to the joint range, as before,
/// the knee gives way and the robot sinks onto its head.
#[test]
fn one_front_leg_carries_the_biped_stance_at_the_lowest_gain() {
    let model = RobotModel::go2();
    let run = |clamp_targets: bool| -> (f32, f32, f32) {
        let mut world = RobotWorld::new(
            &model,
            1,
            Terrain::Flat.collider(),
            &PhysicsParams::default(),
        );
        let mut q = default_q(&model);
        // FL leg straight down under the hip (thigh -1.4 rad turns it from the body's -z to
        // the world's -z), knee bent to -1.1; FR folded up and away; rear legs as they are
        // (they point up and back when the nose points down).
        q[FL_THIGH] = -1.4;
        q[FL_CALF] = -1.1;
        q[4] = 1.5;
        let rot = Rotation::from_rotation_y(FRAC_PI_2);
        let base = pose_with_lowest_point(&model, rot, &q, 0.002);
        world.set_robot_state(&model, 0, base, Vec3::ZERO, Vec3::ZERO, &q);
        world.lock_trunk(
            0,
            LockedAxes::ROTATION_LOCKED
                | LockedAxes::TRANSLATION_LOCKED_X
                | LockedAxes::TRANSLATION_LOCKED_Y,
        );
        let mut params = RobotPhysicalParams::nominal(&model);
        params.actuator.kp *= 0.8;
        params.actuator.kd *= 0.8;
        world.set_physical_params(&model, 0, &params);
        // The policy's targets: hold every joint where it is, and push the loaded knee to
        // extend (action +100: target far past the stop).
        let mut targets = q;
        targets[FL_CALF] = model.config.default_joint_pos[FL_CALF] + 0.25 * 100.0;
        if clamp_targets {
            for (t, joint) in targets.iter_mut().zip(&model.joints) {
                *t = t.clamp(joint.sim_lower, joint.sim_upper);
            }
        }
        let mut torques = [0.0; NUM_JOINTS];
        let mut states = [RobotState::default()];
        world.read_states(&model, &mut states);
        let z0 = states[0].base_pos.z;
        let mut head = 0.0f32;
        let mut foot = 0.0f32;
        for step in 0..400 {
            world.step(&model, &targets, &[params.actuator], &mut torques);
            world.read_states(&model, &mut states);
            head = head.max(states[0].head_force);
            if step >= 300 {
                foot = foot.max(states[0].foot_force[0]);
            }
        }
        (states[0].base_pos.z - z0, head, foot)
    };
    let (dz, head, foot) = run(false);
    let weight = GO2_MASS * 9.81;
    assert!(dz > -0.02, "the stance sank {dz} m");
    assert_eq!(head, 0.0, "the head touched ({head} N)");
    assert!(
        foot > 0.9 * weight,
        "the front foot carries {foot} N of {weight} N"
    );
    let (dz_clamped, head_clamped, _) = run(true);
    assert!(
        dz_clamped < -0.05 || head_clamped > 1.0,
        "with clamped targets the knee should give way (sank {dz_clamped} m)"
    );
}

/// The head is not the trunk: a robot pitched nose-down onto its head (pitch pi/2, nothing
/// else near the ground) is reported in head contact, and that neither ends the episode nor
/// costs the collision penalty. Returns the head term's value at each step on the head alone.
fn head_rest_steps(extra: &str) -> Vec<f32> {
    let model = RobotModel::go2();
    let mut env = batch(calm_config(extra), 1, 0, 1);
    let q = default_q(&model);
    let rot = Rotation::from_rotation_y(FRAC_PI_2);
    env.teleport_env(0, pose_with_lowest_point(&model, rot, &q, 0.003), &q);
    let zeros = vec![0.0; NUM_JOINTS];
    let mut head_terms = Vec::new();
    for step in 0..15 {
        let out = env.step(&zeros).expect("step").clone();
        let s = *env.robot_state(0);
        if out.head_contact[0] == 0 {
            continue;
        }
        assert!(s.head_force > 1.0, "step {step}: flag without force");
        if s.trunk_force == 0.0 && s.penalised_contacts == 0 {
            assert_eq!(out.terminated[0], 0, "step {step}: head contact terminated");
            assert_eq!(
                out.reward_terms[RewardTerm::Collision as usize],
                0.0,
                "step {step}: head contact penalised as a collision"
            );
            head_terms.push(out.reward_terms[RewardTerm::BipedBodyContact as usize]);
        }
    }
    assert!(
        head_terms.len() >= 3,
        "only {} steps on the head alone",
        head_terms.len()
    );
    head_terms
}

#[test]
fn head_contact_is_reported_but_neither_terminates_nor_penalises() {
    // The paper's task, in either mode: the head rest is free.
    for biped in ["0.0", "1.0"] {
        let terms = head_rest_steps(&format!("[modes]\nbiped_probability = {biped}"));
        assert!(terms.iter().all(|&t| t == 0.0), "{terms:?}");
    }
}

/// The optional `biped_body_contact` weight prices each biped-mode step on the head (weight
/// times the policy dt) and leaves the quad mode alone.
#[test]
fn a_weighted_body_contact_term_prices_the_biped_head_rest() {
    let priced = "[rewards.weights]\nbiped_body_contact = -1.0\n[modes]\nbiped_probability = ";
    let biped = head_rest_steps(&format!("{priced}1.0"));
    assert!(biped.iter().all(|&t| (t + 0.02).abs() < 1e-6), "{biped:?}");
    let quad = head_rest_steps(&format!("{priced}0.0"));
    assert!(quad.iter().all(|&t| t == 0.0), "{quad:?}");
}

/// A robot resting on its head alone gets the extra solver iterations of a fallen robot, unless
/// `physics.extra_iterations_on_head_contact` turns that off (measured, kept on:
/// docs/src/decisions/0002-joint-fidelity.md).
#[test]
fn head_contact_extra_iterations_follow_their_switch() {
    let model = RobotModel::go2();
    let q = default_q(&model);
    let zeros = vec![0.0; NUM_JOINTS];
    // rapier's extra solver iterations (the articulated engine has none).
    for (overrides, expected) in [
        ("[physics]\nengine = \"rapier\"", true),
        (
            "[physics]\nengine = \"rapier\"\nextra_iterations_on_head_contact = false",
            false,
        ),
    ] {
        let mut env = batch(calm_config(overrides), 1, 0, 1);
        let rot = Rotation::from_rotation_y(FRAC_PI_2);
        env.teleport_env(0, pose_with_lowest_point(&model, rot, &q, 0.003), &q);
        let mut head_only = 0;
        for step in 0..15 {
            env.step(&zeros).expect("step");
            let s = *env.robot_state(0);
            let only_head = s.head_force > 1.0
                && s.trunk_force == 0.0
                && s.penalised_contacts == 0
                && s.other_contacts == 0;
            if only_head {
                head_only += 1;
                assert_eq!(
                    s.extra_iterations, expected,
                    "step {step}, overrides {overrides:?}"
                );
            }
        }
        assert!(head_only >= 3, "only {head_only} steps on the head alone");
    }
}

/// A robot that lands on its legs within a policy step gets the extra solver iterations from
/// the next physics step on, not only at the next read-back: a hip's or thigh's first touch
/// taken without them left the worst joint gaps (5.5-6.7 mm, over the 5 mm bound).
#[test]
fn a_first_leg_touch_gets_extra_iterations_at_the_next_physics_step() {
    let model = RobotModel::go2();
    let q = default_q(&model);
    let params = PhysicsParams::default();
    let mut world = RobotWorld::new(&model, 1, Terrain::Flat.collider(), &params);
    // On its side, the lowest collider 2 cm above the ground: it falls for about 13 steps.
    let base = pose_with_lowest_point(&model, Rotation::from_rotation_x(FRAC_PI_2), &q, 0.02);
    world.set_robot_state(&model, 0, base, Vec3::ZERO, Vec3::ZERO, &q);
    let actuators = [RobotPhysicalParams::nominal(&model).actuator];
    let mut torques = [0.0; NUM_JOINTS];
    let mut first_extra = None;
    for step in 0..40 {
        world.step(&model, &q, &actuators, &mut torques);
        if world.has_extra_iterations(0) {
            first_extra = Some(step);
            break;
        }
    }
    let step = first_extra.expect("no extra iterations within 40 physics steps");
    assert!(
        step >= 5,
        "extra iterations before the fall could touch: step {step}"
    );
    let mut states = [RobotState::default()];
    world.read_states(&model, &mut states);
    let s = states[0];
    assert!(
        s.penalised_contacts + s.other_contacts > 0,
        "extra iterations without a leg on the ground: {s:?}"
    );
    assert!(s.extra_iterations);
}

/// The trunk still terminates: a robot tipped back (pitch -0.3) with its legs folded up,
/// dropped onto its rear trunk edge, ends its episode.
#[test]
fn trunk_contact_still_terminates() {
    let model = RobotModel::go2();
    let mut env = batch(calm_config(""), 1, 0, 1);
    let mut q = default_q(&model);
    for leg in 0..2 {
        q[3 * leg + 1] = -1.5; // front thighs forward
        q[3 * leg + 2] = -2.7; // front knees folded
    }
    for leg in 2..4 {
        q[3 * leg + 1] = 2.5; // rear thighs back and up
        q[3 * leg + 2] = -0.85;
    }
    let rot = Rotation::from_rotation_y(-0.3);
    let base = pose_with_lowest_point(&model, rot, &q, 0.002);
    env.teleport_env(0, base, &q);
    let targets: Vec<f32> = (0..NUM_JOINTS)
        .map(|j| (q[j] - model.config.default_joint_pos[j]) / 0.25)
        .collect();
    let mut terminated_at = None;
    for step in 0..10 {
        let out = env.step(&targets).expect("step");
        if out.terminated[0] != 0 {
            terminated_at = Some(step);
            break;
        }
    }
    assert!(
        terminated_at.is_some(),
        "the trunk landed without ending the episode"
    );
}

/// The calves carry Unitree's shin colliders (calflower, calflower1): a step edge pressed
/// against the lower shin, clear of the foot sphere and the calf's own capsule, makes a
/// contact, and it counts as a penalised (calf) contact.
#[test]
fn a_shin_against_a_step_edge_collides_and_is_penalised() {
    let model = RobotModel::go2();
    let q = default_q(&model);
    let local = model.forward_kinematics(&q);
    let calf = model.joints[FL_CALF].child_body;
    let shin = model.bodies[calf]
        .colliders
        .iter()
        .find(|c| c.geometry.name == "FL_calflower1")
        .expect("the FL calf has a calflower1 collider");
    assert_eq!(shin.role, unigait_sim::robot::ColliderRole::Penalised);
    // Robot upright in the air, no gravity, drifting forward at 0.2 m/s onto the edge of a
    // block 1 mm ahead of the shin capsule's front, level with the shin (above the foot
    // sphere's top, below the calf's own capsule).
    let base = Pose::from_parts(Vec3::new(0.0, 0.0, 1.0), Rotation::IDENTITY);
    let centre = base * local[calf] * shin.geometry.origin;
    let front = centre.translation + Vec3::X * 0.0155;
    let foot = base * local[calf].transform_point(model.feet[0].offset);
    assert!(
        centre.translation.z - foot.z > 0.02,
        "shin too close to the foot"
    );
    let block = ColliderBuilder::cuboid(0.02, 0.02, 0.01)
        .translation(front + Vec3::new(0.02 + 0.001, 0.0, 0.005));
    let params = PhysicsParams {
        gravity: 0.0,
        ..Default::default()
    };
    let mut world = RobotWorld::new(&model, 1, block, &params);
    world.set_robot_state(&model, 0, base, Vec3::new(0.2, 0.0, 0.0), Vec3::ZERO, &q);
    let actuators = [RobotPhysicalParams::nominal(&model).actuator];
    let mut torques = [0.0; NUM_JOINTS];
    let mut states = [RobotState::default()];
    let mut shin_hits = 0;
    for _ in 0..20 {
        world.step(&model, &q, &actuators, &mut torques);
        world.read_states(&model, &mut states);
        assert_eq!(states[0].foot_force[0], 0.0, "the foot touched the block");
        assert_eq!(states[0].trunk_force, 0.0, "the trunk touched the block");
        shin_hits += usize::from(states[0].penalised_contacts == 1);
    }
    assert!(shin_hits > 0, "the shin went through the block edge");
}

/// Armature on a joint whose parent holds still acts as reflected inertia: with the trunk held
/// and no gravity, a saturated hip torque accelerates the leg by tau / (I_leg + armature), I_leg
/// the leg's bare inertia about the hip axis. Measured as the mean acceleration over the second
/// to fourth physics steps (in the first the impulse joints let the outer leg lag a little, and
/// at speed the PD-held thigh and calf swing out); within 5% of the closed form.
#[test]
fn armature_slows_a_joint_by_its_reflected_inertia() {
    let model = RobotModel::go2();
    let hip = &model.joints[FL_HIP];
    let measure = |armature: f32| -> (f32, f32) {
        let params = PhysicsParams {
            gravity: 0.0,
            ..Default::default()
        };
        let mut world = RobotWorld::new(&model, 1, Terrain::Flat.collider(), &params);
        let q = default_q(&model);
        world.set_robot_state(
            &model,
            0,
            Pose::from_parts(Vec3::new(0.0, 0.0, 1.0), Rotation::IDENTITY),
            Vec3::ZERO,
            Vec3::ZERO,
            &q,
        );
        world.lock_trunk(0, LockedAxes::all());
        let mut p = RobotPhysicalParams::nominal(&model);
        p.armature = armature;
        p.actuator.kd = 0.0;
        p.actuator.damping = 0.0;
        p.actuator.friction = 0.0;
        world.set_physical_params(&model, 0, &p);
        let leg: Vec<usize> = (0..3).map(|j| model.joints[j].child_body).collect();
        let pivot = Vec3::new(0.0, 0.0, 1.0) + hip.origin.translation;
        // The leg (hip, thigh, calf) about the hip axis, armature included.
        let inertia = world.inertia_about(0, &leg, pivot, Vec3::X);
        let mut targets = q;
        targets[FL_HIP] += 100.0; // saturated: +23.7 N m
        let mut torques = [0.0; NUM_JOINTS];
        let mut states = [RobotState::default()];
        let mut qd = [0.0f32; 4];
        for v in &mut qd {
            world.step(&model, &targets, &[p.actuator], &mut torques);
            world.read_states(&model, &mut states);
            *v = states[0].qd[FL_HIP];
        }
        ((qd[3] - qd[1]) / (2.0 * params.dt), inertia)
    };
    let (bare, leg) = measure(0.0);
    assert!((0.01..0.08).contains(&leg), "leg inertia {leg}");
    for armature in [0.0, 0.015, 0.02, 0.025] {
        let (alpha, inertia) = measure(armature);
        assert!(
            (inertia - (leg + armature)).abs() < 2e-3,
            "the hip's armature should add {armature} about its axis: {leg} -> {inertia}"
        );
        let expected = hip.effort / (leg + armature);
        assert!(
            (alpha / expected - 1.0).abs() < 0.05,
            "armature {armature}: {alpha} rad/s^2, closed form {expected}"
        );
    }
    assert!(measure(0.02).0 < 0.65 * bare);
}

/// What armature on the links costs the whole body: its rigid inertia grows by the armature of
/// every joint whose axis lies along the turn (8 pitch joints: thighs and calves; 4 roll
/// joints: hips), about +33% in pitch and +43% in roll at 0.02, where Isaac Gym's joint-space
/// armature adds nothing. Documented, not hidden: rapier's impulse joints have no joint space.
#[test]
fn armature_on_the_links_adds_to_the_whole_body_inertia() {
    let model = RobotModel::go2();
    let inertia = |armature: f32| -> (f32, f32) {
        let mut world = RobotWorld::new(
            &model,
            1,
            Terrain::Flat.collider(),
            &PhysicsParams::default(),
        );
        let mut p = RobotPhysicalParams::nominal(&model);
        p.armature = armature;
        world.set_physical_params(&model, 0, &p);
        (
            world.whole_body_inertia(0, Vec3::Y),
            world.whole_body_inertia(0, Vec3::X),
        )
    };
    let (pitch0, roll0) = inertia(0.0);
    let (pitch, roll) = inertia(0.02);
    // The Go2 at its default pose, no armature: about 0.49 kg m^2 in pitch, 0.19 in roll.
    assert!((0.4..0.6).contains(&pitch0), "pitch inertia {pitch0}");
    assert!((0.15..0.25).contains(&roll0), "roll inertia {roll0}");
    assert!(
        ((pitch - pitch0) - 8.0 * 0.02).abs() < 4e-3,
        "pitch {pitch0} -> {pitch}"
    );
    assert!(
        ((roll - roll0) - 4.0 * 0.02).abs() < 4e-3,
        "roll {roll0} -> {roll}"
    );
}
