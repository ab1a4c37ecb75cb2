//! Forward kinematics: each body's pose, each DoF's motion subspace, each body's spatial velocity
//! and spatial inertia, in world axes about the base origin (see [`Workspace`]).
//!
//! Outward from the root, with `R_b` body `b`'s orientation and `r_b` its origin relative to the
//! base origin:
//!
//! - `R_b = R_p E_b Rot(a_b, q_b)`, `r_b = r_p + R_p t_b` (`E_b`, `t_b` the joint's fixed
//!   transform to the parent `p`, `a_b` its axis in the body frame);
//! - a revolute DoF's motion subspace is the unit twist about its world axis `s = R_p E_b a_b`
//!   through `r_b`: `S = [s; r_b x s]`; the free base's DoFs are `[0; e_k]` (world translations)
//!   and `[R_0 e_k; 0]` (rotations about the base's own axes, through the base origin);
//! - `v_b = v_p + S_b qd_b`;
//! - the spatial inertia about the base origin from the mass `m`, centre of mass
//!   `c = r_b + R_b c_b` and `R_b I_b R_b^T` (parallel-axis theorem).

use super::scalar::Real;
use super::spatial::{
    add, add_scaled6, axis_angle, column, cross, inertia_at, mat_mul, mat_vec, quat_to_mat,
    rotate_symmetric,
};
use super::tree::{ArticulatedTree, BaseJoint};
use super::workspace::Workspace;

impl<T: Real> ArticulatedTree<T> {
    /// Poses, motion subspaces, velocities and inertias of every body for `qpos` (length
    /// [`nq`](Self::nq)) and `qvel` (length [`nv`](Self::nv)), into `ws`. The base quaternion
    /// is normalised on the way (`qpos` itself is left alone).
    pub fn forward_kinematics(&self, ws: &mut Workspace<T>, qpos: &[T], qvel: &[T]) {
        assert_eq!(qpos.len(), self.nq(), "qpos length");
        assert_eq!(qvel.len(), self.nv(), "qvel length");
        let z = T::ZERO;
        ws.qvel.copy_from_slice(qvel);
        ws.offset[0] = [z; 3];
        let joint_q = match self.base() {
            BaseJoint::Free => {
                ws.base_position = [qpos[0], qpos[1], qpos[2]];
                let r = quat_to_mat(&[qpos[3], qpos[4], qpos[5], qpos[6]]);
                ws.rotation[0] = r;
                for k in 0..3 {
                    let mut e = [z; 3];
                    e[k] = T::ONE;
                    ws.motion[k] = [z, z, z, e[0], e[1], e[2]];
                    let a = column(&r, k);
                    ws.motion[3 + k] = [a[0], a[1], a[2], z, z, z];
                }
                let w = mat_vec(&r, &[qvel[3], qvel[4], qvel[5]]);
                ws.velocity[0] = [w[0], w[1], w[2], qvel[0], qvel[1], qvel[2]];
                &qpos[7..]
            }
            BaseJoint::Fixed => {
                ws.base_position = [z; 3];
                ws.rotation[0] = super::spatial::identity();
                ws.velocity[0] = [z; 6];
                qpos
            }
        };
        let base_dofs = self.base_dofs();
        for b in 1..self.num_bodies() {
            let p = self.body_parent[b];
            let k = base_dofs + b - 1;
            let parent_rotation = ws.rotation[p];
            let joint_frame = mat_mul(&parent_rotation, &self.body_rotation[b]);
            let local_axis = &self.body_axis[b];
            let axis = mat_vec(&joint_frame, local_axis);
            ws.rotation[b] = mat_mul(&joint_frame, &axis_angle(local_axis, joint_q[b - 1]));
            let offset = add(
                &ws.offset[p],
                &mat_vec(&parent_rotation, &self.body_translation[b]),
            );
            ws.offset[b] = offset;
            let lin = cross(&offset, &axis);
            let s = [axis[0], axis[1], axis[2], lin[0], lin[1], lin[2]];
            ws.motion[k] = s;
            let mut v = ws.velocity[p];
            add_scaled6(&mut v, qvel[k], &s);
            ws.velocity[b] = v;
        }
        for b in 0..self.num_bodies() {
            let r = &ws.rotation[b];
            let com = add(&ws.offset[b], &mat_vec(r, &self.body_com[b]));
            let ic = rotate_symmetric(r, &self.body_inertia[b]);
            ws.inertia[b] = inertia_at(self.body_mass[b], &com, &ic);
        }
    }
}
