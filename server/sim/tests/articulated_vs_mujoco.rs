//! The articulated dynamics against MuJoCo (issue 34's first check): the mass matrix and the bias
//! forces of our Go2 on recorded states equal MuJoCo's `mj_fullM` and `qfrc_bias` to 1e-4
//! relative in f64.
//!
//! The fixture `tests/data/articulated_fixture.json` is written by
//! `tests/data/make_articulated_fixture.py` (MuJoCo 4.0.0): `assets/go2/go2.urdf` with its own
//! link inertias (no `physics.min_link_inertia` floor) and armature 0.02 kg m^2 on each joint, on
//! ten states (default pose, random joints within limits, random orientations including the
//! pitched-nose-down biped start at pi/2, random velocities, one far from the origin). Both sides
//! use MuJoCo's free-joint coordinates, so no conversion is needed.
//!
//! Error measure: for each state, the largest entry error over the largest entry of MuJoCo's
//! matrix (or vector); asserted below 1e-4, and printed (`--nocapture`) with the per-entry
//! relative error of the entries above 1e-6 of that scale. The same figures for the tree cast
//! to f32 are printed too (not asserted: they tell what an f32 step can expect).

use serde_json::Value;
use unigait_sim::physics::articulated::{ArticulatedTree, Real, Workspace};
use unigait_sim::robot::RobotModel;

const FIXTURE: &str = include_str!("data/articulated_fixture.json");

/// Reading the fixture's fields (a malformed fixture is a test failure, said by name).
trait Field {
    fn num(&self) -> f64;
    fn str(&self) -> &str;
    fn arr(&self) -> &[Value];
    fn nums(&self) -> Vec<f64>;
}

impl Field for Value {
    fn num(&self) -> f64 {
        self.as_f64()
            .unwrap_or_else(|| panic!("not a number: {self}"))
    }

    fn str(&self) -> &str {
        self.as_str()
            .unwrap_or_else(|| panic!("not a string: {self}"))
    }

    fn arr(&self) -> &[Value] {
        self.as_array()
            .unwrap_or_else(|| panic!("not an array: {self}"))
    }

    fn nums(&self) -> Vec<f64> {
        self.arr().iter().map(Field::num).collect()
    }
}

fn errors(got: &[f64], want: &[f64]) -> (f64, f64) {
    let scale = want.iter().fold(0.0f64, |m, w| m.max(w.abs()));
    let mut worst = 0.0f64;
    let mut worst_entry = 0.0f64;
    for (g, w) in got.iter().zip(want) {
        worst = worst.max((g - w).abs());
        if w.abs() > 1e-6 * scale {
            worst_entry = worst_entry.max((g - w).abs() / w.abs());
        }
    }
    (worst / scale, worst_entry)
}

/// Mass matrix (dense) and bias forces of `tree` at one state, in f64.
fn dynamics<T: Real>(
    tree: &ArticulatedTree<T>,
    qpos: &[f64],
    qvel: &[f64],
    g: f64,
) -> (Vec<f64>, Vec<f64>) {
    let mut ws = Workspace::new(tree);
    let qpos: Vec<T> = qpos.iter().map(|&x| T::from_f64(x)).collect();
    let qvel: Vec<T> = qvel.iter().map(|&x| T::from_f64(x)).collect();
    tree.forward_kinematics(&mut ws, &qpos, &qvel);
    tree.mass_matrix(&mut ws);
    tree.bias_forces(&mut ws, &[T::ZERO, T::ZERO, T::from_f64(-g)]);
    let nv = tree.nv();
    let mut dense = vec![T::ZERO; nv * nv];
    ws.mass_matrix_dense(tree, &mut dense);
    (
        dense.iter().map(|x| x.to_f64()).collect(),
        ws.bias().iter().map(|x| x.to_f64()).collect(),
    )
}

#[test]
fn articulated_mass_matrix_and_bias_match_mujoco() {
    let fixture: Value = serde_json::from_str(FIXTURE).expect("the fixture is JSON");
    let armature = fixture["armature"].num();
    let gravity = fixture["gravity"].num();
    let tree = ArticulatedTree::from_robot(&RobotModel::go2(), armature).expect("Go2 tree");
    let names: Vec<&str> = fixture["joint_names"]
        .arr()
        .iter()
        .map(Field::str)
        .collect();
    assert_eq!(
        tree.joint_names(),
        names.as_slice(),
        "same DoF order as MuJoCo"
    );
    assert_eq!(fixture["nv"].num() as usize, tree.nv());
    let tree32 = tree.cast::<f32>();
    let states = fixture["states"].arr();
    assert!(states.len() >= 10, "{} states", states.len());
    let mut worst = [0.0f64; 4];
    let mut worst32 = [0.0f64; 4];
    println!(
        "state                  M rel      M entry    bias rel   bias entry | f32: M rel  bias rel"
    );
    for state in states {
        let name = state["name"].str();
        let qpos = state["qpos"].nums();
        let qvel = state["qvel"].nums();
        let m_ref = state["mass_matrix"].nums();
        let b_ref = state["bias"].nums();
        let (m, b) = dynamics(&tree, &qpos, &qvel, gravity);
        let (m_rel, m_entry) = errors(&m, &m_ref);
        let (b_rel, b_entry) = errors(&b, &b_ref);
        let (m32, b32) = dynamics(&tree32, &qpos, &qvel, gravity);
        let (m32_rel, m32_entry) = errors(&m32, &m_ref);
        let (b32_rel, b32_entry) = errors(&b32, &b_ref);
        println!(
            "{name:22} {m_rel:9.2e} {m_entry:9.2e}  {b_rel:9.2e} {b_entry:9.2e}  |      {m32_rel:9.2e} {b32_rel:9.2e}"
        );
        for (w, e) in worst.iter_mut().zip([m_rel, m_entry, b_rel, b_entry]) {
            *w = w.max(e);
        }
        for (w, e) in worst32
            .iter_mut()
            .zip([m32_rel, m32_entry, b32_rel, b32_entry])
        {
            *w = w.max(e);
        }
        assert!(
            m_rel < 1e-4,
            "{name}: mass matrix off by {m_rel:e} relative"
        );
        assert!(
            b_rel < 1e-4,
            "{name}: bias forces off by {b_rel:e} relative"
        );
    }
    println!(
        "worst f64: M {:.2e} (entry {:.2e}), bias {:.2e} (entry {:.2e})",
        worst[0], worst[1], worst[2], worst[3]
    );
    println!(
        "worst f32: M {:.2e} (entry {:.2e}), bias {:.2e} (entry {:.2e})",
        worst32[0], worst32[1], worst32[2], worst32[3]
    );
}

/// The check can fail: a robot without armature, or the base's angular velocity read in world
/// axes instead of its own, is far from MuJoCo's figures.
#[test]
fn articulated_check_sees_a_different_robot_or_convention() {
    let fixture: Value = serde_json::from_str(FIXTURE).expect("the fixture is JSON");
    let state = &fixture["states"].arr()[2];
    let (qpos, qvel) = (state["qpos"].nums(), state["qvel"].nums());
    let m_ref = state["mass_matrix"].nums();
    let b_ref = state["bias"].nums();
    let gravity = fixture["gravity"].num();
    let bare = ArticulatedTree::from_robot(&RobotModel::go2(), 0.0).expect("Go2 tree");
    let (m, _) = dynamics(&bare, &qpos, &qvel, gravity);
    let (m_rel, _) = errors(&m, &m_ref);
    assert!(m_rel > 1e-3, "armature 0 should show: {m_rel:e}");

    let tree = ArticulatedTree::from_robot(&RobotModel::go2(), 0.02).expect("Go2 tree");
    // Angular velocity rotated into world axes (R w), then passed where the body's is expected.
    let (w, x, y, z) = (qpos[3], qpos[4], qpos[5], qpos[6]);
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let mut world = qvel.clone();
    for (i, row) in r.iter().enumerate() {
        world[3 + i] = row[0] * qvel[3] + row[1] * qvel[4] + row[2] * qvel[5];
    }
    let (_, b) = dynamics(&tree, &qpos, &world, gravity);
    let (b_rel, _) = errors(&b, &b_ref);
    assert!(
        b_rel > 1e-3,
        "a world-frame angular velocity should show: {b_rel:e}"
    );
}
