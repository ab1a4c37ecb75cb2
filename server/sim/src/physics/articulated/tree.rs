//! The robot as a tree of rigid bodies joined by revolute joints on a free (or fixed) base: the
//! constant part of the articulated dynamics, shared by every robot of a batch.
//!
//! Bodies are numbered so that every parent comes before its children (`parent[b] < b`), body 0
//! being the root (the trunk). Each non-root body has one revolute degree of freedom (DoF); a
//! free base adds six DoFs in front of them, MuJoCo's free joint:
//!
//! - `qpos = [x, y, z, qw, qx, qy, qz, q_1 .. q_n]`: base origin in the world, unit quaternion
//!   (base frame to world), joint angles;
//! - `qvel = [vx, vy, vz, wx, wy, wz, qd_1 .. qd_n]`: velocity of the base origin in **world**
//!   axes, angular velocity in the **base's own** axes, joint rates.
//!
//! A fixed base has `qpos = q`, `qvel = qd`. The DoFs form a tree too (`dof_parent[k] < k`): the
//! base's six are a chain (translations, then rotations) and a body's joint hangs on the last DoF
//! of its parent body. The mass matrix has the sparsity of that tree's ancestor relation, stored
//! row by row: row `k` holds columns `ancestors(k)` from the root down and `k` itself last, so
//! entry `(k, i)` for an ancestor `i` sits at `row_start[k] + depth[i]` (see
//! [`ArticulatedTree::row`]).

use super::scalar::Real;
use super::spatial::{Mat3, Vec3, identity, quat_to_mat};
use crate::error::SimError;
use crate::robot::RobotModel;

/// `dof_parent` of a DoF with no parent DoF.
pub const NO_PARENT: usize = usize::MAX;

/// How the root body is attached to the world.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaseJoint {
    /// Six DoFs, MuJoCo's free joint (see the module docs for the coordinates).
    Free,
    /// Welded to the world at the origin, axes aligned.
    Fixed,
}

/// A revolute joint for [`BodySpec`]: where it sits on its parent and what it turns about.
#[derive(Clone, Debug, PartialEq)]
pub struct RevoluteSpec {
    /// The joint's name.
    pub name: String,
    /// Origin of the child (= joint) frame in the parent frame at zero angle (m).
    pub translation: [f64; 3],
    /// Orientation of the child frame in the parent frame at zero angle, row-major.
    pub rotation: [f64; 9],
    /// Rotation axis in the child frame (normalised when the tree is built).
    pub axis: [f64; 3],
    /// Rotor inertia reflected on the joint (kg m^2): added to the mass matrix's diagonal only.
    pub armature: f64,
}

/// One body for [`ArticulatedTree::new`].
#[derive(Clone, Debug, PartialEq)]
pub struct BodySpec {
    /// The body's (link's) name.
    pub name: String,
    /// Parent body index; `None` for the root, which must be body 0.
    pub parent: Option<usize>,
    /// The joint to the parent; `None` for the root.
    pub joint: Option<RevoluteSpec>,
    /// Mass (kg).
    pub mass: f64,
    /// Centre of mass in the body frame (m).
    pub com: [f64; 3],
    /// Rotational inertia about the centre of mass in body axes, `[xx, yy, zz, xy, xz, yz]`.
    pub inertia: [f64; 6],
}

/// The floating-base tree of revolute joints, in structure-of-arrays form.
///
/// Built in f64 ([`ArticulatedTree::new`], [`ArticulatedTree::from_robot`]); [`cast`] gives the
/// same tree in another [`Real`].
///
/// [`cast`]: ArticulatedTree::cast
#[derive(Clone, Debug, PartialEq)]
pub struct ArticulatedTree<T: Real = f64> {
    base: BaseJoint,
    body_name: Vec<String>,
    joint_name: Vec<String>,
    /// Parent body (unused for body 0).
    pub(super) body_parent: Vec<usize>,
    /// Joint frame origin in the parent frame at zero angle.
    pub(super) body_translation: Vec<Vec3<T>>,
    /// Joint frame orientation in the parent frame at zero angle.
    pub(super) body_rotation: Vec<Mat3<T>>,
    /// Unit joint axis in the body frame.
    pub(super) body_axis: Vec<Vec3<T>>,
    pub(super) body_mass: Vec<T>,
    pub(super) body_com: Vec<Vec3<T>>,
    pub(super) body_inertia: Vec<[T; 6]>,
    /// Parent DoF, [`NO_PARENT`] for a root DoF.
    pub(super) dof_parent: Vec<usize>,
    /// Body whose motion the DoF produces (0 for the base's six).
    pub(super) dof_body: Vec<usize>,
    /// Number of ancestor DoFs.
    pub(super) dof_depth: Vec<usize>,
    pub(super) dof_armature: Vec<T>,
    /// Start of each DoF's row in the sparse storage; `nv + 1` entries.
    pub(super) row_start: Vec<usize>,
    /// Column (DoF) of every stored entry, row by row.
    pub(super) row_dofs: Vec<usize>,
}

fn bad(msg: String) -> SimError {
    SimError::Robot(msg)
}

impl ArticulatedTree<f64> {
    /// Build a tree from its bodies (body 0 the root, parents before children).
    pub fn new(base: BaseJoint, bodies: &[BodySpec]) -> Result<Self, SimError> {
        let root = bodies
            .first()
            .ok_or_else(|| bad("an articulated tree needs at least one body".into()))?;
        if root.parent.is_some() || root.joint.is_some() {
            return Err(bad(format!("root body `{}` has a parent", root.name)));
        }
        let n = bodies.len();
        let base_dofs = match base {
            BaseJoint::Free => 6,
            BaseJoint::Fixed => 0,
        };
        let mut tree = Self {
            base,
            body_name: Vec::with_capacity(n),
            joint_name: Vec::with_capacity(n - 1),
            body_parent: Vec::with_capacity(n),
            body_translation: Vec::with_capacity(n),
            body_rotation: Vec::with_capacity(n),
            body_axis: Vec::with_capacity(n),
            body_mass: Vec::with_capacity(n),
            body_com: Vec::with_capacity(n),
            body_inertia: Vec::with_capacity(n),
            dof_parent: Vec::new(),
            dof_body: Vec::new(),
            dof_depth: Vec::new(),
            dof_armature: Vec::new(),
            row_start: Vec::new(),
            row_dofs: Vec::new(),
        };
        for k in 0..base_dofs {
            tree.dof_parent.push(if k == 0 { NO_PARENT } else { k - 1 });
            tree.dof_body.push(0);
            tree.dof_armature.push(0.0);
        }
        for (b, body) in bodies.iter().enumerate() {
            if !(body.mass >= 0.0 && body.mass.is_finite()) {
                return Err(bad(format!("body `{}` has mass {}", body.name, body.mass)));
            }
            tree.body_name.push(body.name.clone());
            tree.body_mass.push(body.mass);
            tree.body_com.push(body.com);
            tree.body_inertia.push(body.inertia);
            if b == 0 {
                tree.body_parent.push(0);
                tree.body_translation.push([0.0; 3]);
                tree.body_rotation.push(identity());
                tree.body_axis.push([0.0; 3]);
                continue;
            }
            let (parent, joint) = match (body.parent, &body.joint) {
                (Some(p), Some(j)) if p < b => (p, j),
                _ => {
                    return Err(bad(format!(
                        "body `{}` needs a joint to a parent listed before it",
                        body.name
                    )));
                }
            };
            let norm = joint.axis.iter().map(|a| a * a).sum::<f64>().sqrt();
            if norm.is_nan() || norm <= 1e-9 {
                return Err(bad(format!("joint `{}` has a zero axis", joint.name)));
            }
            tree.joint_name.push(joint.name.clone());
            tree.body_parent.push(parent);
            tree.body_translation.push(joint.translation);
            tree.body_rotation.push(joint.rotation);
            tree.body_axis.push(joint.axis.map(|a| a / norm));
            // The joint hangs on the last DoF of its parent body.
            let parent_dof = if parent == 0 {
                base_dofs.checked_sub(1).unwrap_or(NO_PARENT)
            } else {
                base_dofs + parent - 1
            };
            tree.dof_parent.push(parent_dof);
            tree.dof_body.push(b);
            tree.dof_armature.push(joint.armature);
        }
        let nv = tree.dof_parent.len();
        tree.dof_depth = vec![0; nv];
        for k in 0..nv {
            let p = tree.dof_parent[k];
            tree.dof_depth[k] = if p == NO_PARENT {
                0
            } else {
                tree.dof_depth[p] + 1
            };
        }
        tree.row_start = Vec::with_capacity(nv + 1);
        tree.row_start.push(0);
        for k in 0..nv {
            let start = tree.row_start[k];
            tree.row_start.push(start + tree.dof_depth[k] + 1);
        }
        tree.row_dofs = vec![0; tree.row_start[nv]];
        for k in 0..nv {
            let mut i = k;
            while i != NO_PARENT {
                tree.row_dofs[tree.row_start[k] + tree.dof_depth[i]] = i;
                i = tree.dof_parent[i];
            }
        }
        Ok(tree)
    }

    /// The tree of our robot model, on a free base: every body of the model (the URDF's links,
    /// fixed parts already merged into their parents as the model does), the URDF's own mass
    /// properties (no inertia floor, no armature on the links) and `armature` on every joint.
    ///
    /// Bodies are ordered depth first from the trunk, children in action order, so that for a
    /// model whose action order follows its tree (the Go2's FL, FR, RL, RR x hip, thigh, calf)
    /// joint `j` of the action order is DoF `6 + j`; [`ArticulatedTree::joint_names`] gives the
    /// order in any case.
    pub fn from_robot(model: &RobotModel, armature: f64) -> Result<Self, SimError> {
        let n = model.bodies.len();
        // Depth-first order: a stack of bodies, children pushed in reverse action order.
        let mut order = Vec::with_capacity(n);
        let mut stack = vec![0usize];
        while let Some(b) = stack.pop() {
            order.push(b);
            let mut children: Vec<usize> = (0..n)
                .filter(|&c| model.bodies[c].parent == Some(b))
                .collect();
            children.sort_by_key(|&c| model.bodies[c].joint);
            stack.extend(children.into_iter().rev());
        }
        if order.len() != n || order[0] != 0 {
            return Err(bad(
                "the model's bodies do not form one tree from the trunk".into(),
            ));
        }
        let mut new_index = vec![0usize; n];
        for (i, &b) in order.iter().enumerate() {
            new_index[b] = i;
        }
        let mut bodies = Vec::with_capacity(n);
        for &b in &order {
            let body = &model.bodies[b];
            let inertial = &body.inertial;
            let i = inertial.inertia;
            let joint = match body.joint {
                None => None,
                Some(j) => {
                    let joint = &model.joints[j];
                    let r = joint.origin.rotation;
                    let quat = [r.w, r.x, r.y, r.z].map(f64::from);
                    Some(RevoluteSpec {
                        name: joint.name.clone(),
                        translation: joint.origin.translation.to_array().map(widen),
                        rotation: quat_to_mat(&quat),
                        axis: joint.axis.to_array().map(widen),
                        armature,
                    })
                }
            };
            bodies.push(BodySpec {
                name: body.name.clone(),
                parent: body.parent.map(|p| new_index[p]),
                joint,
                mass: widen(inertial.mass),
                com: inertial.com.to_array().map(widen),
                inertia: [
                    i.col(0).x,
                    i.col(1).y,
                    i.col(2).z,
                    i.col(1).x,
                    i.col(2).x,
                    i.col(2).y,
                ]
                .map(widen),
            });
        }
        Self::new(BaseJoint::Free, &bodies)
    }
}

/// f32 to f64 through the shortest decimal that round-trips the f32. The URDF's numbers are
/// short decimals (0.0245024); this recovers them exactly where `f64::from` would keep the f32
/// rounding (2e-9 away, 8e-8 relative), so the f64 dynamics sees the robot MuJoCo parses.
fn widen(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(f64::from(x))
}

impl<T: Real> ArticulatedTree<T> {
    /// The same tree in another scalar type.
    pub fn cast<U: Real>(&self) -> ArticulatedTree<U> {
        let c = |x: &T| U::from_f64(x.to_f64());
        ArticulatedTree {
            base: self.base,
            body_name: self.body_name.clone(),
            joint_name: self.joint_name.clone(),
            body_parent: self.body_parent.clone(),
            body_translation: self
                .body_translation
                .iter()
                .map(|v| v.each_ref().map(c))
                .collect(),
            body_rotation: self
                .body_rotation
                .iter()
                .map(|v| v.each_ref().map(c))
                .collect(),
            body_axis: self.body_axis.iter().map(|v| v.each_ref().map(c)).collect(),
            body_mass: self.body_mass.iter().map(c).collect(),
            body_com: self.body_com.iter().map(|v| v.each_ref().map(c)).collect(),
            body_inertia: self
                .body_inertia
                .iter()
                .map(|v| v.each_ref().map(c))
                .collect(),
            dof_parent: self.dof_parent.clone(),
            dof_body: self.dof_body.clone(),
            dof_depth: self.dof_depth.clone(),
            dof_armature: self.dof_armature.iter().map(c).collect(),
            row_start: self.row_start.clone(),
            row_dofs: self.row_dofs.clone(),
        }
    }

    /// How the root is attached.
    pub fn base(&self) -> BaseJoint {
        self.base
    }

    /// Number of DoFs of the base (6 free, 0 fixed).
    pub fn base_dofs(&self) -> usize {
        match self.base {
            BaseJoint::Free => 6,
            BaseJoint::Fixed => 0,
        }
    }

    /// Length of `qpos`.
    pub fn nq(&self) -> usize {
        match self.base {
            BaseJoint::Free => 7 + self.num_joints(),
            BaseJoint::Fixed => self.num_joints(),
        }
    }

    /// Length of `qvel` (the number of DoFs).
    pub fn nv(&self) -> usize {
        self.dof_parent.len()
    }

    /// Number of bodies.
    pub fn num_bodies(&self) -> usize {
        self.body_parent.len()
    }

    /// Number of revolute joints.
    pub fn num_joints(&self) -> usize {
        self.body_parent.len() - 1
    }

    /// Body names, tree order.
    pub fn body_names(&self) -> &[String] {
        &self.body_name
    }

    /// Joint names in DoF order (joint `j` is DoF `base_dofs() + j`, moving body `j + 1`).
    pub fn joint_names(&self) -> &[String] {
        &self.joint_name
    }

    /// Parent body of body `b` (`None` for the root).
    pub fn parent(&self, b: usize) -> Option<usize> {
        (b > 0).then(|| self.body_parent[b])
    }

    /// Parent DoF of DoF `k`, [`NO_PARENT`] for a root DoF.
    pub fn dof_parent(&self, k: usize) -> usize {
        self.dof_parent[k]
    }

    /// Armature of DoF `k` (kg m^2; 0 on the base's DoFs).
    pub fn armature(&self, k: usize) -> T {
        self.dof_armature[k]
    }

    /// Set the armature of DoF `k`.
    pub fn set_armature(&mut self, k: usize, armature: T) {
        self.dof_armature[k] = armature;
    }

    /// Total mass (kg).
    pub fn total_mass(&self) -> T {
        self.body_mass.iter().fold(T::ZERO, |a, &m| a + m)
    }

    /// Stored entries of the mass matrix (its lower triangle's ancestor pattern).
    pub fn nnz(&self) -> usize {
        self.row_dofs.len()
    }

    /// Row `k` of the sparse storage: its range in the stored entries and the columns (DoFs)
    /// they belong to, the root's first and `k` last.
    pub fn row(&self, k: usize) -> (std::ops::Range<usize>, &[usize]) {
        let range = self.row_start[k]..self.row_start[k + 1];
        (range.clone(), &self.row_dofs[range])
    }
}
