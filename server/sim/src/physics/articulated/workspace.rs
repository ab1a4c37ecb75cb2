//! The state-dependent quantities of one robot's articulated dynamics: scratch buffers sized once
//! from the tree, so that kinematics, mass matrix, bias forces and factorisation allocate nothing.
//!
//! Frame: every spatial quantity is in world-aligned axes about the **base origin** (the root
//! body's origin at this instant), not the world origin. The dynamics do not depend on where the
//! robot stands, and keeping the reference point on the robot keeps the lever arms short (a
//! robot 100 m from the origin would otherwise cost f32 four digits; MuJoCo uses the subtree's
//! centre of mass for the same reason).

use super::scalar::Real;
use super::spatial::{Inertia, Mat3, Vec3, Vec6, add, cross, identity};
use super::tree::ArticulatedTree;

/// Scratch and results of the articulated dynamics of one robot.
#[derive(Clone, Debug, PartialEq)]
pub struct Workspace<T: Real = f64> {
    /// Base origin in the world.
    pub(super) base_position: Vec3<T>,
    /// Per body: orientation (body to world).
    pub(super) rotation: Vec<Mat3<T>>,
    /// Per body: origin relative to the base origin, world axes.
    pub(super) offset: Vec<Vec3<T>>,
    /// Per DoF: motion subspace (the spatial velocity a unit rate of the DoF produces).
    pub(super) motion: Vec<Vec6<T>>,
    /// Per DoF: the generalised velocity the kinematics ran with.
    pub(super) qvel: Vec<T>,
    /// Per body: spatial velocity.
    pub(super) velocity: Vec<Vec6<T>>,
    /// Per body: spatial inertia.
    pub(super) inertia: Vec<Inertia<T>>,
    /// Per body: inertia of the subtree rooted at it (composite rigid body).
    pub(super) composite: Vec<Inertia<T>>,
    /// Per body: spatial acceleration (Newton-Euler's outward pass).
    pub(super) acceleration: Vec<Vec6<T>>,
    /// Per body: spatial force transmitted across its joint (Newton-Euler's inward pass).
    pub(super) force: Vec<Vec6<T>>,
    /// The mass matrix in the tree's sparse row storage.
    pub(super) mass_matrix: Vec<T>,
    /// Its `L^T D L` factor, same storage: `D` on the diagonal entries, `L` below.
    pub(super) factor: Vec<T>,
    /// Bias forces `C(q, qd) qd + g(q)`, one per DoF.
    pub(super) bias: Vec<T>,
}

impl<T: Real> Workspace<T> {
    /// Buffers for `tree`.
    pub fn new(tree: &ArticulatedTree<T>) -> Self {
        let (nb, nv) = (tree.num_bodies(), tree.nv());
        Self {
            base_position: [T::ZERO; 3],
            rotation: vec![identity(); nb],
            offset: vec![[T::ZERO; 3]; nb],
            motion: vec![[T::ZERO; 6]; nv],
            qvel: vec![T::ZERO; nv],
            velocity: vec![[T::ZERO; 6]; nb],
            inertia: vec![[T::ZERO; 10]; nb],
            composite: vec![[T::ZERO; 10]; nb],
            acceleration: vec![[T::ZERO; 6]; nb],
            force: vec![[T::ZERO; 6]; nb],
            mass_matrix: vec![T::ZERO; tree.nnz()],
            factor: vec![T::ZERO; tree.nnz()],
            bias: vec![T::ZERO; nv],
        }
    }

    /// A workspace with no buffers (a placeholder while the real one is lent out).
    pub(super) fn empty() -> Self {
        Self {
            base_position: [T::ZERO; 3],
            rotation: Vec::new(),
            offset: Vec::new(),
            motion: Vec::new(),
            qvel: Vec::new(),
            velocity: Vec::new(),
            inertia: Vec::new(),
            composite: Vec::new(),
            acceleration: Vec::new(),
            force: Vec::new(),
            mass_matrix: Vec::new(),
            factor: Vec::new(),
            bias: Vec::new(),
        }
    }

    /// Position of body `b`'s origin in the world (after [`ArticulatedTree::forward_kinematics`]).
    pub fn body_position(&self, b: usize) -> Vec3<T> {
        add(&self.base_position, &self.offset[b])
    }

    /// Orientation of body `b`, body to world, row-major.
    pub fn body_rotation(&self, b: usize) -> Mat3<T> {
        self.rotation[b]
    }

    /// Angular velocity of body `b` and the velocity of its origin, both in world axes.
    pub fn body_velocity(&self, b: usize) -> (Vec3<T>, Vec3<T>) {
        let v = &self.velocity[b];
        let w = [v[0], v[1], v[2]];
        // The stored linear part is the velocity of the body point at the base origin.
        let origin = add(&[v[3], v[4], v[5]], &cross(&w, &self.offset[b]));
        (w, origin)
    }

    /// Spatial velocity of body `b` about the base origin (angular, then linear).
    pub fn body_spatial_velocity(&self, b: usize) -> Vec6<T> {
        self.velocity[b]
    }

    /// The bias forces `C(q, qd) qd + g(q)` (after [`ArticulatedTree::bias_forces`]).
    pub fn bias(&self) -> &[T] {
        &self.bias
    }

    /// The mass matrix in sparse row storage (see [`ArticulatedTree::row`]).
    pub fn mass_matrix(&self) -> &[T] {
        &self.mass_matrix
    }

    /// The mass matrix as a dense row-major `nv x nv` matrix, into `out`.
    pub fn mass_matrix_dense(&self, tree: &ArticulatedTree<T>, out: &mut [T]) {
        let nv = tree.nv();
        assert_eq!(out.len(), nv * nv, "dense mass matrix size");
        out.fill(T::ZERO);
        for k in 0..nv {
            let (range, cols) = tree.row(k);
            for (&value, &i) in self.mass_matrix[range].iter().zip(cols) {
                out[k * nv + i] = value;
                out[i * nv + k] = value;
            }
        }
    }
}
