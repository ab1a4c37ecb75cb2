//! A group of envs sharing one physics world, stepped by one thread. The group is the unit of
//! parallelism; its size comes from the config, never from the thread count, so results do not
//! depend on the number of threads.

use std::time::Instant;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::math::{Pose, Rotation, Vec3};

use crate::physics::{ActuatorParams, PhysicsWorld, RobotState};
use crate::robot::{NUM_FEET, NUM_JOINTS, RobotModel};
use crate::task::{
    self, FeetAirTime, LABEL_DIM, OBS_DIM, PRIVILEGED_DIM, Randomization, RewardInputs, RewardTerm,
    TaskContext, TaskMode, euler_pitch, gait_coefficients, heading_direction, projected_gravity,
    to_heading_frame, uniform,
};
use crate::terrain::{EpisodeDistance, Terrain};

use super::EnvId;
use super::env_state::EnvState;
use super::observation_rows::{rewrite_task_observation, write_labels, write_observation};
use super::output::OutputChunk;
use super::upright_curriculum::UprightCounts;

/// Time spent per stage (seconds, summed over groups).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Physics substeps.
    pub physics: f64,
    /// Observations, labels, rewards, episode logic and resets.
    pub task: f64,
}

/// Envs sharing one physics world (rapier's or the articulated engine, per `physics.engine`).
pub struct EnvGroup {
    world: PhysicsWorld,
    envs: Vec<EnvState>,
    states: Vec<RobotState>,
    actuators: Vec<ActuatorParams>,
    targets: Vec<f32>,
    torques: Vec<f32>,
    /// Stage timers of this group.
    pub times: StageTimes,
    /// Envs reset because their physics blew up (non-finite or beyond any Go2's speeds), since
    /// creation.
    pub nonfinite_resets: u64,
    /// Biped-mode env-steps since the batch last took them (for the upright curriculum).
    pub upright_counts: UprightCounts,
}

/// Everything a group needs to read while stepping.
pub struct Shared<'a> {
    /// The robot.
    pub model: &'a RobotModel,
    /// Derived task data.
    pub ctx: &'a TaskContext,
    /// The terrain.
    pub terrain: &'a Terrain,
    /// Total envs in the batch (for spawn layout).
    pub num_envs: usize,
    /// Skip the task (observations, rewards, episodes): bare physics for benchmarks.
    pub physics_only: bool,
    /// Pitch above which I_up fires in this step (rad): the config's, or the curriculum's.
    pub upright_pitch: f32,
}

/// Stream id of env `index`'s RNG: distinct per env, independent of grouping.
fn env_rng(seed: u64, index: u32) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index as u64);
    rng
}

impl EnvGroup {
    /// A group of envs `first .. first + count`, all reset.
    pub fn new(sh: &Shared, first: usize, count: usize, seed: u64) -> Self {
        let world = PhysicsWorld::new(sh.model, count, sh.terrain, &sh.ctx.config.physics);
        let nominal = Randomization::nominal(&sh.model.config);
        let envs = (0..count)
            .map(|i| {
                let id = EnvId((first + i) as u32);
                EnvState {
                    id,
                    rng: env_rng(seed, id.0),
                    mode: TaskMode::Quad,
                    command: [0.0; 3],
                    held_heading: None,
                    episode_step: 0,
                    actions: [[0.0; NUM_JOINTS]; 3],
                    last_qd: [0.0; NUM_JOINTS],
                    feet_air: FeetAirTime::default(),
                    randomization: nominal,
                    origin: [0.0; 2],
                    terrain_level: 0,
                    mode_levels: [0; 2],
                    episode_mode: TaskMode::Quad,
                    terrain_type: 0,
                    distance: EpisodeDistance::default(),
                }
            })
            .collect();
        let actuator = nominal
            .physical_params(&sh.model.config, &sh.ctx.config.randomization)
            .actuator;
        Self {
            world,
            envs,
            states: vec![RobotState::default(); count],
            actuators: vec![actuator; count],
            targets: vec![0.0; count * NUM_JOINTS],
            torques: vec![0.0; count * NUM_JOINTS],
            times: StageTimes::default(),
            nonfinite_resets: 0,
            upright_counts: UprightCounts::default(),
        }
    }

    /// The physics world (read-only).
    pub fn world(&self) -> &PhysicsWorld {
        &self.world
    }

    /// The env states (read-only).
    pub fn envs(&self) -> &[EnvState] {
        &self.envs
    }

    /// The robot states read after the last step.
    pub fn states(&self) -> &[RobotState] {
        &self.states
    }

    /// Place robot `slot` at rest with trunk pose `base` and joint angles `q` (test hook).
    #[doc(hidden)]
    pub fn teleport(&mut self, model: &RobotModel, slot: usize, base: Pose, q: &[f32; NUM_JOINTS]) {
        self.world
            .set_robot_state(model, slot, base, Vec3::ZERO, Vec3::ZERO, q);
        self.world
            .read_kinematics(model, slot, &mut self.states[slot]);
    }

    /// Mutable world, for tests that poke the physics.
    #[doc(hidden)]
    pub fn world_mut(&mut self) -> &mut PhysicsWorld {
        &mut self.world
    }

    /// Reset env `slot` to a fresh episode. `first` spreads the episode start (legged_gym's
    /// random initial episode length) when the config asks for it.
    pub fn reset_env(&mut self, sh: &Shared, slot: usize, first: bool) {
        let cfg = &sh.ctx.config;
        let model = sh.model;
        let previous = self.states[slot];
        let env = &mut self.envs[slot];
        env.randomization = Randomization::sample(&cfg.randomization, &model.config, &mut env.rng);
        let params = env
            .randomization
            .physical_params(&model.config, &cfg.randomization);
        self.world.set_physical_params(model, slot, &params);
        self.actuators[slot] = params.actuator;

        // Table IV: joints = default + offsets, clipped to the simulated limits.
        let init = &cfg.init;
        let mut q = sh.ctx.default_q;
        for (j, qj) in q.iter_mut().enumerate() {
            let range = match j % model.config.joints_per_leg {
                0 => init.hip,
                1 => init.thigh,
                _ => init.calf,
            };
            let joint = &model.joints[j];
            *qj = (*qj + uniform(&mut env.rng, range)).clamp(joint.sim_lower, joint.sim_upper);
        }
        let pitch = uniform(&mut env.rng, init.pitch);
        let yaw = uniform(&mut env.rng, init.yaw);
        let rot = Rotation::from_rotation_z(yaw) * Rotation::from_rotation_y(pitch);
        let linvel = Vec3::new(
            uniform(&mut env.rng, init.linvel),
            uniform(&mut env.rng, init.linvel),
            uniform(&mut env.rng, init.linvel),
        );
        let angvel = Vec3::new(
            uniform(&mut env.rng, init.angvel),
            uniform(&mut env.rng, init.angvel),
            uniform(&mut env.rng, init.angvel),
        );
        // Lowest point of the robot below the trunk origin, from the colliders' bounding spheres.
        let local = model.forward_kinematics(&q);
        let lowest = sh
            .ctx
            .collider_bounds
            .iter()
            .map(|(b, c, r)| (rot * local[*b].transform_point(*c)).z - r)
            .fold(0.0f32, f32::min);
        let rule = &cfg.terrain_curriculum;
        // With a level per mode the episode's first mode picks its tile, so it is drawn first
        // (decision record 0036); otherwise after the tile, as it always was.
        let early_mode =
            (rule.per_mode_levels && sh.terrain.grid().is_some()).then(|| env.draw_mode(cfg));
        let (x, y) = match sh.terrain.grid() {
            None => sh.terrain.env_origin(env.id.index(), sh.num_envs),
            Some(grid) => {
                if first {
                    let (level, column) =
                        sh.terrain
                            .initial_tile(env.id.index(), sh.num_envs, &mut env.rng);
                    env.terrain_level = level;
                    env.mode_levels = grid
                        .initial_mode_levels(env.id.index())
                        .unwrap_or([level; 2]);
                    env.terrain_type = column;
                } else if previous.is_sound() {
                    // The curriculum judges the episode that just ended by what the robot
                    // walked along its commands against what they asked for (both integrated
                    // per step in `step_task`; see terrain::curriculum).
                    if rule.per_mode_levels {
                        let m = mode_index(env.episode_mode);
                        let biped = env.episode_mode == TaskMode::Biped;
                        env.mode_levels[m] = grid.next_level(
                            env.mode_levels[m],
                            env.distance.in_mode(biped),
                            rule,
                            &mut env.rng,
                        );
                    } else {
                        env.terrain_level =
                            grid.next_level(env.terrain_level, env.distance, rule, &mut env.rng);
                    }
                }
                if let Some(mode) = early_mode {
                    env.terrain_level = env.mode_levels[mode_index(mode)];
                }
                let o = grid.tile_origin(env.terrain_level, env.terrain_type);
                (o.x, o.y)
            }
        };
        let ground = sh.terrain.max_height_within(x, y, 0.6);
        let base = Pose::from_parts(Vec3::new(x, y, ground - lowest + init.spawn_clearance), rot);
        self.world
            .set_robot_state(model, slot, base, linvel, angvel, &q);
        env.origin = [x, y];
        env.distance = EpisodeDistance::default();

        let mode = early_mode.unwrap_or_else(|| env.draw_mode(cfg));
        env.episode_mode = mode;
        env.enter_mode(cfg, mode, None, true);
        env.episode_step = if first && cfg.env.random_initial_episode_step {
            env.rng.random_range(0..sh.ctx.max_episode_steps)
        } else {
            0
        };
        env.actions = [[0.0; NUM_JOINTS]; 3];
        env.last_qd = [0.0; NUM_JOINTS];
        env.feet_air = FeetAirTime::default();
        let s = &mut self.states[slot];
        self.world.read_kinematics(model, slot, s);
        s.clear_contacts();
        env.hold_heading(cfg, s.base_rot);
    }

    /// Reset every env and write the first observations.
    pub fn reset_all(&mut self, sh: &Shared, first: bool, out: &mut OutputChunk) {
        for slot in 0..self.envs.len() {
            self.reset_env(sh, slot, first);
        }
        self.write_all(sh, out);
    }

    /// Reset the envs whose `mask` entry is non-zero and rewrite their rows of `out`.
    pub fn reset_masked(&mut self, sh: &Shared, mask: &[u8], out: &mut OutputChunk) {
        for (slot, &m) in mask.iter().enumerate().take(self.envs.len()) {
            if m != 0 {
                self.reset_env(sh, slot, false);
                self.write_env(sh, slot, out);
            }
        }
    }

    /// Switch env `slot` to `mode` now, as the episode's own mode draw would (see
    /// [`EnvState::enter_mode`]), and rewrite what of its row of `out` the mode decides: the
    /// task slices of o_t and the mode entry. Nothing else of the row changes (the rest of o_t
    /// measures the body, and the last reward was earned under the old mode). The episode's
    /// first mode (`EnvState::episode_mode`, whose level a curriculum with a level per mode
    /// judges) stays the drawn one.
    pub fn set_mode(
        &mut self,
        sh: &Shared,
        slot: usize,
        mode: TaskMode,
        command: Option<[f32; 3]>,
        out: &mut OutputChunk,
    ) {
        let env = &mut self.envs[slot];
        env.enter_mode(&sh.ctx.config, mode, command, false);
        env.hold_heading(&sh.ctx.config, self.states[slot].base_rot);
        rewrite_task_observation(sh, env, &mut out.obs[slot * OBS_DIM..(slot + 1) * OBS_DIM]);
        out.mode[slot] = env.mode as u8;
    }

    /// [`Self::set_mode`] on the envs whose `mask` entry is non-zero.
    pub fn set_mode_masked(
        &mut self,
        sh: &Shared,
        mask: &[u8],
        mode: TaskMode,
        command: Option<[f32; 3]>,
        out: &mut OutputChunk,
    ) {
        for (slot, &m) in mask.iter().enumerate().take(self.envs.len()) {
            if m != 0 {
                self.set_mode(sh, slot, mode, command, out);
            }
        }
    }

    fn write_all(&mut self, sh: &Shared, out: &mut OutputChunk) {
        for slot in 0..self.envs.len() {
            self.write_env(sh, slot, out);
        }
    }

    fn write_env(&mut self, sh: &Shared, slot: usize, out: &mut OutputChunk) {
        let env = &mut self.envs[slot];
        let s = &self.states[slot];
        write_observation(
            sh,
            env,
            s,
            &mut out.obs[slot * OBS_DIM..(slot + 1) * OBS_DIM],
        );
        write_labels(
            sh,
            s,
            &mut out.labels[slot * LABEL_DIM..(slot + 1) * LABEL_DIM],
        );
        out.privileged[slot * PRIVILEGED_DIM..(slot + 1) * PRIVILEGED_DIM]
            .copy_from_slice(&env.randomization.privileged(&sh.ctx.config.randomization));
        out.mode[slot] = env.mode as u8;
        out.terrain_level[slot] = env.terrain_level;
        out.mode_levels[2 * slot..2 * slot + 2].copy_from_slice(&if per_mode_levels(sh) {
            env.mode_levels
        } else {
            [env.terrain_level; 2]
        });
    }

    /// One policy step of every env: actions [len, 12] (already validated finite).
    pub fn step(&mut self, sh: &Shared, actions: &[f32], autoreset: bool, out: &mut OutputChunk) {
        let t0 = Instant::now();
        let cfg = &sh.ctx.config;
        let clip = cfg.env.clip_actions;
        for (slot, env) in self.envs.iter_mut().enumerate() {
            env.actions[2] = env.actions[1];
            env.actions[1] = env.actions[0];
            for j in 0..NUM_JOINTS {
                let a = actions[slot * NUM_JOINTS + j].clamp(-clip, clip);
                env.actions[0][j] = a;
                // Not clamped to the joint range, as legged_gym: a clamped target caps the
                // torque a leg pushes with near its stop (kp x distance, ~13 N m at the default
                // knee angle instead of the motor's 35.55), too little for one front leg to
                // carry the body in the biped stance. The stops are the physics' job.
                self.targets[slot * NUM_JOINTS + j] =
                    sh.ctx.default_q[j] + cfg.env.action_scale * a;
            }
        }
        for _ in 0..cfg.env.decimation {
            self.world
                .step(sh.model, &self.targets, &self.actuators, &mut self.torques);
        }
        self.world.read_states(sh.model, &mut self.states);
        out.torques.copy_from_slice(&self.torques);
        let t1 = Instant::now();
        self.times.physics += (t1 - t0).as_secs_f64();
        if sh.physics_only {
            // Bare physics: only guard against blow-ups.
            for slot in 0..self.envs.len() {
                out.nonfinite[slot] = 0;
                if !self.states[slot].is_sound() {
                    out.nonfinite[slot] = 1;
                    self.nonfinite_resets += 1;
                    report_blowup(&self.envs[slot], &self.states[slot]);
                    self.reset_env(sh, slot, false);
                }
            }
            return;
        }
        for slot in 0..self.envs.len() {
            self.step_task(sh, slot, autoreset, out);
        }
        self.times.task += t1.elapsed().as_secs_f64();
    }

    /// Episode logic, rewards and observations of env `slot` after its physics step.
    fn step_task(&mut self, sh: &Shared, slot: usize, autoreset: bool, out: &mut OutputChunk) {
        let ctx = sh.ctx;
        let cfg = &ctx.config;
        self.envs[slot].episode_step += 1;
        let sound = self.states[slot].is_sound();
        let terms = &mut out.reward_terms[slot * RewardTerm::COUNT..(slot + 1) * RewardTerm::COUNT];
        out.nonfinite[slot] = u8::from(!sound);
        out.head_contact[slot] =
            u8::from(sound && self.states[slot].head_force > cfg.rewards.contact_threshold);
        out.episode_length[slot] = 0;
        let (terminated, truncated);
        if sound {
            let s = &self.states[slot];
            terminated = s.trunk_force > cfg.rewards.contact_threshold;
            truncated = !terminated && self.envs[slot].episode_step >= ctx.max_episode_steps;
            if sh.terrain.grid().is_some() {
                let env = &mut self.envs[slot];
                let heading = heading_direction(s.base_rot);
                let v = to_heading_frame(heading, s.base_linvel);
                let command = [env.command[0], env.command[1]];
                let dt = cfg.policy_dt();
                let biped = env.mode == TaskMode::Biped;
                env.distance.add_step(command, [v.x, v.y], dt, biped);
                let offset = [s.base_pos.x - env.origin[0], s.base_pos.y - env.origin[1]];
                let yaw = heading.y.atan2(heading.x);
                env.distance
                    .reach
                    .add_step(offset, yaw, env.command, dt, biped);
                if terminated {
                    let left = ctx.max_episode_steps.saturating_sub(env.episode_step);
                    env.distance.add_unlived(command, left as f32 * dt, biped);
                }
            }
            let contact = s.foot_force.map(|f| f > cfg.rewards.contact_threshold);
            let touchdown = self.envs[slot].feet_air.step(contact, cfg.policy_dt());
            let inputs = reward_inputs(
                sh,
                &self.envs[slot],
                s,
                terminated,
                touchdown,
                &self.torques[slot * NUM_JOINTS..],
            );
            let raw = task::raw_terms(&inputs, &ctx.reward, cfg);
            let biped = self.envs[slot].mode == TaskMode::Biped;
            let ind = task::indicators(biped, inputs.pitch, sh.upright_pitch, cfg);
            if biped {
                self.upright_counts.add(inputs.pitch > sh.upright_pitch);
            }
            out.reward[slot] = task::weigh_terms(&raw, &ind, cfg, terms);
        } else {
            // A physics blow-up: the transition carries no reward and ends without bootstrap.
            self.nonfinite_resets += 1;
            report_blowup(&self.envs[slot], &self.states[slot]);
            terminated = true;
            truncated = false;
            terms.fill(0.0);
            out.reward[slot] = 0.0;
        }
        out.terminated[slot] = u8::from(terminated);
        out.truncated[slot] = u8::from(truncated);
        let done = terminated || truncated;
        let range = |dim: usize| slot * dim..(slot + 1) * dim;
        if done {
            out.episode_length[slot] = self.envs[slot].episode_step;
            if sound {
                let (env, s) = (&mut self.envs[slot], &self.states[slot]);
                write_observation(sh, env, s, &mut out.final_obs[range(OBS_DIM)]);
                write_labels(sh, s, &mut out.final_labels[range(LABEL_DIM)]);
            } else {
                out.final_obs[range(OBS_DIM)].fill(0.0);
                out.final_labels[range(LABEL_DIM)].fill(0.0);
            }
            out.final_privileged[range(PRIVILEGED_DIM)]
                .copy_from_slice(&self.envs[slot].randomization.privileged(&cfg.randomization));
            if autoreset || !sound {
                self.reset_env(sh, slot, false);
            }
        } else {
            let env = &mut self.envs[slot];
            env.last_qd = self.states[slot].qd;
            let step = env.episode_step;
            let mode = if step.is_multiple_of(ctx.mode_interval) {
                env.draw_mode(cfg)
            } else {
                env.mode
            };
            env.enter_mode(cfg, mode, None, step.is_multiple_of(ctx.command_interval));
            env.hold_heading(cfg, self.states[slot].base_rot);
            if ctx.push_interval.is_some_and(|p| step.is_multiple_of(p)) {
                let v = cfg.randomization.push_velocity;
                let delta = Vec3::new(
                    uniform(&mut env.rng, [-v, v]),
                    uniform(&mut env.rng, [-v, v]),
                    0.0,
                );
                self.world.add_base_velocity(slot, delta);
            }
        }
        self.write_env(sh, slot, out);
    }
}

/// Say where and how an env blew up before it is reset (decision record 0035): their cause is
/// not yet known, and the state is gone after the reset.
fn report_blowup(env: &EnvState, s: &RobotState) {
    let joint = s.qd.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    tracing::warn!(
        env = env.id.index(),
        step = env.episode_step,
        mode = ?env.mode,
        terrain_level = env.terrain_level,
        terrain_type = env.terrain_type,
        base_pos = ?s.base_pos,
        base_linvel = ?s.base_linvel,
        base_angvel = ?s.base_angvel,
        max_joint_speed = joint,
        faulted = s.faulted,
        "physics blow-up: env reset"
    );
}

/// Whether this batch's curriculum keeps a level per mode (decision record 0036).
fn per_mode_levels(sh: &Shared) -> bool {
    sh.ctx.config.terrain_curriculum.per_mode_levels && sh.terrain.grid().is_some()
}

/// The entry of [`EnvState::mode_levels`] that holds `mode`'s level.
fn mode_index(mode: TaskMode) -> usize {
    usize::from(mode == TaskMode::Biped)
}

/// Height of each foot's frame origin (the sphere centre) above the highest terrain within
/// `radius` of it: Eq. 4's p_i - max(H_sample,i), with p_i the foot position as legged_gym reads
/// it (the foot body's origin), so p_des 0.08 m means the same lift as in the paper.
fn foot_clearance_heights(sh: &Shared, s: &RobotState, radius: f32) -> [f32; NUM_FEET] {
    std::array::from_fn(|f| {
        let p = s.foot_pos[f];
        p.z - sh.terrain.max_height_within(p.x, p.y, radius)
    })
}

fn reward_inputs(
    sh: &Shared,
    env: &EnvState,
    s: &RobotState,
    terminated: bool,
    touchdown_air_time: [f32; NUM_FEET],
    torques: &[f32],
) -> RewardInputs {
    let cfg = &sh.ctx.config;
    let inv = s.base_rot.inverse();
    let heading = heading_direction(s.base_rot);
    let gravity = projected_gravity(s.base_rot);
    let normal = sh.terrain.normal(s.base_pos.x, s.base_pos.y);
    let phase = env.gait_phase(cfg);
    let coeffs = |offsets: [f32; 4]| {
        std::array::from_fn(|f| {
            gait_coefficients(&sh.ctx.cdf, phase + offsets[f], cfg.gait.swing_ratio)
        })
    };
    RewardInputs {
        terminated,
        penalised_contacts: s.penalised_contacts,
        head_contact: s.head_force > cfg.rewards.contact_threshold,
        base_angvel_b: inv * s.base_angvel,
        base_linvel_b: inv * s.base_linvel,
        heading_linvel: to_heading_frame(heading, s.base_linvel),
        yaw_rate: s.base_angvel.z,
        command: env.command,
        base_height: s.base_pos.z - sh.terrain.height(s.base_pos.x, s.base_pos.y),
        terrain_normal_b: inv * normal,
        pitch: euler_pitch(s.base_rot),
        roll_proxy: gravity.y,
        q: s.q,
        qd: s.qd,
        qd_prev: env.last_qd,
        actions: env.actions,
        torques: std::array::from_fn(|j| torques[j]),
        foot_force: s.foot_force,
        foot_speed: s.foot_vel.map(|v| v.length()),
        foot_speed_xy: s.foot_vel.map(|v| v.truncate().length()),
        foot_clearance_height: foot_clearance_heights(sh, s, cfg.rewards.foot_clearance_radius),
        touchdown_air_time,
        gait_quad: coeffs(cfg.gait.offsets_quad),
        gait_biped: coeffs(cfg.gait.offsets_biped),
    }
}
