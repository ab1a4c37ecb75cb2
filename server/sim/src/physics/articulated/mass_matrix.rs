//! The joint-space mass matrix by the composite rigid body algorithm (Featherstone 6.2).
//!
//! With every quantity in one frame (see [`Workspace`]), a body's composite inertia is the plain
//! sum of its subtree's inertias, `I^c_b = I_b + sum_{children c} I^c_c`, and for a DoF `j` moving
//! body `b` and each DoF `i` that is `j` or one of its ancestors,
//! `M[j][i] = M[i][j] = S_i . (I^c_b S_j)`; every other entry is zero. The armature of DoF `j`
//! is then added to `M[j][j]`: a rotor's reflected inertia acts on its joint coordinate alone
//! (as MuJoCo's `armature` and PhysX's articulation armature), not on the link.

use super::scalar::Real;
use super::spatial::{dot6, inertia_add, inertia_mul};
use super::tree::ArticulatedTree;
use super::workspace::Workspace;

impl<T: Real> ArticulatedTree<T> {
    /// The mass matrix for the state of the last [`forward_kinematics`](Self::forward_kinematics),
    /// into `ws` (sparse rows: [`Workspace::mass_matrix`], dense: [`Workspace::mass_matrix_dense`]).
    pub fn mass_matrix(&self, ws: &mut Workspace<T>) {
        ws.composite.copy_from_slice(&ws.inertia);
        for b in (1..self.num_bodies()).rev() {
            let child = ws.composite[b];
            inertia_add(&mut ws.composite[self.body_parent[b]], &child);
        }
        for j in 0..self.nv() {
            let f = inertia_mul(&ws.composite[self.dof_body[j]], &ws.motion[j]);
            let (range, cols) = self.row(j);
            for (entry, &i) in ws.mass_matrix[range].iter_mut().zip(cols) {
                *entry = dot6(&ws.motion[i], &f);
            }
            ws.mass_matrix[self.row_start[j + 1] - 1] += self.dof_armature[j];
        }
    }

    /// `out = M x` with the mass matrix in `ws`.
    pub fn mul_mass_matrix(&self, ws: &Workspace<T>, x: &[T], out: &mut [T]) {
        assert_eq!(x.len(), self.nv(), "x length");
        assert_eq!(out.len(), self.nv(), "out length");
        out.fill(T::ZERO);
        for k in 0..self.nv() {
            let (range, cols) = self.row(k);
            let (last, below) = cols.split_last().unwrap_or((&k, &[]));
            let values = &ws.mass_matrix[range];
            out[k] += values[values.len() - 1] * x[*last];
            for (&m, &i) in values.iter().zip(below) {
                out[k] += m * x[i];
                out[i] += m * x[k];
            }
        }
    }
}
