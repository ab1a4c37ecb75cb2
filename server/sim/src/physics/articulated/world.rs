//! A group of robots stepped with the articulated dynamics: the same operations as the rapier
//! [`RobotWorld`](crate::physics::RobotWorld), over one shared terrain shape.
//!
//! One physics step of one robot (semi-implicit Euler, step `h`):
//!
//! 1. kinematics, mass matrix (armature on the joint diagonal, the robot's own payload on the
//!    trunk), bias forces `c`, factor `M = L^T D L`;
//! 2. joint torques `tau`: the PD law clipped to the effort limit plus passive damping and
//!    Coulomb friction (the rapier engine's [`pd_torque`] and [`passive_torque`]);
//! 3. unconstrained velocity `v_free = v + h M^-1 (tau - c)`;
//! 4. contact rows from parry's contact manifolds between each robot collider and the terrain
//!    (one normal and two friction rows per point, friction `mu` from the robot's parameters),
//!    one row per joint at or heading into a stop; the Delassus matrix `J M^-1 J^T` from the
//!    factor, projected Gauss-Seidel warm-started from the last step ([`Rows::solve`]), and
//!    `v+ = v_free + M^-1 J^T lambda`;
//! 5. `q <- q (+) h v+`: positions and joint angles by Euler, the base quaternion by the
//!    exponential map of the body-frame angular velocity, renormalised.
//!
//! Storage is contiguous per world (`qpos`, `qvel` and the per-robot parameters as flat arrays,
//! one shared tree, one scratch workspace, one set of rows): our code allocates nothing per
//! step. parry's manifold update for boxes and capsules does (it rebuilds the point list, as in
//! rapier's own narrow phase), and its caches grow as contacts appear.

use std::time::Instant;

use rapier3d::math::{Mat3 as GMat3, Pose, Rotation, Vec3};
use rapier3d::parry::query::{
    ContactManifold, ContactManifoldsWorkspace, DefaultQueryDispatcher, PersistentQueryDispatcher,
};
use rapier3d::prelude::{LockedAxes, SharedShape};

use super::solver::{RowKind, Rows, SoftConstraint};
use super::spatial::{self, cross, dot, mat_vec};
use super::tree::{ArticulatedTree, NO_PARENT};
use super::workspace::Workspace;
use crate::physics::actuation::{ActuatorParams, passive_torque, pd_torque};
use crate::physics::counters::PhysicsCounters;
use crate::physics::params::PhysicsParams;
use crate::physics::robot_state::RobotState;
use crate::physics::world::{CONTACT_FORCE_THRESHOLD, RobotPhysicalParams};
use crate::robot::{ColliderRole, NUM_FEET, NUM_JOINTS, RobotModel, Shape};
use crate::terrain::Terrain;

/// Distance (m) within which parry reports a contact point; closer points become speculative
/// rows (a foot at 2 m/s moves 10 mm in a 5 ms step).
const CONTACT_PREDICTION: f32 = 0.01;
/// A joint closer than this to a stop (rad), or heading into it within a step, gets a row.
const LIMIT_PREDICTION: f64 = 0.02;
/// Contact points kept per robot per step, in collider order (a fallen robot on a mesh edge can
/// report more; the rest are dropped).
const MAX_CONTACT_POINTS: usize = 32;
/// How far (m) a robot's base may move before its reachable terrain height is asked again.
const GROUND_CACHE_SLACK: f32 = 0.05;
/// Contact points kept per collider.
const MAX_POINTS_PER_COLLIDER: usize = 8;
/// Gauss-Seidel sweeps at most per step, and the impulse change (N s) that ends them early:
/// 1e-4 N s is 20 mN over a 5 ms step (the robot weighs 147 N). Under random targets, with the
/// warm start: 15-29 sweeps a step at 1e-7, 7-24 at 1e-5, 5-7 (18 at worst) at 1e-4, with the
/// same test figures and MuJoCo cross-checks.
const MAX_SWEEPS: usize = 50;
const SWEEP_TOLERANCE: f64 = 1e-4;
/// Tags of joint-stop rows: `LIMIT_TAG + 2 j + side` (side 0 the lower stop).
const LIMIT_TAG: u32 = 1 << 31;
/// Diagonal put on a locked base DoF (test hook), which is decoupled from the others.
const LOCKED_DIAGONAL: f64 = 1.0;

/// A robot collider of the articulated world.
#[derive(Clone, Debug)]
struct ColliderSpec {
    /// Body in tree order.
    body: usize,
    /// Body in model order (for the penalised-body bit set).
    model_body: usize,
    /// Pose in the body frame.
    local: Pose,
    shape: SharedShape,
    /// Bounding sphere: centre in the body frame, radius.
    sphere_center: [f64; 3],
    sphere_radius: f32,
    role: ColliderRole,
}

/// parry's persistent contact data of one (robot, collider) pair with the terrain.
#[derive(Default)]
struct PairCache {
    /// Each point carries its last impulses (normal, two friction), which parry hands over to
    /// the same feature pair in the next step: the solve's warm start.
    manifolds: Vec<ContactManifold<(), [f64; 3]>>,
    workspace: Option<ContactManifoldsWorkspace>,
}

/// Contact forces of one robot over its last physics step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct ContactSummary {
    foot_force: [f32; NUM_FEET],
    trunk_force: f32,
    head_force: f32,
    penalised_bodies: u32,
    penalised_contacts: u32,
    other_contacts: u32,
}

/// Robots integrated in reduced coordinates over one terrain shape.
pub struct ArticulatedWorld {
    tree: ArticulatedTree<f64>,
    ws: Workspace<f64>,
    nq: usize,
    nv: usize,
    count: usize,
    dt: f64,
    gravity: [f64; 3],
    soft: SoftConstraint,
    /// Generalised positions, `count x nq` (MuJoCo's free joint, see [`ArticulatedTree`]).
    qpos: Vec<f64>,
    /// Generalised velocities, `count x nv`.
    qvel: Vec<f64>,
    /// Per robot: trunk mass, centre of mass and inertia (payload and offset applied).
    trunk_mass: Vec<f64>,
    trunk_com: Vec<[f64; 3]>,
    trunk_inertia: Vec<[f64; 6]>,
    /// Per robot: armature on each joint, friction coefficient with the terrain.
    armature: Vec<f64>,
    friction: Vec<f64>,
    /// Per robot: base DoFs held still (test hook).
    locked: Vec<[bool; 6]>,
    /// Whether the joint stops act (always, but for the energy test).
    limits: bool,
    faulted: Vec<bool>,
    summary: Vec<ContactSummary>,
    /// DoF of each action-order joint.
    joint_dof: [usize; NUM_JOINTS],
    /// Tree body of each model body, and the reverse.
    tree_body: Vec<usize>,
    model_body: Vec<usize>,
    lower: [f64; NUM_JOINTS],
    upper: [f64; NUM_JOINTS],
    effort: [f32; NUM_JOINTS],
    colliders: Vec<ColliderSpec>,
    terrain: SharedShape,
    terrain_pose: Pose,
    /// The terrain's height queries, for skipping colliders well above it.
    ground: Terrain,
    /// Added to a collider's bounding radius in those queries (m): a heightfield's ramps reach
    /// one sample past the cells the query looks at.
    ground_margin: f32,
    /// Farthest any collider point can be from the base origin, whatever the joint angles (m).
    reach: f32,
    /// Per robot: the terrain's highest point within `reach + GROUND_CACHE_SLACK` of (x, y),
    /// as `[x, y, height]` (NaN: not yet asked). One height query per robot while it moves less
    /// than the slack, instead of one per collider and step.
    ground_cache: Vec<[f32; 3]>,
    /// `count x colliders.len()` contact caches.
    pairs: Vec<PairCache>,
    rows: Rows,
    /// Per contact point of the current robot's rows: (collider, manifold, point).
    sources: Vec<(u32, u32, u32)>,
    /// Per robot: last impulse of each joint stop (`2 NUM_JOINTS`), the warm start.
    limit_impulse: Vec<f64>,
    /// Scratch, `nv` each.
    force: Vec<f64>,
    /// Inverse pivots of the factor.
    pivots: Vec<f64>,
    velocity: Vec<f64>,
    /// Gauss-Seidel sweeps, summed over robot steps since creation.
    pub sweeps: u64,
    /// Time by stage, in the rapier world's terms: `torques_s` the dynamics up to the
    /// unconstrained velocity, `collision_detection_s` (= `narrow_phase_s`) parry's queries and
    /// the contact rows, `assembly_s` the rows' responses and targets, `resolution_s` the
    /// Gauss-Seidel sweeps (`solver_s` both), `update_s` the integration.
    counters: PhysicsCounters,
}

fn shape_of(shape: &Shape) -> SharedShape {
    match *shape {
        Shape::Box { size } => SharedShape::cuboid(size.x / 2.0, size.y / 2.0, size.z / 2.0),
        // Cylinders become capsules, as in the rapier world (legged_gym's
        // `replace_cylinder_with_capsule`).
        Shape::Cylinder { radius, length } => SharedShape::capsule_z(length / 2.0, radius),
        Shape::Sphere { radius } => SharedShape::ball(radius),
    }
}

fn widen3(v: Vec3) -> [f64; 3] {
    [f64::from(v.x), f64::from(v.y), f64::from(v.z)]
}

fn narrow3(v: [f64; 3]) -> Vec3 {
    Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32)
}

/// A rotation matrix (row-major) as a quaternion.
fn rotation_of(m: &[f64; 9]) -> Rotation {
    let cols = GMat3::from_cols(
        narrow3([m[0], m[3], m[6]]),
        narrow3([m[1], m[4], m[7]]),
        narrow3([m[2], m[5], m[8]]),
    );
    Rotation::from_mat3(&cols).normalize()
}

impl ArticulatedWorld {
    /// A world with `count` robots of `model` over `terrain` (its collider's shape and pose for
    /// contacts, its height queries to skip colliders far above it; friction comes from each
    /// robot's parameters). Robots start at the origin in the
    /// default pose, at rest.
    pub fn new(
        model: &RobotModel,
        count: usize,
        terrain: &Terrain,
        params: &PhysicsParams,
    ) -> Self {
        let collider = terrain.collider();
        // RobotModel::new has checked that the bodies form one tree from the trunk.
        let tree = ArticulatedTree::from_robot(model, 0.0)
            .expect("a robot model's bodies form a tree from the trunk");
        let ws = Workspace::new(&tree);
        let (nq, nv) = (tree.nq(), tree.nv());
        let n = model.bodies.len();
        let tree_body: Vec<usize> = model
            .bodies
            .iter()
            .map(|b| {
                tree.body_names()
                    .iter()
                    .position(|name| *name == b.name)
                    .unwrap_or(0)
            })
            .collect();
        let mut model_body = vec![0; n];
        for (m, &t) in tree_body.iter().enumerate() {
            model_body[t] = m;
        }
        let joint_dof = std::array::from_fn(|j| {
            let name = &model.joints[j].name;
            let k = tree
                .joint_names()
                .iter()
                .position(|n| n == name)
                .unwrap_or(j);
            tree.base_dofs() + k
        });
        let colliders = model
            .bodies
            .iter()
            .enumerate()
            .flat_map(|(b, body)| {
                let t = tree_body[b];
                body.colliders.iter().map(move |c| {
                    let shape = shape_of(&c.geometry.shape);
                    let sphere = shape.compute_local_bounding_sphere();
                    ColliderSpec {
                        body: t,
                        model_body: b,
                        local: c.geometry.origin,
                        sphere_center: widen3(c.geometry.origin.transform_point(sphere.center)),
                        sphere_radius: sphere.radius,
                        shape,
                        role: c.role,
                    }
                })
            })
            .collect::<Vec<_>>();
        let nominal = RobotPhysicalParams::nominal(model);
        let trunk = &model.bodies[0].inertial;
        let i = trunk.inertia;
        let mut world = Self {
            nq,
            nv,
            count,
            dt: f64::from(params.dt),
            gravity: [0.0, 0.0, -f64::from(params.gravity)],
            soft: {
                // MuJoCo clamps the time constant to at least two steps.
                let mut soft = SoftConstraint::default();
                soft.timeconst = soft.timeconst.max(2.0 * f64::from(params.dt));
                soft
            },
            qpos: vec![0.0; count * nq],
            qvel: vec![0.0; count * nv],
            trunk_mass: vec![f64::from(trunk.mass); count],
            trunk_com: vec![widen3(trunk.com); count],
            trunk_inertia: vec![
                [
                    i.col(0).x,
                    i.col(1).y,
                    i.col(2).z,
                    i.col(1).x,
                    i.col(2).x,
                    i.col(2).y,
                ]
                .map(f64::from);
                count
            ],
            armature: vec![f64::from(nominal.armature); count],
            friction: vec![f64::from(nominal.friction); count],
            locked: vec![[false; 6]; count],
            limits: true,
            faulted: vec![false; count],
            summary: vec![ContactSummary::default(); count],
            joint_dof,
            tree_body,
            model_body,
            lower: model.joints.each_ref().map(|j| f64::from(j.sim_lower)),
            upper: model.joints.each_ref().map(|j| f64::from(j.sim_upper)),
            effort: model.joints.each_ref().map(|j| j.effort),
            pairs: (0..count * colliders.len())
                .map(|_| PairCache::default())
                .collect(),
            colliders,
            terrain: collider.shape.clone(),
            terrain_pose: collider.position,
            ground: terrain.clone(),
            ground_margin: terrain.grid().map_or(0.0, |g| g.spec().horizontal_scale),
            reach: 0.0,
            ground_cache: vec![[f32::NAN; 3]; count],
            rows: Rows::new(nv, 3 * MAX_CONTACT_POINTS + NUM_JOINTS),
            sources: Vec::with_capacity(MAX_CONTACT_POINTS),
            limit_impulse: vec![0.0; count * 2 * NUM_JOINTS],
            force: vec![0.0; nv],
            pivots: vec![0.0; nv],
            velocity: vec![0.0; nv],
            tree,
            ws,
            sweeps: 0,
            counters: PhysicsCounters::default(),
        };
        world.reach = world.colliders_reach();
        let q0: [f32; NUM_JOINTS] = std::array::from_fn(|j| model.config.default_joint_pos[j]);
        for slot in 0..count {
            world.set_physical_params(model, slot, &nominal);
            world.set_robot_state(model, slot, Pose::IDENTITY, Vec3::ZERO, Vec3::ZERO, &q0);
        }
        world
    }

    /// Number of robots.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether the world holds no robot.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The shared tree (armature zero: each robot's armature is added per step).
    pub fn tree(&self) -> &ArticulatedTree<f64> {
        &self.tree
    }

    /// Robot `slot`'s generalised position and velocity.
    pub fn state(&self, slot: usize) -> (&[f64], &[f64]) {
        (
            &self.qpos[slot * self.nq..(slot + 1) * self.nq],
            &self.qvel[slot * self.nv..(slot + 1) * self.nv],
        )
    }

    /// Apply new physical parameters (payload, centre-of-mass shift, armature, friction) to
    /// robot `slot`. The actuator part is passed to [`ArticulatedWorld::step`].
    pub fn set_physical_params(
        &mut self,
        model: &RobotModel,
        slot: usize,
        params: &RobotPhysicalParams,
    ) {
        let trunk = &model.bodies[0].inertial;
        let mass = f64::from(trunk.mass);
        let payload = f64::from(params.payload);
        let scale = (mass + payload) / mass;
        let i = trunk.inertia;
        self.trunk_mass[slot] = mass + payload;
        self.trunk_com[slot] = widen3(trunk.com + params.com_offset);
        self.trunk_inertia[slot] = [
            i.col(0).x,
            i.col(1).y,
            i.col(2).z,
            i.col(1).x,
            i.col(2).x,
            i.col(2).y,
        ]
        .map(|x| f64::from(x) * scale);
        self.armature[slot] = f64::from(params.armature);
        self.friction[slot] = f64::from(params.friction);
    }

    /// Teleport robot `slot`: trunk pose, trunk velocities (world frame, at the trunk origin),
    /// joint angles; joint speeds are zero. Contacts are forgotten.
    pub fn set_robot_state(
        &mut self,
        _model: &RobotModel,
        slot: usize,
        base: Pose,
        linvel: Vec3,
        angvel: Vec3,
        q: &[f32; NUM_JOINTS],
    ) {
        let (nq, nv) = (self.nq, self.nv);
        let qpos = &mut self.qpos[slot * nq..(slot + 1) * nq];
        let r = base.rotation.normalize();
        qpos[..3].copy_from_slice(&widen3(base.translation));
        qpos[3..7].copy_from_slice(&[r.w, r.x, r.y, r.z].map(f64::from));
        for (j, &k) in self.joint_dof.iter().enumerate() {
            qpos[k + 1] = f64::from(q[j]);
        }
        let qvel = &mut self.qvel[slot * nv..(slot + 1) * nv];
        qvel.fill(0.0);
        qvel[..3].copy_from_slice(&widen3(linvel));
        qvel[3..6].copy_from_slice(&widen3(r.inverse() * angvel));
        self.faulted[slot] = false;
        self.summary[slot] = ContactSummary::default();
        self.ground_cache[slot] = [f32::NAN; 3];
        let nc = self.colliders.len();
        for pair in &mut self.pairs[slot * nc..(slot + 1) * nc] {
            pair.manifolds.clear();
            pair.workspace = None;
        }
        self.limit_impulse[slot * 2 * NUM_JOINTS..(slot + 1) * 2 * NUM_JOINTS].fill(0.0);
    }

    /// Add `delta` to the velocity of robot `slot`'s trunk (pushes); joint rates are kept, so
    /// every body gets the same change, as in the rapier world.
    pub fn add_base_velocity(&mut self, slot: usize, delta: Vec3) {
        let v = &mut self.qvel[slot * self.nv..slot * self.nv + 3];
        for (x, d) in v.iter_mut().zip(widen3(delta)) {
            *x += d;
        }
    }

    /// Hold `axes` of robot `slot`'s trunk still (test hook). Translations are the world axes,
    /// rotations the trunk's own axes (the free joint's DoFs).
    #[doc(hidden)]
    pub fn lock_trunk(&mut self, slot: usize, axes: LockedAxes) {
        let flags = [
            LockedAxes::TRANSLATION_LOCKED_X,
            LockedAxes::TRANSLATION_LOCKED_Y,
            LockedAxes::TRANSLATION_LOCKED_Z,
            LockedAxes::ROTATION_LOCKED_X,
            LockedAxes::ROTATION_LOCKED_Y,
            LockedAxes::ROTATION_LOCKED_Z,
        ];
        for (k, f) in flags.iter().enumerate() {
            self.locked[slot][k] = axes.contains(*f);
            if self.locked[slot][k] {
                self.qvel[slot * self.nv + k] = 0.0;
            }
        }
    }

    /// Switch the joint stops off or on (test hook: a free swing that must conserve energy).
    #[doc(hidden)]
    pub fn set_limits_enabled(&mut self, on: bool) {
        self.limits = on;
    }

    /// Set robot `slot`'s trunk velocity to `speed` m/s along x (test hook for the blow-up
    /// guard: NaN makes it non-finite, a huge finite speed a blow-up not yet overflowed).
    #[doc(hidden)]
    pub fn poison(&mut self, slot: usize, speed: f32) {
        self.qvel[slot * self.nv] = f64::from(speed);
    }

    /// Whether robot `slot` was found non-finite and frozen since its last reset.
    pub fn is_faulted(&self, slot: usize) -> bool {
        self.faulted[slot]
    }

    /// Kinematics, inertias and velocities of robot `slot` into the scratch workspace.
    fn kinematics(&mut self, slot: usize) {
        let mut ws = std::mem::replace(&mut self.ws, Workspace::empty());
        self.kinematics_into(slot, &mut ws);
        self.ws = ws;
    }

    /// Kinematics, inertias and velocities of robot `slot` into `ws`.
    pub fn kinematics_into(&self, slot: usize, ws: &mut Workspace<f64>) {
        let (nq, nv) = (self.nq, self.nv);
        self.tree.forward_kinematics(
            ws,
            &self.qpos[slot * nq..(slot + 1) * nq],
            &self.qvel[slot * nv..(slot + 1) * nv],
        );
        // The robot's own trunk (payload, centre-of-mass shift) replaces the shared one.
        let r = ws.rotation[0];
        let com = mat_vec(&r, &self.trunk_com[slot]);
        let ic = spatial::rotate_symmetric(&r, &self.trunk_inertia[slot]);
        ws.inertia[0] = spatial::inertia_at(self.trunk_mass[slot], &com, &ic);
    }

    /// An upper bound on the distance from the base origin to any point of any collider: the
    /// joint offsets up the tree, plus the collider's bounding sphere.
    fn colliders_reach(&self) -> f32 {
        self.colliders
            .iter()
            .map(|c| {
                let mut d = dot(&c.sphere_center, &c.sphere_center).sqrt();
                let mut b = c.body;
                while b != 0 {
                    let t = &self.tree.body_translation[b];
                    d += dot(t, t).sqrt();
                    b = self.tree.body_parent[b];
                }
                d as f32 + c.sphere_radius
            })
            .fold(0.0, f32::max)
    }

    /// Mass (kg) and world centre of mass of model body `b` of robot `slot`, as simulated.
    pub fn body_mass(&self, slot: usize, b: usize) -> (f32, Vec3) {
        let mut ws = Workspace::new(&self.tree);
        self.kinematics_into(slot, &mut ws);
        let i = &ws.inertia[self.tree_body[b]];
        let c = spatial::scale(1.0 / i[0].max(f64::MIN_POSITIVE), &[i[1], i[2], i[3]]);
        (i[0] as f32, narrow3(spatial::add(&ws.base_position, &c)))
    }

    /// Rotational inertia (kg m^2) of robot `slot` taken as rigid, about the world axis `axis`
    /// (unit) through its centre of mass. The armature is on the joints, so not in it.
    pub fn whole_body_inertia(&self, slot: usize, axis: Vec3) -> f32 {
        let mut ws = Workspace::new(&self.tree);
        self.kinematics_into(slot, &mut ws);
        let mut total = [0.0; 10];
        for i in &ws.inertia {
            spatial::inertia_add(&mut total, i);
        }
        // About the base origin; the parallel-axis theorem moves it to the centre of mass.
        let m = total[0];
        let c = spatial::scale(1.0 / m, &[total[1], total[2], total[3]]);
        let a = widen3(axis);
        let io = [
            [total[4], total[7], total[8]],
            [total[7], total[5], total[9]],
            [total[8], total[9], total[6]],
        ];
        let about_origin: f64 = (0..3)
            .map(|r| a[r] * (0..3).map(|k| io[r][k] * a[k]).sum::<f64>())
            .sum();
        let arm = cross(&a, &c);
        (about_origin - m * dot(&arm, &arm)) as f32
    }

    /// Mechanical energy of robot `slot` (J): `v^T M v / 2` (armature included) plus the
    /// potential energy in gravity (zero at z = 0).
    pub fn mechanical_energy(&mut self, slot: usize) -> f64 {
        self.kinematics(slot);
        self.tree.mass_matrix(&mut self.ws);
        self.add_armature(slot);
        let nv = self.nv;
        let v = &self.qvel[slot * nv..(slot + 1) * nv];
        self.tree.mul_mass_matrix(&self.ws, v, &mut self.force);
        let kinetic = 0.5 * dot_n(v, &self.force);
        let base = self.ws.base_position;
        let potential: f64 = self
            .ws
            .inertia
            .iter()
            .map(|i| {
                // h = m c with c relative to the base origin.
                let height = i[0] * base[2] + i[3];
                -self.gravity[2] * height
            })
            .sum();
        kinetic + potential
    }

    fn add_armature(&mut self, slot: usize) {
        let a = self.armature[slot];
        for k in self.tree.base_dofs()..self.nv {
            let diag = self.tree.row_start[k + 1] - 1;
            self.ws.mass_matrix[diag] += a;
        }
    }

    /// Decouple the locked base DoFs of robot `slot` in the mass matrix (unit diagonal, no
    /// coupling), so the solve gives the rest of the tree's dynamics with them held.
    fn apply_locks(&mut self, slot: usize) {
        let locked = self.locked[slot];
        if !locked.iter().any(|&l| l) {
            return;
        }
        for k in 0..self.nv {
            let (range, cols) = self.tree.row(k);
            for (e, &i) in range.zip(cols) {
                let (lk, li) = (k < 6 && locked[k], i < 6 && locked[i]);
                if lk || li {
                    self.ws.mass_matrix[e] = if i == k { LOCKED_DIAGONAL } else { 0.0 };
                }
            }
        }
    }

    /// One physics step of every robot towards `targets` (slot-major, NUM_JOINTS per robot).
    /// Writes the motor torques into `torques` (same layout).
    pub fn step(
        &mut self,
        _model: &RobotModel,
        targets: &[f32],
        actuators: &[ActuatorParams],
        torques: &mut [f32],
    ) {
        let t0 = Instant::now();
        for (slot, act) in actuators.iter().enumerate().take(self.count) {
            let i = slot * NUM_JOINTS;
            self.step_robot(
                slot,
                &targets[i..i + NUM_JOINTS],
                act,
                &mut torques[i..i + NUM_JOINTS],
            );
        }
        let c = &mut self.counters;
        c.world_steps += 1;
        c.robot_steps += self.count as u64;
        c.step_s += t0.elapsed().as_secs_f64();
    }

    /// Time by stage summed over this world's steps since it was built (see the field's docs).
    pub fn counters(&self) -> &PhysicsCounters {
        &self.counters
    }

    fn step_robot(
        &mut self,
        slot: usize,
        targets: &[f32],
        act: &ActuatorParams,
        torques: &mut [f32],
    ) {
        let (nq, nv, h) = (self.nq, self.nv, self.dt);
        let finite = self.qpos[slot * nq..(slot + 1) * nq]
            .iter()
            .chain(&self.qvel[slot * nv..(slot + 1) * nv])
            .all(|x| x.is_finite());
        let t0 = Instant::now();
        if self.faulted[slot] || !finite {
            // Frozen until the env layer resets it, like a body rapier quarantined.
            self.faulted[slot] = true;
            torques.fill(0.0);
            self.summary[slot] = ContactSummary::default();
            return;
        }
        self.kinematics(slot);
        self.tree.mass_matrix(&mut self.ws);
        self.add_armature(slot);
        self.apply_locks(slot);
        self.tree.bias_forces(&mut self.ws, &self.gravity);
        self.tree.factor(&mut self.ws);

        // Joint torques, then v_free = v + h M^-1 (tau - c).
        let qpos = &self.qpos[slot * nq..(slot + 1) * nq];
        let qvel = &self.qvel[slot * nv..(slot + 1) * nv];
        for (f, &c) in self.force.iter_mut().zip(self.ws.bias()) {
            *f = -c;
        }
        for (j, &k) in self.joint_dof.iter().enumerate() {
            let (q, qd) = (qpos[k + 1] as f32, qvel[k] as f32);
            let motor = pd_torque(targets[j], q, qd, act.kp, act.kd, self.effort[j]);
            torques[j] = motor;
            self.force[k] += f64::from(motor + passive_torque(qd, act.damping, act.friction));
        }
        let locked = self.locked[slot];
        for (k, f) in self.force.iter_mut().enumerate().take(6) {
            if locked[k] {
                *f = 0.0;
            }
        }
        self.tree.solve(&self.ws, &mut self.force);
        for ((v, &v0), &a) in self.velocity.iter_mut().zip(qvel).zip(&self.force) {
            *v = v0 + h * a;
        }

        let t1 = Instant::now();
        self.rows.clear();
        self.contact_rows(slot);
        let points = self.rows.len() / 3;
        self.limit_rows(slot);
        let t2 = Instant::now();
        let mut t3 = t2;
        let mut summary = ContactSummary::default();
        if !self.rows.is_empty() {
            // Y_i = L^-T J_i^T per row, then A = Y^T D^-1 Y, each row's regulariser and target.
            self.tree.pivots(&self.ws, &mut self.pivots);
            for d in &mut self.pivots {
                *d = 1.0 / *d;
            }
            for i in 0..self.rows.len() {
                let range = i * nv..(i + 1) * nv;
                let jac = &mut self.rows.jacobian[range.clone()];
                for (x, &l) in jac.iter_mut().zip(&locked) {
                    if l {
                        *x = 0.0;
                    }
                }
                let half = &mut self.rows.half[range];
                half.copy_from_slice(jac);
                half_solve(&self.tree, &self.ws, half);
            }
            let tree = &self.tree;
            self.rows.assemble(&self.pivots, |k| tree.row(k).1);
            self.finish_rows(slot);
            t3 = Instant::now();
            self.rows.warm_start(&self.velocity);
            self.sweeps += self.rows.solve(MAX_SWEEPS, SWEEP_TOLERANCE) as u64;
            // v+ = v_free + M^-1 J^T lambda.
            self.rows.generalised_impulse(&mut self.force);
            self.tree.solve(&self.ws, &mut self.force);
            for (v, dv) in self.velocity.iter_mut().zip(&self.force) {
                *v += dv;
            }
            self.summarise(&mut summary);
            self.store_impulses(slot);
        }
        let t4 = Instant::now();
        self.summary[slot] = summary;
        for (k, v) in self.velocity.iter_mut().enumerate().take(6) {
            if locked[k] {
                *v = 0.0;
            }
        }
        self.integrate(slot);
        let t5 = Instant::now();
        let c = &mut self.counters;
        let secs = |a: Instant, b: Instant| (b - a).as_secs_f64();
        c.torques_s += secs(t0, t1);
        c.collision_detection_s += secs(t1, t2);
        c.narrow_phase_s += secs(t1, t2);
        c.assembly_s += secs(t2, t3);
        c.resolution_s += secs(t3, t4);
        c.solver_s += secs(t2, t4);
        c.update_s += secs(t4, t5);
        c.contacts += points as u64;
        c.constraints += self.rows.len() as u64;
    }

    /// Contact rows of robot `slot` from parry's manifolds against the terrain.
    fn contact_rows(&mut self, slot: usize) {
        let nc = self.colliders.len();
        let base = self.ws.base_position;
        let mu = self.friction[slot];
        let dispatcher = DefaultQueryDispatcher;
        let mut points = 0;
        self.sources.clear();
        // The highest terrain anywhere the robot can reach: colliders above it need no query of
        // their own.
        let (bx, by) = (base[0] as f32, base[1] as f32);
        let cache = &mut self.ground_cache[slot];
        let stale = cache[2].is_nan() || (bx - cache[0]).hypot(by - cache[1]) > GROUND_CACHE_SLACK;
        if stale {
            let radius = self.reach + GROUND_CACHE_SLACK + self.ground_margin;
            *cache = [bx, by, self.ground.max_height_within(bx, by, radius)];
        }
        let robot_ground = cache[2];
        for c in 0..nc {
            let spec = &self.colliders[c];
            let b = spec.body;
            let pair = &mut self.pairs[slot * nc + c];
            // Far above the ground under it: no query, and no contact to remember. The
            // workspace goes with the manifolds: parry's mesh cache keeps one manifold per
            // triangle it found and must not outlive them. (Checked before any pose is built:
            // most colliders end here.)
            let body_position = self.ws.body_position(b);
            let centre = spatial::add(
                &body_position,
                &mat_vec(&self.ws.rotation[b], &spec.sphere_center),
            );
            let bottom = centre[2] as f32 - spec.sphere_radius - CONTACT_PREDICTION;
            let clear = bottom > robot_ground || {
                let reach = spec.sphere_radius + self.ground_margin;
                bottom
                    > self
                        .ground
                        .max_height_within(centre[0] as f32, centre[1] as f32, reach)
            };
            if clear {
                if !pair.manifolds.is_empty() || pair.workspace.is_some() {
                    pair.manifolds.clear();
                    pair.workspace = None;
                }
                continue;
            }
            let dof = body_dof(&self.tree, b);
            let body_pose =
                Pose::from_parts(narrow3(body_position), rotation_of(&self.ws.rotation[b]));
            let pose = body_pose * spec.local;
            let pos12 = pose.inverse() * self.terrain_pose;
            if dispatcher
                .contact_manifolds(
                    &pos12,
                    &*spec.shape,
                    &*self.terrain,
                    CONTACT_PREDICTION,
                    &mut pair.manifolds,
                    &mut pair.workspace,
                )
                .is_err()
            {
                continue;
            }
            let mut kept = 0;
            for (m, manifold) in pair.manifolds.iter().enumerate() {
                let normal = -(pose.rotation * manifold.local_n1);
                let n = widen3(normal);
                let (t1, t2) = tangents(&n);
                for (pi, point) in manifold.points.iter().enumerate() {
                    if point.dist >= CONTACT_PREDICTION
                        || kept >= MAX_POINTS_PER_COLLIDER
                        || points >= MAX_CONTACT_POINTS
                        || self.rows.room() < 3
                    {
                        continue;
                    }
                    kept += 1;
                    points += 1;
                    let p = widen3(pose.transform_point(point.local_p1));
                    let rel = [p[0] - base[0], p[1] - base[1], p[2] - base[2]];
                    let dist = f64::from(point.dist);
                    let tag = c as u32;
                    let (ni, jac) = self.rows.push(RowKind::Unilateral, tag, dof);
                    point_jacobian(&self.tree, &self.ws, b, &rel, &n, jac);
                    // The distance rides in the target until `finish_rows` (it is needed with
                    // the row's velocity).
                    self.rows.target[ni] = dist;
                    self.rows.impulse[ni] = point.data[0];
                    for (e, t) in [t1, t2].into_iter().enumerate() {
                        let (ti, jac) =
                            self.rows
                                .push(RowKind::Friction { normal: ni, mu }, tag, dof);
                        point_jacobian(&self.tree, &self.ws, b, &rel, &t, jac);
                        self.rows.target[ti] = dist;
                        self.rows.impulse[ti] = point.data[1 + e];
                    }
                    self.sources.push((c as u32, m as u32, pi as u32));
                }
            }
        }
    }

    /// One row per joint at or heading into a stop: `J = +e_k` at the lower stop (distance
    /// `q - lower`), `-e_k` at the upper one.
    fn limit_rows(&mut self, slot: usize) {
        let (nq, nv, h) = (self.nq, self.nv, self.dt);
        if !self.limits {
            return;
        }
        for j in 0..NUM_JOINTS {
            let k = self.joint_dof[j];
            let q = self.qpos[slot * nq + k + 1];
            let qd = self.qvel[slot * nv + k];
            for (side, (sign, dist)) in [(1.0, q - self.lower[j]), (-1.0, self.upper[j] - q)]
                .into_iter()
                .enumerate()
            {
                let closing = (-sign * qd * h).max(0.0);
                if dist < LIMIT_PREDICTION + closing && self.rows.room() > 0 {
                    let tag = LIMIT_TAG + (2 * j + side) as u32;
                    let (i, jac) = self.rows.push(RowKind::Unilateral, tag, k);
                    jac[k] = sign;
                    self.rows.target[i] = dist;
                    self.rows.impulse[i] = self.limit_impulse[slot * 2 * NUM_JOINTS + 2 * j + side];
                }
            }
        }
    }

    /// Regularisers and targets of the rows: `target` holds each row's signed distance on
    /// entry (its contact's, for a friction row).
    fn finish_rows(&mut self, slot: usize) {
        let nv = self.nv;
        let h = self.dt;
        let (b, k) = self.soft.reference_gains();
        let qvel = &self.qvel[slot * nv..(slot + 1) * nv];
        for i in 0..self.rows.len() {
            let jac = &self.rows.jacobian[i * nv..(i + 1) * nv];
            let dist = self.rows.target[i];
            let vel = dot_n(jac, qvel);
            let friction = matches!(self.rows.kind[i], RowKind::Friction { .. });
            if dist > 0.0 {
                // Apart: speculative and hard. Friction only acts through its normal row.
                let target = if friction { 0.0 } else { -dist / h };
                self.rows.finish(i, None, 1.0, target);
            } else {
                let d = self.soft.impedance(-dist);
                let (a_ref, ratio) = if friction {
                    (-b * vel, self.soft.impratio)
                } else {
                    (-b * vel - k * d * dist, 1.0)
                };
                self.rows.finish(i, Some(d), ratio, vel + h * a_ref);
            }
        }
    }

    /// Keep the solved impulses for the next step's warm start: on parry's contact points
    /// (rows come in threes, normal first, in `sources` order) and per joint stop.
    fn store_impulses(&mut self, slot: usize) {
        let nc = self.colliders.len();
        for (n, &(c, m, p)) in self.sources.iter().enumerate() {
            let pair = &mut self.pairs[slot * nc + c as usize];
            let point = &mut pair.manifolds[m as usize].points[p as usize];
            point.data = std::array::from_fn(|e| self.rows.impulse[3 * n + e]);
        }
        let stops = &mut self.limit_impulse[slot * 2 * NUM_JOINTS..(slot + 1) * 2 * NUM_JOINTS];
        stops.fill(0.0);
        for i in 3 * self.sources.len()..self.rows.len() {
            if let Some(k) = self.rows.tag(i).checked_sub(LIMIT_TAG) {
                stops[k as usize] = self.rows.impulse[i];
            }
        }
    }

    /// Contact forces of the solved rows into `out`.
    fn summarise(&self, out: &mut ContactSummary) {
        let h = self.dt;
        let mut other = 0u64;
        for i in 0..self.rows.len() {
            if self.rows.kind[i] != RowKind::Unilateral || self.rows.tag(i) >= LIMIT_TAG {
                continue;
            }
            let c = self.rows.tag(i) as usize;
            let spec = &self.colliders[c];
            let force = (self.rows.impulse(i) / h) as f32;
            let touching = self.rows.target[i] <= 0.0 || force > 0.0;
            match spec.role {
                ColliderRole::Trunk => out.trunk_force += force,
                ColliderRole::Head => out.head_force += force,
                ColliderRole::Foot(f) => out.foot_force[f as usize] += force,
                ColliderRole::Penalised => {
                    let bit = 1 << spec.model_body;
                    if force > CONTACT_FORCE_THRESHOLD && out.penalised_bodies & bit == 0 {
                        out.penalised_bodies |= bit;
                        out.penalised_contacts += 1;
                    }
                }
                ColliderRole::Other => {
                    // Counted once per collider in contact, as the rapier world counts pairs.
                    if touching && other & (1 << c) == 0 {
                        other |= 1 << c;
                        out.other_contacts += 1;
                    }
                }
            }
        }
    }

    /// `q <- q (+) h v+` with `v+` in `self.velocity`; a non-finite result freezes the robot.
    fn integrate(&mut self, slot: usize) {
        let (nq, nv, h) = (self.nq, self.nv, self.dt);
        let qpos = &mut self.qpos[slot * nq..(slot + 1) * nq];
        let qvel = &mut self.qvel[slot * nv..(slot + 1) * nv];
        qvel.copy_from_slice(&self.velocity);
        for k in 0..3 {
            qpos[k] += h * qvel[k];
        }
        // q <- q * exp(h w / 2), w in the base's own axes.
        let w = [qvel[3], qvel[4], qvel[5]];
        let angle = h * dot(&w, &w).sqrt();
        let (s, c) = (0.5 * angle).sin_cos();
        let e = if angle > 1e-12 {
            let f = s / (angle / h);
            [c, w[0] * f, w[1] * f, w[2] * f]
        } else {
            [1.0, 0.5 * h * w[0], 0.5 * h * w[1], 0.5 * h * w[2]]
        };
        let q = [qpos[3], qpos[4], qpos[5], qpos[6]];
        let mut out = [
            q[0] * e[0] - q[1] * e[1] - q[2] * e[2] - q[3] * e[3],
            q[0] * e[1] + q[1] * e[0] + q[2] * e[3] - q[3] * e[2],
            q[0] * e[2] - q[1] * e[3] + q[2] * e[0] + q[3] * e[1],
            q[0] * e[3] + q[1] * e[2] - q[2] * e[1] + q[3] * e[0],
        ];
        let norm = out.iter().map(|x| x * x).sum::<f64>().sqrt();
        for x in &mut out {
            *x /= norm;
        }
        qpos[3..7].copy_from_slice(&out);
        for k in 6..nv {
            qpos[k + 1] += h * qvel[k];
        }
        if !qpos.iter().chain(qvel.iter()).all(|x| x.is_finite()) {
            self.faulted[slot] = true;
        }
    }

    /// Read the pose, velocities, joints and feet of robot `slot` into `s` (contacts untouched).
    pub fn read_kinematics(&mut self, model: &RobotModel, slot: usize, s: &mut RobotState) {
        self.kinematics(slot);
        let (nq, nv) = (self.nq, self.nv);
        let qpos = &self.qpos[slot * nq..(slot + 1) * nq];
        let qvel = &self.qvel[slot * nv..(slot + 1) * nv];
        let rot = Rotation::from_xyzw(
            qpos[4] as f32,
            qpos[5] as f32,
            qpos[6] as f32,
            qpos[3] as f32,
        );
        s.base_pos = narrow3([qpos[0], qpos[1], qpos[2]]);
        s.base_rot = rot;
        s.base_linvel = narrow3([qvel[0], qvel[1], qvel[2]]);
        s.base_angvel = narrow3(mat_vec(&self.ws.rotation[0], &[qvel[3], qvel[4], qvel[5]]));
        for (j, &k) in self.joint_dof.iter().enumerate() {
            s.q[j] = qpos[k + 1] as f32;
            s.qd[j] = qvel[k] as f32;
        }
        s.max_joint_gap = 0.0;
        s.extra_iterations = false;
        s.faulted = self.faulted[slot];
        for (f, foot) in model.feet.iter().enumerate() {
            let b = self.tree_body[foot.body];
            let r = self.ws.rotation[b];
            let p = spatial::add(
                &self.ws.body_position(b),
                &mat_vec(&r, &widen3(foot.offset)),
            );
            let (w, v_origin) = self.ws.body_velocity(b);
            let arm = [
                p[0] - self.ws.body_position(b)[0],
                p[1] - self.ws.body_position(b)[1],
                p[2] - self.ws.body_position(b)[2],
            ];
            s.foot_pos[f] = narrow3(p);
            s.foot_vel[f] = narrow3(spatial::add(&v_origin, &cross(&w, &arm)));
        }
    }

    /// Read every robot's state into `out` (one entry per slot), with the contact forces of the
    /// last physics step.
    pub fn read_states(&mut self, model: &RobotModel, out: &mut [RobotState]) {
        let t0 = Instant::now();
        for (slot, s) in out.iter_mut().enumerate().take(self.count) {
            self.read_kinematics(model, slot, s);
            s.clear_contacts();
            let c = &self.summary[slot];
            s.foot_force = c.foot_force;
            s.trunk_force = c.trunk_force;
            s.head_force = c.head_force;
            s.penalised_bodies = c.penalised_bodies;
            s.penalised_contacts = c.penalised_contacts;
            s.other_contacts = c.other_contacts;
            s.faulted = self.faulted[slot];
        }
        self.counters.read_back_s += t0.elapsed().as_secs_f64();
    }

    /// World poses of all bodies of robot `slot`, model order (trunk first).
    pub fn body_poses(&mut self, slot: usize) -> Vec<Pose> {
        self.kinematics(slot);
        self.tree_body
            .iter()
            .map(|&b| self.pose_in(&self.ws, b))
            .collect()
    }

    /// Pose of tree body `b` in the kinematics of `ws`.
    pub fn pose_in(&self, ws: &Workspace<f64>, b: usize) -> Pose {
        Pose::from_parts(narrow3(ws.body_position(b)), rotation_of(&ws.rotation[b]))
    }

    /// Tree body of model body `b` (and back with [`Self::model_body_of`]).
    pub fn tree_body_of(&self, b: usize) -> usize {
        self.tree_body[b]
    }

    /// Model body of tree body `b`.
    pub fn model_body_of(&self, b: usize) -> usize {
        self.model_body[b]
    }
}

/// `sum a_i b_i`.
#[inline]
fn dot_n(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `x <- L^-T x` with the factor `M = L^T D L` in `ws` (the first of the solve's three walks):
/// for a Jacobian row, nonzero only on a body's ancestor DoFs, the result keeps that sparsity.
fn half_solve(tree: &ArticulatedTree<f64>, ws: &Workspace<f64>, x: &mut [f64]) {
    for k in (0..tree.nv()).rev() {
        let xk = x[k];
        if xk == 0.0 {
            continue;
        }
        let (start, diag) = (tree.row_start[k], tree.row_start[k + 1] - 1);
        for e in start..diag {
            x[tree.row_dofs[e]] -= ws.factor[e] * xk;
        }
    }
}

/// Two unit tangents completing the unit normal `n` to an orthonormal basis.
fn tangents(n: &[f64; 3]) -> ([f64; 3], [f64; 3]) {
    // Duff et al., "Building an orthonormal basis, revisited" (2017).
    let sign = if n[2] >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    (
        [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]],
        [b, sign + n[1] * n[1] * a, -n[1]],
    )
}

/// The DoF that moves body `body` last: its joint, or the base's last DoF for the root
/// ([`NO_PARENT`] for a fixed root).
fn body_dof(tree: &ArticulatedTree<f64>, body: usize) -> usize {
    if body == 0 {
        tree.base_dofs().checked_sub(1).unwrap_or(NO_PARENT)
    } else {
        tree.base_dofs() + body - 1
    }
}

/// Jacobian row of the velocity along `dir` of the point of body `body` at `rel` (relative to
/// the base origin, world axes): over the body's ancestor DoFs, `dir . (S_lin + S_ang x rel)`.
fn point_jacobian(
    tree: &ArticulatedTree<f64>,
    ws: &Workspace<f64>,
    body: usize,
    rel: &[f64; 3],
    dir: &[f64; 3],
    out: &mut [f64],
) {
    let arm = cross(rel, dir);
    let mut k = body_dof(tree, body);
    while k != NO_PARENT {
        let s = &ws.motion[k];
        out[k] = dir[0] * s[3]
            + dir[1] * s[4]
            + dir[2] * s[5]
            + arm[0] * s[0]
            + arm[1] * s[1]
            + arm[2] * s[2];
        k = tree.dof_parent[k];
    }
}
