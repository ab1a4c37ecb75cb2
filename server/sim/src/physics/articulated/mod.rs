//! Reduced-coordinate dynamics of an articulated robot (issue 34): a floating-base tree of
//! revolute joints, its forward kinematics, the joint-space mass matrix (composite rigid body
//! algorithm, armature on the joint diagonal), the bias forces (recursive Newton-Euler) and the
//! mass matrix's tree-sparse `L^T D L` factorisation, and the step built on them
//! ([`ArticulatedWorld`]: PD torques, damping and friction, contacts from parry's queries and
//! joint limits solved in joint space, semi-implicit Euler). rapier (parry) stays the collision
//! engine; `physics.engine = "articulated"` selects this one.
//!
//! Layout: one [`ArticulatedTree`] (the constants, structure of arrays, shared by every robot)
//! and one [`Workspace`] per robot (every state-dependent buffer, sized once): no call allocates.
//! Coordinates follow MuJoCo's free joint (see [`ArticulatedTree`]), so `qpos`, `qvel`,
//! the mass matrix and the bias forces compare entry for entry with `mj_fullM` and `qfrc_bias`
//! (`tests/articulated_vs_mujoco.rs`).
//!
//! Precision: the code is generic over [`Real`]; f64 is what runs for now. On the MuJoCo
//! fixture, f64 agrees to 9e-16 (mass matrix) and 6e-15 (bias forces), the largest entry error
//! over the largest entry; the same tree cast to f32 measured 5e-8 and 2e-7 on that measure
//! (3e-4 relative on the smallest mass-matrix entries, which are 1e-5 of the largest), so f32 is measured
//! to hold for this layer; whether it holds through the contact solve is still to measure.
//!
//! Equations: docs/src/articulated.md; Featherstone, *Rigid Body Dynamics Algorithms* (2008),
//! ch. 5-7.

mod bias;
mod factor;
mod kinematics;
mod mass_matrix;
mod scalar;
mod solver;
pub mod spatial;
mod tree;
mod workspace;
mod world;

#[cfg(test)]
mod test;

pub use scalar::Real;
pub use solver::{RowKind, Rows, SoftConstraint};
pub use tree::{ArticulatedTree, BaseJoint, BodySpec, NO_PARENT, RevoluteSpec};
pub use workspace::Workspace;
pub use world::ArticulatedWorld;
