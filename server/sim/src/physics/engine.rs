//! The physics engine of a group of robots, chosen per session by `physics.engine` in the task
//! config: `"articulated"` (our own reduced-coordinate dynamics, issue 34, with parry's collision
//! queries; the default) or `"rapier"` (impulse joints in rapier). Both offer the same
//! operations, which [`PhysicsWorld`] dispatches; the task layer does not know which one runs.

use rapier3d::math::{Pose, Vec3};
use rapier3d::prelude::LockedAxes;

use super::actuation::ActuatorParams;
use super::articulated::{ArticulatedTree, ArticulatedWorld, Workspace};
use super::counters::PhysicsCounters;
use super::params::PhysicsParams;
use super::robot_state::RobotState;
use super::world::{RobotPhysicalParams, RobotWorld};
use crate::robot::{NUM_JOINTS, RobotModel};
use crate::terrain::Terrain;

/// Which dynamics steps the robots.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum EngineKind {
    /// rapier's rigid bodies held together by impulse joints.
    Rapier,
    /// Reduced coordinates: a floating-base tree, joint-space contacts and limits (the default
    /// since it passed issue 34's gates).
    #[default]
    Articulated,
}

impl EngineKind {
    /// The config's name of the engine.
    pub fn name(self) -> &'static str {
        match self {
            EngineKind::Rapier => "rapier",
            EngineKind::Articulated => "articulated",
        }
    }

    /// Every engine.
    pub const ALL: [EngineKind; 2] = [EngineKind::Articulated, EngineKind::Rapier];

    /// The engine the config calls `name`.
    pub fn from_name(name: &str) -> Option<EngineKind> {
        Self::ALL.into_iter().find(|e| e.name() == name)
    }
}

/// A group of robots over one terrain, in the engine the config chose.
pub enum PhysicsWorld {
    /// rapier's world (boxed: it is ten times the size of the other).
    Rapier(Box<RobotWorld>),
    /// The articulated engine.
    Articulated(Box<ArticulatedWorld>),
}

impl PhysicsWorld {
    /// A world of `count` robots of `model` over `terrain`, in `params.engine`.
    pub fn new(
        model: &RobotModel,
        count: usize,
        terrain: &Terrain,
        params: &PhysicsParams,
    ) -> Self {
        match params.engine {
            EngineKind::Rapier => PhysicsWorld::Rapier(Box::new(RobotWorld::new(
                model,
                count,
                terrain.collider(),
                params,
            ))),
            EngineKind::Articulated => PhysicsWorld::Articulated(Box::new(ArticulatedWorld::new(
                model, count, terrain, params,
            ))),
        }
    }

    /// Which engine this is.
    pub fn kind(&self) -> EngineKind {
        match self {
            PhysicsWorld::Rapier(_) => EngineKind::Rapier,
            PhysicsWorld::Articulated(_) => EngineKind::Articulated,
        }
    }

    /// Number of robots.
    pub fn len(&self) -> usize {
        match self {
            PhysicsWorld::Rapier(w) => w.len(),
            PhysicsWorld::Articulated(w) => w.len(),
        }
    }

    /// Whether the world holds no robot.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Apply new physical parameters (mass, armature, friction) to robot `slot`.
    pub fn set_physical_params(
        &mut self,
        model: &RobotModel,
        slot: usize,
        params: &RobotPhysicalParams,
    ) {
        match self {
            PhysicsWorld::Rapier(w) => w.set_physical_params(model, slot, params),
            PhysicsWorld::Articulated(w) => w.set_physical_params(model, slot, params),
        }
    }

    /// Teleport robot `slot` (see [`RobotWorld::set_robot_state`]).
    pub fn set_robot_state(
        &mut self,
        model: &RobotModel,
        slot: usize,
        base: Pose,
        linvel: Vec3,
        angvel: Vec3,
        q: &[f32; NUM_JOINTS],
    ) {
        match self {
            PhysicsWorld::Rapier(w) => w.set_robot_state(model, slot, base, linvel, angvel, q),
            PhysicsWorld::Articulated(w) => w.set_robot_state(model, slot, base, linvel, angvel, q),
        }
    }

    /// One physics step towards `targets` (see [`RobotWorld::step`]).
    pub fn step(
        &mut self,
        model: &RobotModel,
        targets: &[f32],
        actuators: &[ActuatorParams],
        torques: &mut [f32],
    ) {
        match self {
            PhysicsWorld::Rapier(w) => w.step(model, targets, actuators, torques),
            PhysicsWorld::Articulated(w) => w.step(model, targets, actuators, torques),
        }
    }

    /// Read robot `slot`'s pose, velocities, joints and feet (contacts untouched).
    pub fn read_kinematics(&mut self, model: &RobotModel, slot: usize, s: &mut RobotState) {
        match self {
            PhysicsWorld::Rapier(w) => w.read_kinematics(model, slot, s),
            PhysicsWorld::Articulated(w) => w.read_kinematics(model, slot, s),
        }
    }

    /// Read every robot's state, with the contact forces of the last physics step.
    pub fn read_states(&mut self, model: &RobotModel, out: &mut [RobotState]) {
        match self {
            PhysicsWorld::Rapier(w) => w.read_states(model, out),
            PhysicsWorld::Articulated(w) => w.read_states(model, out),
        }
    }

    /// Add `delta` to the linear velocity of robot `slot` (pushes).
    pub fn add_base_velocity(&mut self, slot: usize, delta: Vec3) {
        match self {
            PhysicsWorld::Rapier(w) => w.add_base_velocity(slot, delta),
            PhysicsWorld::Articulated(w) => w.add_base_velocity(slot, delta),
        }
    }

    /// World poses of robot `slot`'s bodies, model order (trunk first), for visualisation.
    pub fn body_poses(&self, slot: usize) -> Vec<Pose> {
        match self {
            PhysicsWorld::Rapier(w) => w.body_poses(slot),
            PhysicsWorld::Articulated(w) => {
                // Visualisation only: its own scratch, so this stays a shared borrow.
                let tree: &ArticulatedTree<f64> = w.tree();
                let mut ws = Workspace::new(tree);
                let (qpos, qvel) = w.state(slot);
                tree.forward_kinematics(&mut ws, qpos, qvel);
                (0..tree.num_bodies())
                    .map(|m| w.pose_in(&ws, w.tree_body_of(m)))
                    .collect()
            }
        }
    }

    /// Mass (kg) and world centre of mass of body `b` (model order) of robot `slot`.
    pub fn body_mass(&self, slot: usize, b: usize) -> (f32, Vec3) {
        match self {
            PhysicsWorld::Rapier(w) => w.body_mass(slot, b),
            PhysicsWorld::Articulated(w) => w.body_mass(slot, b),
        }
    }

    /// Rotational inertia (kg m^2) of robot `slot` taken as rigid about the world axis `axis`
    /// through its centre of mass, as simulated (rapier: armature and inertia floor on the
    /// links; articulated: the URDF's links, armature on the joints).
    pub fn whole_body_inertia(&self, slot: usize, axis: Vec3) -> f32 {
        match self {
            PhysicsWorld::Rapier(w) => w.whole_body_inertia(slot, axis),
            PhysicsWorld::Articulated(w) => w.whole_body_inertia(slot, axis),
        }
    }

    /// Whether robot `slot` gets extra solver iterations (rapier only).
    pub fn has_extra_iterations(&self, slot: usize) -> bool {
        match self {
            PhysicsWorld::Rapier(w) => w.has_extra_iterations(slot),
            PhysicsWorld::Articulated(_) => false,
        }
    }

    /// Hold `axes` of robot `slot`'s trunk (test hook).
    #[doc(hidden)]
    pub fn lock_trunk(&mut self, slot: usize, axes: LockedAxes) {
        match self {
            PhysicsWorld::Rapier(w) => w.lock_trunk(slot, axes),
            PhysicsWorld::Articulated(w) => w.lock_trunk(slot, axes),
        }
    }

    /// Set robot `slot`'s trunk velocity to `speed` m/s along x (test hook for the blow-up
    /// guard).
    #[doc(hidden)]
    pub fn poison(&mut self, slot: usize, speed: f32) {
        match self {
            PhysicsWorld::Rapier(w) => w.poison(slot, speed),
            PhysicsWorld::Articulated(w) => w.poison(slot, speed),
        }
    }

    /// Time by stage summed over this world's steps since it was built.
    pub fn counters(&self) -> &PhysicsCounters {
        match self {
            PhysicsWorld::Rapier(w) => w.counters(),
            PhysicsWorld::Articulated(w) => w.counters(),
        }
    }

    /// Remove every robot's joints (rapier benchmark hook; the articulated engine has no joints
    /// to remove, so it is left as is).
    #[doc(hidden)]
    pub fn remove_joints(&mut self) {
        if let PhysicsWorld::Rapier(w) = self {
            w.remove_joints();
        }
    }

    /// The rapier world, if that is the engine.
    pub fn rapier(&self) -> Option<&RobotWorld> {
        match self {
            PhysicsWorld::Rapier(w) => Some(w),
            PhysicsWorld::Articulated(_) => None,
        }
    }

    /// The articulated world, if that is the engine.
    pub fn articulated(&self) -> Option<&ArticulatedWorld> {
        match self {
            PhysicsWorld::Rapier(_) => None,
            PhysicsWorld::Articulated(w) => Some(w),
        }
    }

    /// The articulated world, mutable, if that is the engine.
    pub fn articulated_mut(&mut self) -> Option<&mut ArticulatedWorld> {
        match self {
            PhysicsWorld::Rapier(_) => None,
            PhysicsWorld::Articulated(w) => Some(w),
        }
    }
}
