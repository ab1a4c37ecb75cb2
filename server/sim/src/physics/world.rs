//! A rapier world holding a fixed group of robots over one shared terrain collider.
//!
//! Many robots share one world (1.5-1.8x cheaper per robot than a world each, measured): collision
//! groups let robots touch only the terrain, never each other or themselves. Joints are impulse
//! (maximal-coordinate) joints driven by explicit PD torques: rapier's multibody joints ran at
//! 0.42x of their speed even with one substep (docs/src/decisions/0001-impulse-joints.md).
//! Their anchors drift a little under load, which [`RobotWorld::max_joint_gap`] reports.

use std::time::Instant;

use rapier3d::prelude::*;

use crate::robot::{ColliderRole, NUM_JOINTS, RobotModel, Shape};

use super::actuation::{ActuatorParams, passive_torque, pd_torque};
use super::counters::PhysicsCounters;
use super::inertia::mass_properties;
use super::joint_state::{joint_angle, joint_speed};
use super::params::PhysicsParams;
use super::robot_state::RobotState;

/// Collider `user_data` of the terrain.
const TERRAIN_TAG: u128 = u128::MAX;
const ROBOTS: Group = Group::GROUP_1;
const TERRAIN: Group = Group::GROUP_2;

/// Encodes which robot slot and which collider role a robot collider has.
fn robot_tag(slot: usize, body: usize, role: ColliderRole) -> u128 {
    let role_code: u128 = match role {
        ColliderRole::Trunk => 0,
        ColliderRole::Penalised => 1,
        ColliderRole::Other => 2,
        ColliderRole::Head => 3,
        ColliderRole::Foot(f) => 8 + f as u128,
    };
    ((slot as u128) << 32) | ((body as u128) << 8) | role_code
}

/// Rapier handles of one robot.
#[derive(Clone, Debug)]
struct RobotHandles {
    bodies: Vec<RigidBodyHandle>,
}

/// Per-robot physical parameters that domain randomisation may change.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotPhysicalParams {
    /// Actuator parameters.
    pub actuator: ActuatorParams,
    /// Rotor inertia reflected on each joint coordinate (kg m^2).
    pub armature: f32,
    /// Extra mass on the trunk (kg).
    pub payload: f32,
    /// Shift of the trunk's centre of mass (m).
    pub com_offset: Vec3,

    /// Friction coefficient between the robot and the terrain.
    pub friction: f32,
}

impl RobotPhysicalParams {
    /// The nominal values of `model`'s config.
    pub fn nominal(model: &RobotModel) -> Self {
        let c = &model.config;
        Self {
            actuator: ActuatorParams {
                kp: c.kp,
                kd: c.kd,
                damping: c.joint_damping,
                friction: c.joint_friction,
            },
            armature: c.armature,
            payload: 0.0,
            com_offset: Vec3::ZERO,
            friction: 1.0,
        }
    }
}

/// One rapier world with `len()` robots.
pub struct RobotWorld {
    pipeline: PhysicsPipeline,
    integration: IntegrationParameters,
    islands: IslandManager,
    broad_phase: BroadPhaseBvh,
    narrow_phase: NarrowPhase,
    bodies: RigidBodySet,
    colliders: ColliderSet,
    impulse_joints: ImpulseJointSet,
    multibody_joints: MultibodyJointSet,
    soft_bodies: SoftBodySet,
    ccd: CCDSolver,
    gravity: Vec3,
    min_link_inertia: f32,
    extra_on_leg_contact: usize,
    extra_pgs_on_leg_contact: usize,
    extra_on_head_contact: bool,
    robots: Vec<RobotHandles>,
    /// Robots currently given extra solver iterations.
    extra_iterations: Vec<bool>,
    /// Robots with a joint at (or about to hit) a stop, as of the last read-back.
    near_stop: Vec<bool>,
    /// Robots whose hips, thighs, calves or head touched the terrain in the last physics step.
    leg_contact: Vec<bool>,
    /// Robots with a body rapier quarantined (non-finite state) since their last reset.
    faulted: Vec<bool>,
    /// Scratch: world poses and velocities of one robot's bodies.
    scratch_rot: Vec<Rotation>,
    scratch_angvel: Vec<Vec3>,
    /// Time by stage, summed over steps (the benchmark's breakdown).
    counters: PhysicsCounters,
}

impl RobotWorld {
    /// A world with `count` robots of `model` over the terrain `terrain` (a collider builder for
    /// a fixed body: a half-space, heightfield or mesh). Robots start at the origin in the default
    /// pose; place them with [`RobotWorld::set_robot_state`].
    pub fn new(
        model: &RobotModel,
        count: usize,
        terrain: ColliderBuilder,
        params: &PhysicsParams,
    ) -> Self {
        let mut integration = IntegrationParameters {
            dt: params.dt,
            ..Default::default()
        };
        integration.num_solver_iterations = params.solver_iterations;
        integration.num_internal_pgs_iterations = params.pgs_iterations;
        let mut world = Self {
            pipeline: PhysicsPipeline::new(),
            integration,
            islands: IslandManager::new(),
            broad_phase: BroadPhaseBvh::new(),
            narrow_phase: NarrowPhase::new(),
            bodies: RigidBodySet::new(),
            colliders: ColliderSet::new(),
            impulse_joints: ImpulseJointSet::new(),
            multibody_joints: MultibodyJointSet::new(),
            soft_bodies: SoftBodySet::default(),
            ccd: CCDSolver::new(),
            gravity: Vec3::new(0.0, 0.0, -params.gravity),
            min_link_inertia: params.min_link_inertia,
            extra_on_leg_contact: params.extra_iterations_on_leg_contact,
            extra_pgs_on_leg_contact: params.extra_pgs_iterations_on_leg_contact,
            extra_on_head_contact: params.extra_iterations_on_head_contact,
            extra_iterations: vec![false; count],
            near_stop: vec![false; count],
            leg_contact: vec![false; count],
            faulted: vec![false; count],
            robots: Vec::with_capacity(count),
            scratch_rot: vec![Rotation::IDENTITY; model.bodies.len()],
            scratch_angvel: vec![Vec3::ZERO; model.bodies.len()],
            counters: PhysicsCounters::default(),
        };
        world.colliders.insert(
            terrain
                .friction(1.0)
                .restitution(0.0)
                .user_data(TERRAIN_TAG)
                .collision_groups(InteractionGroups::new(
                    TERRAIN,
                    ROBOTS,
                    InteractionTestMode::And,
                )),
        );
        let nominal = RobotPhysicalParams::nominal(model);
        for slot in 0..count {
            world.add_robot(model, slot, &nominal);
        }
        world
    }

    /// Number of robots.
    pub fn len(&self) -> usize {
        self.robots.len()
    }

    /// Whether the world holds no robot.
    pub fn is_empty(&self) -> bool {
        self.robots.is_empty()
    }

    fn add_robot(&mut self, model: &RobotModel, slot: usize, params: &RobotPhysicalParams) {
        let q0: [f32; NUM_JOINTS] = std::array::from_fn(|j| model.config.default_joint_pos[j]);
        let poses = model.forward_kinematics(&q0);
        let mut handles = Vec::with_capacity(model.bodies.len());
        for (b, body) in model.bodies.iter().enumerate() {
            let rb = RigidBodyBuilder::dynamic()
                .pose(poses[b])
                .user_data(slot as u128)
                .can_sleep(false)
                .additional_mass_properties(body_mass_properties(
                    model,
                    b,
                    params,
                    self.min_link_inertia,
                ))
                .build();
            let h = self.bodies.insert(rb);
            for c in &body.colliders {
                let shape = match c.geometry.shape {
                    Shape::Box { size } => {
                        SharedShape::cuboid(size.x / 2.0, size.y / 2.0, size.z / 2.0)
                    }
                    // Cylinders become capsules, as in legged_gym (`replace_cylinder_with_capsule`):
                    // cheaper and smoother contacts.
                    Shape::Cylinder { radius, length } => {
                        SharedShape::capsule_z(length / 2.0, radius)
                    }
                    Shape::Sphere { radius } => SharedShape::ball(radius),
                };
                let collider = ColliderBuilder::new(shape)
                    .position(c.geometry.origin)
                    .density(0.0)
                    .friction(params.friction)
                    .friction_combine_rule(CoefficientCombineRule::Multiply)
                    .restitution(0.0)
                    .user_data(robot_tag(slot, b, c.role))
                    .collision_groups(InteractionGroups::new(
                        ROBOTS,
                        TERRAIN,
                        InteractionTestMode::And,
                    ));
                self.colliders
                    .insert_with_parent(collider, h, &mut self.bodies);
            }
            // Mass properties now rather than at the first step: a reset reads the centre of
            // mass, and so do the inertia queries.
            self.bodies[h].recompute_mass_properties_from_colliders(&self.colliders);
            handles.push(h);
        }
        for joint in &model.joints {
            let j = RevoluteJointBuilder::new(joint.axis)
                .local_anchor1(joint.origin.translation)
                .local_anchor2(Vec3::ZERO)
                .limits([joint.sim_lower, joint.sim_upper])
                .contacts_enabled(false)
                .build();
            self.impulse_joints.insert(
                handles[joint.parent_body],
                handles[joint.child_body],
                j,
                true,
            );
        }
        self.robots.push(RobotHandles { bodies: handles });
    }

    /// Apply new physical parameters (mass, armature, friction) to robot `slot`.
    pub fn set_physical_params(
        &mut self,
        model: &RobotModel,
        slot: usize,
        params: &RobotPhysicalParams,
    ) {
        for (b, &h) in self.robots[slot].bodies.iter().enumerate() {
            let Some(rb) = self.bodies.get_mut(h) else {
                continue;
            };
            rb.set_additional_mass_properties(
                body_mass_properties(model, b, params, self.min_link_inertia),
                true,
            );
            rb.recompute_mass_properties_from_colliders(&self.colliders);
            for &ch in rb.colliders() {
                if let Some(c) = self.colliders.get_mut(ch) {
                    c.set_friction(params.friction);
                }
            }
        }
    }

    /// Teleport robot `slot`: trunk pose, trunk velocities (world frame, at the trunk origin),
    /// joint angles; joint speeds are zero. Forces are cleared.
    pub fn set_robot_state(
        &mut self,
        model: &RobotModel,
        slot: usize,
        base: Pose,
        linvel: Vec3,
        angvel: Vec3,
        q: &[f32; NUM_JOINTS],
    ) {
        let local = model.forward_kinematics(q);
        self.faulted[slot] = false;
        for (b, &h) in self.robots[slot].bodies.iter().enumerate() {
            let Some(rb) = self.bodies.get_mut(h) else {
                continue;
            };
            rb.set_enabled(true);
            let pose = base * local[b];
            rb.set_position(pose, true);
            let com = pose.transform_point(rb.mass_properties().local_mprops.local_com);
            rb.set_linvel(linvel + angvel.cross(com - base.translation), true);
            rb.set_angvel(angvel, true);
            rb.reset_forces(false);
            rb.reset_torques(false);
        }
    }

    /// Drive every robot's joints towards `targets` (slot-major, NUM_JOINTS per robot) for one
    /// physics step. Writes the motor torques into `torques` (same layout).
    pub fn step(
        &mut self,
        model: &RobotModel,
        targets: &[f32],
        actuators: &[ActuatorParams],
        torques: &mut [f32],
    ) {
        let t0 = Instant::now();
        for (slot, robot) in self.robots.iter().enumerate() {
            for (b, &h) in robot.bodies.iter().enumerate() {
                let rb = &mut self.bodies[h];
                rb.reset_torques(false);
                self.scratch_rot[b] = *rb.rotation();
                self.scratch_angvel[b] = rb.angvel();
            }
            let act = &actuators[slot];
            for (j, joint) in model.joints.iter().enumerate() {
                let (p, c) = (joint.parent_body, joint.child_body);
                let q = joint_angle(self.scratch_rot[p], self.scratch_rot[c], joint.axis);
                let qd = joint_speed(
                    self.scratch_rot[c],
                    self.scratch_angvel[p],
                    self.scratch_angvel[c],
                    joint.axis,
                );
                let i = slot * NUM_JOINTS + j;
                let motor = pd_torque(targets[i], q, qd, act.kp, act.kd, joint.effort);
                torques[i] = motor;
                let tau = motor
                    + passive_torque(qd, act.damping, act.friction)
                    + limit_torque(q, qd, joint.sim_lower, joint.sim_upper);
                let axis = self.scratch_rot[c] * joint.axis * tau;
                self.bodies[robot.bodies[c]].add_torque(axis, false);
                self.bodies[robot.bodies[p]].add_torque(-axis, false);
            }
        }
        let t1 = Instant::now();
        self.pipeline.step(
            self.gravity,
            &self.integration,
            &mut self.islands,
            &mut self.broad_phase,
            &mut self.narrow_phase,
            &mut self.bodies,
            &mut self.colliders,
            &mut self.impulse_joints,
            &mut self.multibody_joints,
            &mut self.soft_bodies,
            &mut self.ccd,
            &(),
            &(),
        );
        let t2 = Instant::now();
        // Rapier disables bodies whose state turned non-finite; the env layer resets the robot.
        for &h in self.pipeline.quarantine().bodies() {
            if let Some(f) = self
                .bodies
                .get(h)
                .and_then(|b| self.faulted.get_mut(b.user_data as usize))
            {
                *f = true;
            }
        }
        self.update_leg_contact();
        for slot in 0..self.robots.len() {
            self.update_extra_iterations(slot);
        }
        let t3 = Instant::now();
        let c = &mut self.counters;
        c.add_rapier(&self.pipeline.counters);
        c.world_steps += 1;
        c.robot_steps += self.robots.len() as u64;
        c.torques_s += (t1 - t0).as_secs_f64();
        c.after_s += (t3 - t2).as_secs_f64();
        c.step_s += (t3 - t0).as_secs_f64();
    }

    /// Time by stage summed over this world's steps since it was built.
    pub fn counters(&self) -> &PhysicsCounters {
        &self.counters
    }

    /// Remove every robot's joints, leaving 13 free bodies a robot (benchmark hook: the cost
    /// of rapier's pipeline without the joint solver; the robots fall apart).
    #[doc(hidden)]
    pub fn remove_joints(&mut self) {
        let joints: Vec<_> = self.impulse_joints.iter().map(|(h, _)| h).collect();
        for h in joints {
            self.impulse_joints.remove(h, true);
        }
    }

    /// The robot's collider of a contact pair with the terrain, with its contact force (N) over
    /// the last physics step: (slot, body index, role code of [`robot_tag`]).
    fn robot_contact(&self, pair: &ContactPair) -> Option<(usize, u32, u128, f32)> {
        if !pair.has_any_active_contact() {
            return None;
        }
        let c1 = self.colliders.get(pair.collider1)?;
        let c2 = self.colliders.get(pair.collider2)?;
        let tag = if c1.user_data == TERRAIN_TAG {
            c2.user_data
        } else {
            c1.user_data
        };
        if tag == TERRAIN_TAG {
            return None;
        }
        let force = pair.total_impulse_magnitude() / self.integration.dt;
        Some((
            (tag >> 32) as usize,
            ((tag >> 8) & 0xff_ffff) as u32,
            tag & 0xff,
            force,
        ))
    }

    /// Which robots lie on hips, thighs, calves or (if configured) the head, after every physics
    /// step rather than once per policy step: a hip that first touches the ground within a
    /// policy step otherwise takes the impact without extra iterations, which is where the
    /// worst joint gaps came from (5.5-6.7 mm at 4096 envs and on the curriculum terrain, every
    /// one a hip's first touch; under 5 mm since).
    fn update_leg_contact(&mut self) {
        self.leg_contact.fill(false);
        for pair in self.narrow_phase.contact_pairs() {
            let Some((slot, _, role, force)) = self.robot_contact(pair) else {
                continue;
            };
            let touching = match role {
                1 => force > CONTACT_FORCE_THRESHOLD,
                2 => true,
                3 => self.extra_on_head_contact && force > CONTACT_FORCE_THRESHOLD,
                _ => false,
            };
            if touching && let Some(flag) = self.leg_contact.get_mut(slot) {
                *flag = true;
            }
        }
    }

    /// Whether robot `slot` gets the extra solver iterations in its next physics step.
    pub fn has_extra_iterations(&self, slot: usize) -> bool {
        self.extra_iterations[slot]
    }

    /// Give robot `slot` the extra solver iterations if it lies on legs or head or has a joint
    /// near a stop, or take them back.
    fn update_extra_iterations(&mut self, slot: usize) {
        let hard = self.leg_contact[slot] || self.near_stop[slot];
        if self.extra_iterations[slot] == hard {
            return;
        }
        self.extra_iterations[slot] = hard;
        let (substeps, pgs) = if hard {
            (self.extra_on_leg_contact, self.extra_pgs_on_leg_contact)
        } else {
            (0, 0)
        };
        // Rapier gives a group of jointed bodies the maximum of their extra iterations; the
        // trunk carries the robot's, and robots sharing a value are solved together.
        let trunk = &mut self.bodies[self.robots[slot].bodies[0]];
        trunk.set_additional_solver_iterations(substeps);
        trunk.set_additional_pgs_iterations(pgs);
    }

    /// Read the pose, velocities, joints and feet of robot `slot` into `s` (contacts untouched).
    pub fn read_kinematics(&self, model: &RobotModel, slot: usize, s: &mut RobotState) {
        let robot = &self.robots[slot];
        let trunk = &self.bodies[robot.bodies[0]];
        let base = *trunk.position();
        s.base_pos = base.translation;
        s.base_rot = base.rotation;
        s.base_linvel = trunk.velocity_at_point(base.translation);
        s.base_angvel = trunk.angvel();
        let mut gap: f32 = 0.0;
        for (j, joint) in model.joints.iter().enumerate() {
            let pb = &self.bodies[robot.bodies[joint.parent_body]];
            let cb = &self.bodies[robot.bodies[joint.child_body]];
            s.q[j] = joint_angle(*pb.rotation(), *cb.rotation(), joint.axis);
            s.qd[j] = joint_speed(*cb.rotation(), pb.angvel(), cb.angvel(), joint.axis);
            let anchor = pb.position().transform_point(joint.origin.translation);
            gap = gap.max(anchor.distance(cb.translation()));
        }
        s.max_joint_gap = gap;
        for (f, foot) in model.feet.iter().enumerate() {
            let b = &self.bodies[robot.bodies[foot.body]];
            let p = b.position().transform_point(foot.offset);
            s.foot_pos[f] = p;
            s.foot_vel[f] = b.velocity_at_point(p);
        }
    }

    /// Read every robot's state into `out` (one entry per slot), including the contact forces of
    /// the last physics step.
    pub fn read_states(&mut self, model: &RobotModel, out: &mut [RobotState]) {
        let t0 = Instant::now();
        for (slot, s) in out.iter_mut().enumerate().take(self.robots.len()) {
            self.read_kinematics(model, slot, s);
            s.clear_contacts();
            s.faulted = self.faulted[slot];
        }
        for pair in self.narrow_phase.contact_pairs() {
            let Some((slot, body, role, force)) = self.robot_contact(pair) else {
                continue;
            };
            let Some(s) = out.get_mut(slot) else { continue };
            match role {
                0 => s.trunk_force += force,
                3 => s.head_force += force,
                1 => {
                    // Count each penalised body once (a body may have several colliders).
                    if force > CONTACT_FORCE_THRESHOLD && s.penalised_bodies & (1 << body) == 0 {
                        s.penalised_bodies |= 1 << body;
                        s.penalised_contacts += 1;
                    }
                }
                code @ 8..=11 => s.foot_force[(code - 8) as usize] += force,
                _ => s.other_contacts += 1,
            }
        }
        for (slot, s) in out.iter_mut().enumerate().take(self.robots.len()) {
            // A joint at its stop, or fast enough to reach it within the next policy step.
            let reach = LIMIT_MARGIN;
            let at_limit = model.joints.iter().enumerate().any(|(j, joint)| {
                let ahead = s.q[j] + s.qd[j] * LIMIT_LOOKAHEAD_S;
                s.q[j].min(ahead) < joint.sim_lower + reach
                    || s.q[j].max(ahead) > joint.sim_upper - reach
            });
            self.near_stop[slot] = at_limit;
            self.update_extra_iterations(slot);
            s.extra_iterations = self.extra_iterations[slot];
        }
        self.counters.read_back_s += t0.elapsed().as_secs_f64();
    }

    /// Overwrite the linear velocity of robot `slot`'s trunk (used by pushes), keeping the other
    /// bodies' velocities relative to it.
    pub fn add_base_velocity(&mut self, slot: usize, delta: Vec3) {
        for &h in &self.robots[slot].bodies {
            let rb = &mut self.bodies[h];
            let v = rb.linvel() + delta;
            rb.set_linvel(v, true);
        }
    }

    /// World poses of all bodies of robot `slot` (for visualisation).
    pub fn body_poses(&self, slot: usize) -> Vec<Pose> {
        self.robots[slot]
            .bodies
            .iter()
            .map(|&h| *self.bodies[h].position())
            .collect()
    }

    /// Rotational inertia (kg m^2) of robot `slot` taken as rigid, about the world axis `axis`
    /// (unit) through its centre of mass: what the robot feels when it turns as a whole
    /// (armature included, as the links carry it).
    pub fn whole_body_inertia(&self, slot: usize, axis: Vec3) -> f32 {
        let bodies: Vec<usize> = (0..self.robots[slot].bodies.len()).collect();
        let (mut mass, mut moment) = (0.0, Vec3::ZERO);
        for &b in &bodies {
            let (m, c) = self.body_mass(slot, b);
            mass += m;
            moment += c * m;
        }
        let com = moment / mass.max(f32::EPSILON);
        self.inertia_about(slot, &bodies, com, axis)
    }

    /// Mass (kg) and world centre of mass of body `b` of robot `slot`, as simulated.
    pub fn body_mass(&self, slot: usize, b: usize) -> (f32, Vec3) {
        let rb = &self.bodies[self.robots[slot].bodies[b]];
        (rb.mass(), rb.center_of_mass())
    }

    /// Rotational inertia (kg m^2) of bodies `bodies` of robot `slot`, as simulated (the inertia
    /// floor and armature included), about the world axis `axis` (unit) through `point`.
    pub fn inertia_about(&self, slot: usize, bodies: &[usize], point: Vec3, axis: Vec3) -> f32 {
        bodies
            .iter()
            .map(|&b| {
                let rb = &self.bodies[self.robots[slot].bodies[b]];
                let local_axis = rb.rotation().inverse() * axis;
                let inertia = rb
                    .mass_properties()
                    .local_mprops
                    .reconstruct_inertia_matrix();
                let arm = axis.cross(rb.center_of_mass() - point);
                local_axis.dot(inertia * local_axis) + rb.mass() * arm.length_squared()
            })
            .sum()
    }

    /// Lock `axes` of robot `slot`'s trunk (test hook: a joint's response with the trunk held,
    /// a stance held upright).
    #[doc(hidden)]
    pub fn lock_trunk(&mut self, slot: usize, axes: LockedAxes) {
        let h = self.robots[slot].bodies[0];
        self.bodies[h].set_locked_axes(axes, true);
    }

    /// Set robot `slot`'s trunk velocity to `speed` m/s along x (test hook for the blow-up
    /// guard: NaN makes it non-finite, a huge finite speed a blow-up not yet overflowed).
    #[doc(hidden)]
    pub fn poison(&mut self, slot: usize, speed: f32) {
        let h = self.robots[slot].bodies[0];
        self.bodies[h].set_linvel(Vec3::new(speed, 0.0, 0.0), true);
    }
}

/// Stiffness (N m/rad) and damping (N m s/rad) of the joint stops. Rapier's limit constraint
/// only engages once a joint is past its limit and, with our first solver setting (4 substeps),
/// let fast joints overshoot by up to 0.16 rad; this explicit spring backs it up (stable:
/// k dt^2 / I < 0.2 with armature; stiffer springs, 1500-2500, made whipped legs overshoot more).
const LIMIT_STIFFNESS: f32 = 500.0;
const LIMIT_DAMPING: f32 = 5.0;

/// Torque of the joint stops: a stiff one-sided spring-damper beyond either limit.
#[inline]
fn limit_torque(q: f32, qd: f32, lower: f32, upper: f32) -> f32 {
    if q < lower {
        LIMIT_STIFFNESS * (lower - q) - LIMIT_DAMPING * qd.min(0.0)
    } else if q > upper {
        LIMIT_STIFFNESS * (upper - q) - LIMIT_DAMPING * qd.max(0.0)
    } else {
        0.0
    }
}

/// A joint closer than this to a limit (rad) counts as at its limit: limit constraints under
/// load need the extra iterations too.
const LIMIT_MARGIN: f32 = 0.05;
/// How far ahead (s) a joint's speed is extrapolated to decide it may hit a stop.
const LIMIT_LOOKAHEAD_S: f32 = 0.02;

/// Contact force (N) above which a contact counts (legged_gym uses 1 N for feet and trunk, 0.1 N
/// for penalised bodies).
pub const CONTACT_FORCE_THRESHOLD: f32 = 0.1;

/// Mass properties of body `b` of `model` with `params` applied: payload and CoM shift on the
/// trunk, the inertia floor and the armature on every leg link.
///
/// Armature is rotor inertia reflected on the joint coordinate (Isaac Gym and MuJoCo add it to
/// the joint-space mass matrix only). Impulse joints have no joint space, so it is added to the
/// child link's inertia about the joint axis: exact for a joint whose parent holds still, but
/// the whole robot also becomes harder to turn (pitch +0.16, roll +0.08 kg m^2 at 0.02, see
/// the physics tests). A joint motor pulling each joint towards its starting speed (an
/// implicit armature on the joint alone) was measured and rejected: as a stiff row for PGS it
/// kept loaded robots from converging (standing 19 mm low at 3 PGS iterations, creeping 5 mm
/// per 5 s even at 8): docs/src/decisions/0005-armature-on-links.md.
fn body_mass_properties(
    model: &RobotModel,
    b: usize,
    params: &RobotPhysicalParams,
    min_inertia: f32,
) -> MassProperties {
    let body = &model.bodies[b];
    let inertial = body.inertial;
    let (mut mass, mut com, mut inertia) = (inertial.mass, inertial.com, inertial.inertia);
    if b == 0 {
        let scale = (mass + params.payload) / mass;
        mass += params.payload;
        com += params.com_offset;
        inertia *= scale;
    } else if let Some(j) = body.joint {
        for i in 0..3 {
            let column = inertia.col_mut(i);
            column[i] = column[i].max(min_inertia);
        }
        let a = model.joints[j].axis;
        inertia += Mat3::from_cols(a * a.x, a * a.y, a * a.z) * params.armature;
    }
    mass_properties(com, mass, inertia)
}
