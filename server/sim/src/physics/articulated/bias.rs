//! Bias forces `C(q, qd) qd + g(q)` and inverse dynamics by the recursive Newton-Euler algorithm
//! (Featherstone 5.3), in the one frame of [`Workspace`].
//!
//! Gravity enters as a fictitious upward acceleration of the root, `a_0 = [0; -g]`. Outward:
//! `a_b = a_p + S_b qdd_b + v_b x (S_b qd_b)` (the last term is `dS/dt qd` of a joint axis that
//! turns with its body), and for the free base `a_0 += S_base qdd_base + [0; v_0 x w_0]`: the
//! base's rotation axes pass through its moving origin, so their twists change at rate
//! `v_0 x w_0` in the fixed frame. Each body's net force `f_b = I_b a_b + v_b x* I_b v_b`;
//! inward, `tau_k = S_k . f_b` and `f_p += f_b`. With `qdd = 0` the torques are the bias forces.

use super::scalar::Real;
use super::spatial::{Vec3, add_scaled6, cross, cross_force, cross_motion, dot6, inertia_mul};
use super::tree::{ArticulatedTree, BaseJoint};
use super::workspace::Workspace;

impl<T: Real> ArticulatedTree<T> {
    /// Bias forces for the state of the last [`forward_kinematics`](Self::forward_kinematics)
    /// under `gravity` (m/s^2, world, e.g. `[0, 0, -9.81]`), into [`Workspace::bias`]: MuJoCo's
    /// `qfrc_bias`.
    pub fn bias_forces(&self, ws: &mut Workspace<T>, gravity: &Vec3<T>) {
        let mut bias = std::mem::take(&mut ws.bias);
        self.newton_euler(ws, None, gravity, &mut bias);
        ws.bias = bias;
    }

    /// Generalised forces that produce the accelerations `qacc` from the last kinematics' state:
    /// `M qacc + C qd + g`, armature included, into `out`.
    pub fn inverse_dynamics(
        &self,
        ws: &mut Workspace<T>,
        qacc: &[T],
        gravity: &Vec3<T>,
        out: &mut [T],
    ) {
        assert_eq!(qacc.len(), self.nv(), "qacc length");
        self.newton_euler(ws, Some(qacc), gravity, out);
        for ((o, &a), &arm) in out.iter_mut().zip(qacc).zip(&self.dof_armature) {
            *o += arm * a;
        }
    }

    fn newton_euler(
        &self,
        ws: &mut Workspace<T>,
        qacc: Option<&[T]>,
        gravity: &Vec3<T>,
        out: &mut [T],
    ) {
        assert_eq!(out.len(), self.nv(), "output length");
        let z = T::ZERO;
        let mut a0 = [z, z, z, -gravity[0], -gravity[1], -gravity[2]];
        if self.base() == BaseJoint::Free {
            let v = &ws.velocity[0];
            let drift = cross(&[v[3], v[4], v[5]], &[v[0], v[1], v[2]]);
            for (a, d) in a0[3..].iter_mut().zip(drift) {
                *a += d;
            }
            if let Some(qacc) = qacc {
                for (&a, s) in qacc.iter().zip(&ws.motion[..6]) {
                    add_scaled6(&mut a0, a, s);
                }
            }
        }
        ws.acceleration[0] = a0;
        let base_dofs = self.base_dofs();
        for b in 1..self.num_bodies() {
            let k = base_dofs + b - 1;
            let s = &ws.motion[k];
            let sqd = s.map(|x| x * ws.qvel[k]);
            let mut a = ws.acceleration[self.body_parent[b]];
            add_scaled6(&mut a, T::ONE, &cross_motion(&ws.velocity[b], &sqd));
            if let Some(qacc) = qacc {
                add_scaled6(&mut a, qacc[k], s);
            }
            ws.acceleration[b] = a;
        }
        for b in 0..self.num_bodies() {
            let inertia = &ws.inertia[b];
            let v = &ws.velocity[b];
            let mut f = inertia_mul(inertia, &ws.acceleration[b]);
            add_scaled6(&mut f, T::ONE, &cross_force(v, &inertia_mul(inertia, v)));
            ws.force[b] = f;
        }
        for b in (1..self.num_bodies()).rev() {
            let k = base_dofs + b - 1;
            out[k] = dot6(&ws.motion[k], &ws.force[b]);
            let f = ws.force[b];
            add_scaled6(&mut ws.force[self.body_parent[b]], T::ONE, &f);
        }
        for (o, s) in out.iter_mut().zip(&ws.motion[..base_dofs]) {
            *o = dot6(s, &ws.force[0]);
        }
    }
}
