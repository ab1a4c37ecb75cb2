//! The mass matrix's `L^T D L` factorisation along the tree, and its solve (Featherstone 6.5).
//!
//! With parents numbered before children, `M = L^T D L` with `L` unit lower triangular has
//! exactly `M`'s sparsity (the ancestor pattern): no fill-in. From the last DoF to the first,
//! each DoF `k` with pivot `D_k = M[k][k]` eliminates itself from its ancestors:
//! for each ancestor `i`, `a = M[k][i] / D_k`, then `M[i][j] -= a M[k][j]` for every `j` that
//! is `i` or an ancestor of `i`, and `L[k][i] = a`. In row storage (root first) the ancestors of
//! `i` are a prefix of `k`'s row, so each update is one contiguous `axpy`. Solving `M x = b`
//! is three walks over the same rows: `L^T` (leaves to root), `D`, `L` (root to leaves).

use super::scalar::Real;
use super::tree::ArticulatedTree;
use super::workspace::Workspace;

impl<T: Real> ArticulatedTree<T> {
    /// Factorise the mass matrix in `ws` (computed by [`mass_matrix`](Self::mass_matrix)).
    /// The matrix must be positive definite, which a tree with positive masses and inertias is.
    pub fn factor(&self, ws: &mut Workspace<T>) {
        ws.factor.copy_from_slice(&ws.mass_matrix);
        for k in (0..self.nv()).rev() {
            let start = self.row_start[k];
            let depth = self.dof_depth[k];
            let (head, tail) = ws.factor.split_at_mut(start);
            let row_k = &mut tail[..=depth];
            let inv_pivot = T::ONE / row_k[depth];
            for d in (0..depth).rev() {
                let i = self.row_dofs[start + d];
                let a = row_k[d] * inv_pivot;
                let row_i = &mut head[self.row_start[i]..=self.row_start[i] + d];
                for (x, &y) in row_i.iter_mut().zip(&row_k[..=d]) {
                    *x -= a * y;
                }
                row_k[d] = a;
            }
        }
    }

    /// Solve `M x = b` in place (`x` holds `b` on entry) with the factor in `ws`.
    pub fn solve(&self, ws: &Workspace<T>, x: &mut [T]) {
        assert_eq!(x.len(), self.nv(), "right-hand side length");
        let nv = self.nv();
        for k in (0..nv).rev() {
            let (start, diag) = (self.row_start[k], self.row_start[k + 1] - 1);
            let xk = x[k];
            for e in start..diag {
                x[self.row_dofs[e]] -= ws.factor[e] * xk;
            }
        }
        for (xk, &end) in x.iter_mut().zip(&self.row_start[1..]) {
            *xk /= ws.factor[end - 1];
        }
        for k in 0..nv {
            let (start, diag) = (self.row_start[k], self.row_start[k + 1] - 1);
            let mut s = x[k];
            for e in start..diag {
                s -= ws.factor[e] * x[self.row_dofs[e]];
            }
            x[k] = s;
        }
    }

    /// The pivots `D` of the last factorisation, into `out` (all positive for a valid tree).
    pub fn pivots(&self, ws: &Workspace<T>, out: &mut [T]) {
        for (k, o) in out.iter_mut().enumerate().take(self.nv()) {
            *o = ws.factor[self.row_start[k + 1] - 1];
        }
    }
}
