//! Unit tests with hand-computed values: a pendulum, a two-link chain, the Go2's structure, and
//! the algorithms against each other (factor and solve vs a dense solve, inverse dynamics vs the
//! mass matrix, free fall, kinematics vs finite differences).

use super::spatial::{Vec3, axis_angle, identity, mat_mul};
use super::*;
use crate::robot::{NUM_JOINTS, RobotModel};

const G: f64 = 9.81;
const GRAVITY: Vec3<f64> = [0.0, 0.0, -G];

fn link(name: &str, parent: usize, joint: RevoluteSpec, mass: f64, com: [f64; 3]) -> BodySpec {
    BodySpec {
        name: name.into(),
        parent: Some(parent),
        joint: Some(joint),
        mass,
        com,
        inertia: [0.003, 0.005, 0.002, 0.0, 0.0, 0.0],
    }
}

fn revolute(name: &str, translation: [f64; 3], rotation: [f64; 9], axis: [f64; 3]) -> RevoluteSpec {
    RevoluteSpec {
        name: name.into(),
        translation,
        rotation,
        axis,
        armature: 0.0,
    }
}

fn anchor() -> BodySpec {
    BodySpec {
        name: "anchor".into(),
        parent: None,
        joint: None,
        mass: 0.0,
        com: [0.0; 3],
        inertia: [0.0; 6],
    }
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + b.abs())
}

/// One link of mass m on a y axis, centre of mass l below the pivot at q = 0:
/// M = I_yy + m l^2 + armature, bias = m g l sin q whatever the rate.
#[test]
fn pendulum_mass_and_gravity_torque() {
    let (m, l, armature, iyy) = (1.3, 0.4, 0.02, 0.005);
    // The same pendulum twice: axis y directly, and axis x in a joint frame turned 90 deg about z
    // (whose x is the world's y), which goes through the fixed rotation.
    let turned = axis_angle(&[0.0, 0.0, 1.0], std::f64::consts::FRAC_PI_2);
    for (rotation, axis) in [(identity(), [0.0, 1.0, 0.0]), (turned, [1.0, 0.0, 0.0])] {
        let mut joint = revolute("pivot", [0.0; 3], rotation, axis);
        joint.armature = armature;
        let mut bob = link("bob", 0, joint, m, [0.0, 0.0, -l]);
        // Inertia about the joint axis in the body frame: y for the first, x for the turned one.
        bob.inertia = if axis[1] == 1.0 {
            [0.003, iyy, 0.002, 0.0, 0.0, 0.0]
        } else {
            [iyy, 0.003, 0.002, 0.0, 0.0, 0.0]
        };
        let tree = ArticulatedTree::new(BaseJoint::Fixed, &[anchor(), bob]).expect("tree");
        assert_eq!((tree.nq(), tree.nv()), (1, 1));
        let mut ws = Workspace::new(&tree);
        for (q, qd) in [(0.0, 0.0), (0.3, 0.0), (-1.2, 2.5), (2.0, -4.0)] {
            tree.forward_kinematics(&mut ws, &[q], &[qd]);
            tree.mass_matrix(&mut ws);
            tree.bias_forces(&mut ws, &GRAVITY);
            let expected_m = iyy + m * l * l + armature;
            assert!(
                close(ws.mass_matrix()[0], expected_m, 1e-12),
                "M at q = {q}"
            );
            let expected_bias = m * G * l * q.sin();
            assert!(
                close(ws.bias()[0], expected_bias, 1e-12),
                "bias at q = {q}: {}",
                ws.bias()[0]
            );
        }
    }
}

/// A planar double pendulum about y (links hanging down at q = 0), the textbook formulas:
/// M11 = I1 + m1 c1^2 + I2 + m2 (l1^2 + c2^2 + 2 l1 c2 cos q2), M12 = I2 + m2 (c2^2 + l1 c2 cos q2),
/// M22 = I2 + m2 c2^2; with h = m2 l1 c2 sin q2, bias = (-h (2 qd1 qd2 + qd2^2) + (m1 c1 + m2 l1) g
/// sin q1 + m2 c2 g sin(q1 + q2), h qd1^2 + m2 c2 g sin(q1 + q2)).
#[test]
fn two_link_chain_matches_the_textbook() {
    let (m1, m2, l1, c1, c2) = (2.0, 0.7, 0.5, 0.2, 0.3);
    let (i1, i2) = (0.004, 0.009);
    let mut upper = link(
        "upper",
        0,
        revolute("shoulder", [0.0; 3], identity(), [0.0, 1.0, 0.0]),
        m1,
        [0.0, 0.0, -c1],
    );
    upper.inertia[1] = i1;
    let mut lower = link(
        "lower",
        1,
        revolute("elbow", [0.0, 0.0, -l1], identity(), [0.0, 1.0, 0.0]),
        m2,
        [0.0, 0.0, -c2],
    );
    lower.inertia[1] = i2;
    let tree = ArticulatedTree::new(BaseJoint::Fixed, &[anchor(), upper, lower]).expect("tree");
    let mut ws = Workspace::new(&tree);
    let mut dense = [0.0; 4];
    for (q, qd) in [
        ([0.0, 0.0], [0.0, 0.0]),
        ([0.4, -0.9], [1.5, -2.0]),
        ([-2.1, 1.3], [-3.0, 0.7]),
    ] {
        tree.forward_kinematics(&mut ws, &q, &qd);
        tree.mass_matrix(&mut ws);
        tree.bias_forces(&mut ws, &GRAVITY);
        ws.mass_matrix_dense(&tree, &mut dense);
        let (s2, cos2) = q[1].sin_cos();
        let m11 = i1 + m1 * c1 * c1 + i2 + m2 * (l1 * l1 + c2 * c2 + 2.0 * l1 * c2 * cos2);
        let m12 = i2 + m2 * (c2 * c2 + l1 * c2 * cos2);
        let m22 = i2 + m2 * c2 * c2;
        for (got, want) in dense.iter().zip([m11, m12, m12, m22]) {
            assert!(close(*got, want, 1e-12), "M {dense:?} at q = {q:?}");
        }
        let h = m2 * l1 * c2 * s2;
        let g12 = m2 * c2 * G * (q[0] + q[1]).sin();
        let b1 =
            -h * (2.0 * qd[0] * qd[1] + qd[1] * qd[1]) + (m1 * c1 + m2 * l1) * G * q[0].sin() + g12;
        let b2 = h * qd[0] * qd[0] + g12;
        assert!(
            close(ws.bias()[0], b1, 1e-12),
            "bias 0 {} vs {b1}",
            ws.bias()[0]
        );
        assert!(
            close(ws.bias()[1], b2, 1e-12),
            "bias 1 {} vs {b2}",
            ws.bias()[1]
        );
    }
}

fn go2() -> ArticulatedTree {
    ArticulatedTree::from_robot(&RobotModel::go2(), 0.02).expect("the Go2 tree")
}

/// A reproducible state: base anywhere, any orientation, joints and rates within a few rad.
fn state(seed: u64) -> (Vec<f64>, Vec<f64>) {
    // A small linear congruential generator: the tests need spread, not statistics.
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let mut qpos = vec![next(), next(), 0.4 + 0.1 * next()];
    let quat = [next(), next(), next(), next()];
    let norm = quat.iter().map(|x| x * x).sum::<f64>().sqrt();
    qpos.extend(quat.iter().map(|x| x / norm));
    qpos.extend((0..NUM_JOINTS).map(|_| 1.5 * next()));
    let qvel = (0..18)
        .map(|i| if i < 6 { next() } else { 5.0 * next() })
        .collect();
    (qpos, qvel)
}

#[test]
fn go2_tree_follows_the_model() {
    let model = RobotModel::go2();
    let tree = go2();
    assert_eq!((tree.nq(), tree.nv(), tree.num_bodies()), (19, 18, 13));
    let names: Vec<&str> = model.joints.iter().map(|j| j.name.as_str()).collect();
    assert_eq!(
        tree.joint_names(),
        names.as_slice(),
        "DoF 6 + j is action joint j"
    );
    // Base chain 1 + ... + 6, then per leg hip 7, thigh 8, calf 9 entries.
    assert_eq!(tree.nnz(), 21 + 4 * (7 + 8 + 9));
    assert!(
        (tree.total_mass() - 15.019).abs() < 1e-9,
        "{}",
        tree.total_mass()
    );
    assert_eq!(tree.dof_parent(6), 5, "FL hip on the base's last DoF");
    assert_eq!(tree.dof_parent(8), 7, "FL calf on the FL thigh");
    assert_eq!(tree.armature(5), 0.0);
    assert_eq!(tree.armature(6), 0.02);
}

/// Our body poses at the default pose equal the robot model's own forward kinematics.
#[test]
fn go2_kinematics_matches_the_model() {
    let model = RobotModel::go2();
    let tree = go2();
    let mut ws = Workspace::new(&tree);
    let q = model.config.default_joint_pos.clone();
    let mut qpos = vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    qpos.extend(q.iter().map(|&x| f64::from(x)));
    tree.forward_kinematics(&mut ws, &qpos, &[0.0; 18]);
    let q: [f32; NUM_JOINTS] = q.try_into().expect("12 angles");
    let poses = model.forward_kinematics(&q);
    // Tree order is depth first, the model's breadth first: match bodies by name.
    for (b, name) in tree.body_names().iter().enumerate() {
        let m = model
            .bodies
            .iter()
            .position(|body| &body.name == name)
            .expect("body");
        let p = ws.body_position(b);
        let t = poses[m].translation;
        for (a, e) in p.iter().zip([t.x, t.y, t.z]) {
            assert!((a - f64::from(e)).abs() < 1e-6, "{name}: {p:?} vs {t:?}");
        }
    }
}

/// Body velocities equal finite differences of body positions along qvel (MuJoCo's free joint:
/// linear velocity in the world, angular in the base frame).
#[test]
fn velocities_are_the_derivative_of_positions() {
    let tree = go2();
    let (mut ws, mut ws2) = (Workspace::new(&tree), Workspace::new(&tree));
    let (qpos, qvel) = state(3);
    tree.forward_kinematics(&mut ws, &qpos, &qvel);
    let h = 1e-6;
    let mut next = qpos.clone();
    for i in 0..3 {
        next[i] += h * qvel[i];
    }
    // q <- q * exp(h w_body / 2): the body-frame angular velocity multiplies on the right.
    let (w, x, y, z) = (qpos[3], qpos[4], qpos[5], qpos[6]);
    let d = [h * qvel[3] / 2.0, h * qvel[4] / 2.0, h * qvel[5] / 2.0];
    next[3] = w - x * d[0] - y * d[1] - z * d[2];
    next[4] = x + w * d[0] + y * d[2] - z * d[1];
    next[5] = y + w * d[1] + z * d[0] - x * d[2];
    next[6] = z + w * d[2] + x * d[1] - y * d[0];
    for j in 0..NUM_JOINTS {
        next[7 + j] += h * qvel[6 + j];
    }
    tree.forward_kinematics(&mut ws2, &next, &qvel);
    for b in 0..tree.num_bodies() {
        let (_, v) = ws.body_velocity(b);
        let (p0, p1) = (ws.body_position(b), ws2.body_position(b));
        for i in 0..3 {
            let fd = (p1[i] - p0[i]) / h;
            assert!(
                (fd - v[i]).abs() < 1e-4,
                "body {b} axis {i}: {fd} vs {}",
                v[i]
            );
        }
        // Angular velocity: R' R^T ~ I + h [w]x.
        let (r0, r1) = (ws.body_rotation(b), ws2.body_rotation(b));
        let r0t = [
            r0[0], r0[3], r0[6], r0[1], r0[4], r0[7], r0[2], r0[5], r0[8],
        ];
        let dr = mat_mul(&r1, &r0t);
        let fd = [
            (dr[7] - dr[5]) / (2.0 * h),
            (dr[2] - dr[6]) / (2.0 * h),
            (dr[3] - dr[1]) / (2.0 * h),
        ];
        let (w, _) = ws.body_velocity(b);
        for i in 0..3 {
            assert!(
                (fd[i] - w[i]).abs() < 1e-4,
                "body {b} spin {i}: {fd:?} vs {w:?}"
            );
        }
    }
}

/// Dense Gaussian elimination with partial pivoting, for reference.
fn dense_solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Vec<f64> {
    let n = b.len();
    for c in 0..n {
        let p = (c..n)
            .max_by(|&i, &j| a[i * n + c].abs().total_cmp(&a[j * n + c].abs()))
            .expect("rows");
        for k in 0..n {
            a.swap(c * n + k, p * n + k);
        }
        b.swap(c, p);
        for r in c + 1..n {
            let f = a[r * n + c] / a[c * n + c];
            for k in c..n {
                a[r * n + k] -= f * a[c * n + k];
            }
            b[r] -= f * b[c];
        }
    }
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|k| a[r * n + k] * b[k]).sum();
        b[r] = (b[r] - s) / a[r * n + r];
    }
    b
}

#[test]
fn factor_and_solve_equal_a_dense_solve() {
    let tree = go2();
    let mut ws = Workspace::new(&tree);
    let mut dense = vec![0.0; 18 * 18];
    let mut pivots = [0.0; 18];
    for seed in 0..5 {
        let (qpos, qvel) = state(seed);
        tree.forward_kinematics(&mut ws, &qpos, &qvel);
        tree.mass_matrix(&mut ws);
        tree.factor(&mut ws);
        tree.pivots(&ws, &mut pivots);
        assert!(
            pivots.iter().all(|&d| d > 0.0),
            "positive definite: {pivots:?}"
        );
        ws.mass_matrix_dense(&tree, &mut dense);
        let b: Vec<f64> = (0..18).map(|i| (i as f64 * 0.7).sin() * 10.0).collect();
        let mut x = b.clone();
        tree.solve(&ws, &mut x);
        let reference = dense_solve(dense.clone(), b.clone());
        let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (got, want) in x.iter().zip(&reference) {
            assert!((got - want).abs() <= 1e-10 * scale, "{got} vs {want}");
        }
        // And M x gives b back through the sparse product.
        let mut back = vec![0.0; 18];
        tree.mul_mass_matrix(&ws, &x, &mut back);
        for (got, want) in back.iter().zip(&b) {
            assert!((got - want).abs() < 1e-10, "{got} vs {want}");
        }
    }
}

/// Newton-Euler with accelerations minus the bias forces is the mass matrix times them, column by
/// column: the two algorithms agree on M.
#[test]
fn inverse_dynamics_agrees_with_the_mass_matrix() {
    let tree = go2();
    let mut ws = Workspace::new(&tree);
    let mut dense = vec![0.0; 18 * 18];
    let mut tau = vec![0.0; 18];
    let (qpos, qvel) = state(11);
    tree.forward_kinematics(&mut ws, &qpos, &qvel);
    tree.mass_matrix(&mut ws);
    tree.bias_forces(&mut ws, &GRAVITY);
    ws.mass_matrix_dense(&tree, &mut dense);
    let bias = ws.bias().to_vec();
    for j in 0..18 {
        let mut qacc = vec![0.0; 18];
        qacc[j] = 1.0;
        tree.inverse_dynamics(&mut ws, &qacc, &GRAVITY, &mut tau);
        for i in 0..18 {
            let got = tau[i] - bias[i];
            assert!(
                (got - dense[i * 18 + j]).abs() < 1e-12,
                "M[{i}][{j}]: {got} vs {}",
                dense[i * 18 + j]
            );
        }
    }
}

/// At rest, a free robot falls: M^-1 (-bias) accelerates the base at g, nothing else.
#[test]
fn free_fall_accelerates_the_base_at_g_only() {
    let tree = go2();
    let mut ws = Workspace::new(&tree);
    for seed in 20..23 {
        let (qpos, _) = state(seed);
        tree.forward_kinematics(&mut ws, &qpos, &[0.0; 18]);
        tree.mass_matrix(&mut ws);
        tree.bias_forces(&mut ws, &GRAVITY);
        tree.factor(&mut ws);
        let mut qacc: Vec<f64> = ws.bias().iter().map(|b| -b).collect();
        tree.solve(&ws, &mut qacc);
        for (i, a) in qacc.iter().enumerate() {
            let want = if i == 2 { -G } else { 0.0 };
            assert!((a - want).abs() < 1e-10, "qacc[{i}] = {a}");
        }
    }
}

/// Where the robot stands changes nothing: the dynamics are computed about the base origin.
#[test]
fn dynamics_do_not_depend_on_the_base_position() {
    let tree = go2();
    let (mut a, mut b) = (Workspace::new(&tree), Workspace::new(&tree));
    let (qpos, qvel) = state(5);
    let mut far = qpos.clone();
    far[0] += 1000.0;
    far[1] -= 250.0;
    for (ws, q) in [(&mut a, &qpos), (&mut b, &far)] {
        tree.forward_kinematics(ws, q, &qvel);
        tree.mass_matrix(ws);
        tree.bias_forces(ws, &GRAVITY);
    }
    assert_eq!(a.mass_matrix(), b.mass_matrix());
    assert_eq!(a.bias(), b.bias());
}

#[test]
fn a_malformed_tree_is_refused() {
    let orphan = BodySpec {
        parent: Some(1),
        ..link(
            "orphan",
            1,
            revolute("j", [0.0; 3], identity(), [0.0, 1.0, 0.0]),
            1.0,
            [0.0; 3],
        )
    };
    assert!(ArticulatedTree::new(BaseJoint::Free, &[anchor(), orphan]).is_err());
    let still = link(
        "still",
        0,
        revolute("j", [0.0; 3], identity(), [0.0; 3]),
        1.0,
        [0.0; 3],
    );
    assert!(ArticulatedTree::new(BaseJoint::Free, &[anchor(), still]).is_err());
    assert!(ArticulatedTree::new(BaseJoint::Free, &[]).is_err());
}

/// One free body, centre of mass c off its origin: the bias forces are Newton's and Euler's
/// equations written at the origin, whatever the origin's velocity (MuJoCo's coordinates):
/// translation `m (g_up + w x (w x R c))` in world axes, rotation
/// `w_b x (I_O w_b) + m c x (R^T g_up)` in body axes, `I_O` the inertia about the origin.
#[test]
fn free_body_bias_is_newton_and_euler() {
    let (m, c) = (2.5, [0.1, -0.05, 0.2]);
    let ic = [0.02, 0.03, 0.04];
    let body = BodySpec {
        mass: m,
        com: c,
        inertia: [ic[0], ic[1], ic[2], 0.0, 0.0, 0.0],
        ..anchor()
    };
    let tree = ArticulatedTree::new(BaseJoint::Free, &[body]).expect("tree");
    assert_eq!((tree.nq(), tree.nv()), (7, 6));
    let mut ws = Workspace::new(&tree);
    let half = 0.35f64;
    let axis = [0.6, 0.0, 0.8];
    let qpos = [
        1.0,
        2.0,
        3.0,
        half.cos(),
        axis[0] * half.sin(),
        0.0,
        axis[2] * half.sin(),
    ];
    let r = axis_angle(&axis, 2.0 * half);
    let w_body = [0.7, -1.1, 0.4];
    let qvel = [3.0, -2.0, 0.5, w_body[0], w_body[1], w_body[2]];
    tree.forward_kinematics(&mut ws, &qpos, &qvel);
    tree.bias_forces(&mut ws, &GRAVITY);
    let cross = super::spatial::cross::<f64>;
    let rc = super::spatial::mat_vec(&r, &c);
    let w = super::spatial::mat_vec(&r, &w_body);
    let centripetal = cross(&w, &cross(&w, &rc));
    let trans = [
        m * centripetal[0],
        m * centripetal[1],
        m * (centripetal[2] + G),
    ];
    // Inertia about the origin in body axes (parallel-axis theorem), diagonal + products.
    let c2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
    let io = |i: usize, j: usize| {
        let diag = if i == j { ic[i] + m * c2 } else { 0.0 };
        diag - m * c[i] * c[j]
    };
    let iw = [0, 1, 2].map(|i| (0..3).map(|j| io(i, j) * w_body[j]).sum::<f64>());
    let g_body = [r[6] * G, r[7] * G, r[8] * G]; // R^T (0, 0, g): the third row of R.
    let gyro = cross(&w_body, &iw);
    let lever = cross(&c, &g_body);
    let rot = [0, 1, 2].map(|i| gyro[i] + m * lever[i]);
    for (i, want) in trans.iter().chain(&rot).enumerate() {
        assert!(
            close(ws.bias()[i], *want, 1e-12),
            "bias[{i}] = {} vs {want}",
            ws.bias()[i]
        );
    }
}
