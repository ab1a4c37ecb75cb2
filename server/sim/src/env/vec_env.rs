//! N envs stepped in parallel: the batch a learner or the service drives.

use std::sync::Arc;

use rayon::prelude::*;

use crate::error::SimError;
use crate::physics::{PhysicsCounters, RobotState};
use crate::robot::{NUM_JOINTS, RobotModel};
use crate::task::{TaskConfig, TaskContext, TaskMode};
use crate::terrain::Terrain;

use super::group::{EnvGroup, Shared, StageTimes};
use super::output::StepOutput;
use super::upright_curriculum::{UprightCounts, UprightThreshold};

/// How a batch is built.
#[derive(Clone, Debug, PartialEq)]
pub struct VecEnvOptions {
    /// Number of envs (>= 1).
    pub num_envs: usize,
    /// Seed of every random draw; env i uses stream i of it.
    pub seed: u64,
    /// Worker threads (0 = one per core).
    pub threads: usize,
    /// Skip the task (bare physics, for benchmarks).
    pub physics_only: bool,
    /// Reset ended envs inside the step (else the client resets them with a mask).
    pub autoreset: bool,
}

impl Default for VecEnvOptions {
    fn default() -> Self {
        Self {
            num_envs: 1,
            seed: 0,
            threads: 0,
            physics_only: false,
            autoreset: true,
        }
    }
}

/// A batch of Go2 envs.
pub struct VecEnv {
    model: Arc<RobotModel>,
    ctx: Arc<TaskContext>,
    terrain: Arc<Terrain>,
    groups: Vec<EnvGroup>,
    pool: Arc<rayon::ThreadPool>,
    out: StepOutput,
    options: VecEnvOptions,
    upright: UprightThreshold,
}

/// A pool of `threads` env worker threads (0 = one per core).
pub fn worker_pool(threads: usize) -> Result<Arc<rayon::ThreadPool>, SimError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("unigait-env-{i}"))
        .build()
        .map(Arc::new)
        .map_err(|e| SimError::invalid("threads", threads, e.to_string()))
}

/// Check an action tensor: `num_envs * 12` finite values.
pub fn validate_actions(actions: &[f32], num_envs: usize) -> Result<(), SimError> {
    let expected = num_envs * NUM_JOINTS;
    if actions.len() != expected {
        return Err(SimError::Shape {
            name: "actions".into(),
            got: actions.len(),
            expected,
            detail: format!("{num_envs} envs x {NUM_JOINTS} joints"),
        });
    }
    if let Some(index) = actions.iter().position(|a| !a.is_finite()) {
        return Err(SimError::NonFinite {
            name: "actions".into(),
            index,
            env: index / NUM_JOINTS,
            value: actions[index],
        });
    }
    Ok(())
}

/// A caller's command must be finite (`env` names the env it is for, in the error).
fn check_command(command: Option<[f32; 3]>, env: usize) -> Result<(), SimError> {
    if let Some(c) = command
        && let Some(index) = c.iter().position(|v| !v.is_finite())
    {
        return Err(SimError::NonFinite {
            name: "command".into(),
            index,
            env,
            value: c[index],
        });
    }
    Ok(())
}

impl VecEnv {
    /// Build and reset a batch with its own pool of `options.threads` worker threads.
    pub fn new(
        model: Arc<RobotModel>,
        config: TaskConfig,
        terrain: Arc<Terrain>,
        options: VecEnvOptions,
    ) -> Result<Self, SimError> {
        let pool = worker_pool(options.threads)?;
        Self::with_pool(model, config, terrain, options, pool)
    }

    /// Build and reset a batch that steps on a shared worker pool (`options.threads` is
    /// ignored). A server shares one pool between its sessions.
    pub fn with_pool(
        model: Arc<RobotModel>,
        config: TaskConfig,
        terrain: Arc<Terrain>,
        options: VecEnvOptions,
        pool: Arc<rayon::ThreadPool>,
    ) -> Result<Self, SimError> {
        config.validate()?;
        if options.num_envs == 0 {
            return Err(SimError::invalid("num_envs", 0, "at least 1"));
        }
        let ctx = Arc::new(TaskContext::new(config, &model));
        let epw = ctx.config.env.envs_per_world;
        let n = options.num_envs;
        let upright = UprightThreshold::new(&ctx.config.rewards);
        let mut out = StepOutput::new(n);
        out.upright_pitch = upright.current();
        let mut env = Self {
            groups: Vec::new(),
            out,
            upright,
            model,
            ctx,
            terrain,
            pool,
            options,
        };
        let firsts: Vec<usize> = (0..n).step_by(epw).collect();
        let seed = env.options.seed;
        let (sh, _, _, pool) = env.parts();
        let groups: Vec<EnvGroup> = pool.install(|| {
            firsts
                .par_iter()
                .map(|&first| EnvGroup::new(&sh, first, epw.min(n - first), seed))
                .collect()
        });
        env.groups = groups;
        env.reset_all(true);
        Ok(env)
    }

    /// What the groups read while stepping, beside the groups, the output and the pool: one
    /// borrow of `self` split by field, so the groups and the output can be written while the
    /// shared view is read.
    fn parts(
        &mut self,
    ) -> (
        Shared<'_>,
        &mut Vec<EnvGroup>,
        &mut StepOutput,
        &rayon::ThreadPool,
    ) {
        let sh = Shared {
            model: &self.model,
            ctx: &self.ctx,
            terrain: &self.terrain,
            num_envs: self.options.num_envs,
            physics_only: self.options.physics_only,
            upright_pitch: self.upright.current(),
        };
        (sh, &mut self.groups, &mut self.out, &self.pool)
    }

    /// Run `work(shared, group, its output rows, its first env index)` on every group in
    /// parallel on the worker pool.
    fn for_each_group(
        &mut self,
        work: impl Fn(&Shared, &mut EnvGroup, &mut super::OutputChunk, usize) + Sync,
    ) {
        let epw = self.ctx.config.env.envs_per_world;
        let (sh, groups, out, pool) = self.parts();
        let chunks = out.chunks_mut(epw);
        pool.install(|| {
            groups
                .par_iter_mut()
                .zip(chunks)
                .enumerate()
                .for_each(|(i, (g, mut chunk))| work(&sh, g, &mut chunk, i * epw));
        });
    }

    fn reset_all(&mut self, first: bool) {
        self.for_each_group(|sh, g, chunk, _| g.reset_all(sh, first, chunk));
        self.out.forget_episode_ends();
    }

    /// Reset every env (a new episode everywhere) and return the first observations.
    pub fn reset(&mut self) -> &StepOutput {
        self.reset_all(false);
        &self.out
    }

    /// Reset the envs where `mask` is non-zero (`mask` has one entry per env).
    pub fn reset_envs(&mut self, mask: &[u8]) -> Result<&StepOutput, SimError> {
        let n = self.options.num_envs;
        if mask.len() != n {
            return Err(SimError::Shape {
                name: "reset_mask".into(),
                got: mask.len(),
                expected: n,
                detail: format!("{n} envs"),
            });
        }
        let epw = self.ctx.config.env.envs_per_world;
        self.for_each_group(|sh, g, chunk, first| {
            g.reset_masked(sh, &mask[first..(first + epw).min(n)], chunk)
        });
        self.out.forget_episode_ends();
        Ok(&self.out)
    }

    /// Step every env with `actions` ([num_envs, 12], row-major).
    pub fn step(&mut self, actions: &[f32]) -> Result<&StepOutput, SimError> {
        let n = self.options.num_envs;
        validate_actions(actions, n)?;
        let epw = self.ctx.config.env.envs_per_world;
        let autoreset = self.options.autoreset;
        self.for_each_group(|sh, g, chunk, first| {
            let rows = &actions[first * NUM_JOINTS..(first + epw).min(n) * NUM_JOINTS];
            g.step(sh, rows, autoreset, chunk);
        });
        // Summed in group order after the parallel step, so the threshold does not depend on
        // the thread count.
        let mut counts = UprightCounts::default();
        for g in &mut self.groups {
            counts += std::mem::take(&mut g.upright_counts);
        }
        self.upright.observe(counts);
        self.out.upright_pitch = self.upright.current();
        Ok(&self.out)
    }

    /// Switch env `env` to task mode `mode` now, as the episode's own mode draw does, so that
    /// the next action the policy computes already sees the new mode.
    ///
    /// - `command` (vx, vy in the heading frame, yaw rate) becomes the env's command. With
    ///   None the command is redrawn from the new mode's ranges when the mode changes (as a
    ///   drawn mode change does) and kept when the env already is in `mode`.
    /// - The gait clock runs on, as at a drawn mode change (its phase offsets follow the mode).
    /// - Row `env` of the current output is rewritten where the mode decides it: the command,
    ///   mode and clock slices of `obs` (ratio too, unchanged) and `mode`. The rest of the row,
    ///   including the reward of the last step, stays as the last step left it.
    /// - Later mode and command draws of the episode come on their usual schedule, and a reset
    ///   draws the mode afresh.
    ///
    /// Only env `env` is touched, and only its own random stream may advance (by the command
    /// draw), so other envs stay bit-identical and results do not depend on the thread count.
    pub fn set_mode(
        &mut self,
        env: usize,
        mode: TaskMode,
        command: Option<[f32; 3]>,
    ) -> Result<(), SimError> {
        let n = self.options.num_envs;
        if env >= n {
            return Err(SimError::invalid(
                "env",
                env,
                format!("an env index below num_envs = {n}"),
            ));
        }
        check_command(command, env)?;
        let epw = self.ctx.config.env.envs_per_world;
        let (sh, groups, out, _) = self.parts();
        // Groups and output chunks pair up one to one (both are `epw` envs each).
        let (group, slot) = (env / epw, env % epw);
        if let (Some(g), Some(chunk)) = (groups.get_mut(group), out.chunks_mut(epw).get_mut(group))
        {
            g.set_mode(&sh, slot, mode, command, chunk);
        }
        Ok(())
    }

    /// [`Self::set_mode`] on every env whose `mask` entry is non-zero (`mask` has one entry per
    /// env), all to the same mode and, when given, the same command.
    pub fn set_modes(
        &mut self,
        mask: &[u8],
        mode: TaskMode,
        command: Option<[f32; 3]>,
    ) -> Result<(), SimError> {
        let n = self.options.num_envs;
        if mask.len() != n {
            return Err(SimError::Shape {
                name: "mode_mask".into(),
                got: mask.len(),
                expected: n,
                detail: format!("{n} envs"),
            });
        }
        // A bad command is refused even when the mask is empty: it is the caller's bug either way.
        let first = mask.iter().position(|&m| m != 0).unwrap_or(0);
        check_command(command, first)?;
        let epw = self.ctx.config.env.envs_per_world;
        self.for_each_group(|sh, g, chunk, first| {
            g.set_mode_masked(sh, &mask[first..(first + epw).min(n)], mode, command, chunk)
        });
        Ok(())
    }

    /// The latest results.
    pub fn output(&self) -> &StepOutput {
        &self.out
    }

    /// Number of envs.
    pub fn num_envs(&self) -> usize {
        self.options.num_envs
    }

    /// Options the batch was built with.
    pub fn options(&self) -> &VecEnvOptions {
        &self.options
    }

    /// The task context (config and derived values).
    pub fn context(&self) -> &TaskContext {
        &self.ctx
    }

    /// The robot model.
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// The terrain.
    pub fn terrain(&self) -> &Terrain {
        &self.terrain
    }

    /// Worst joint anchor separation over all envs after the last step (m).
    pub fn max_joint_gap(&self) -> f32 {
        self.groups
            .iter()
            .flat_map(|g| g.states())
            .map(|s| s.max_joint_gap)
            .fold(0.0, f32::max)
    }

    /// Share of envs given extra solver iterations after the last step (a cost driver: see
    /// [`crate::physics::PhysicsParams::extra_pgs_iterations_on_leg_contact`]).
    pub fn extra_iteration_share(&self) -> f64 {
        let (mut extra, mut total) = (0usize, 0usize);
        for s in self.groups.iter().flat_map(|g| g.states()) {
            extra += usize::from(s.extra_iterations);
            total += 1;
        }
        extra as f64 / total.max(1) as f64
    }

    /// Measured state of env `i` after the last step.
    pub fn robot_state(&self, i: usize) -> &RobotState {
        let epw = self.ctx.config.env.envs_per_world;
        &self.groups[i / epw].states()[i % epw]
    }

    /// Episode state of env `i`.
    pub fn env_state(&self, i: usize) -> &super::EnvState {
        let epw = self.ctx.config.env.envs_per_world;
        &self.groups[i / epw].envs()[i % epw]
    }

    /// World poses of env `i`'s bodies (trunk first), for visualisation.
    pub fn body_poses(&self, i: usize) -> Vec<rapier3d::math::Pose> {
        let epw = self.ctx.config.env.envs_per_world;
        self.groups[i / epw].world().body_poses(i % epw)
    }

    /// Time per stage summed over groups since creation (CPU seconds).
    pub fn stage_times(&self) -> StageTimes {
        self.groups
            .iter()
            .fold(StageTimes::default(), |acc, g| StageTimes {
                physics: acc.physics + g.times.physics,
                task: acc.task + g.times.task,
            })
    }

    /// The physics worlds' time by stage, summed over worlds since creation.
    pub fn physics_counters(&self) -> PhysicsCounters {
        self.groups
            .iter()
            .fold(PhysicsCounters::default(), |acc, g| {
                acc.plus(g.world().counters())
            })
    }

    /// Remove every robot's joints (benchmark hook: rapier's pipeline without the joint
    /// solver; the robots fall apart into 13 free bodies each).
    #[doc(hidden)]
    pub fn remove_joints(&mut self) {
        for g in &mut self.groups {
            g.world_mut().remove_joints();
        }
    }

    /// Envs reset because their physics went non-finite, since creation.
    pub fn nonfinite_resets(&self) -> u64 {
        self.groups.iter().map(|g| g.nonfinite_resets).sum()
    }

    /// Place env `i`'s robot at rest: trunk pose `base`, joint angles `q` (test hook for
    /// contact cases; the episode goes on).
    #[doc(hidden)]
    pub fn teleport_env(&mut self, i: usize, base: rapier3d::math::Pose, q: &[f32; NUM_JOINTS]) {
        let epw = self.ctx.config.env.envs_per_world;
        self.groups[i / epw].teleport(&self.model, i % epw, base, q);
    }

    /// Set env `i`'s trunk speed to `speed` m/s (test hook for the blow-up guard: NaN for a
    /// non-finite state, a huge finite speed for one that has not overflowed yet).
    #[doc(hidden)]
    pub fn poison_env(&mut self, i: usize, speed: f32) {
        let epw = self.ctx.config.env.envs_per_world;
        self.groups[i / epw].world_mut().poison(i % epw, speed);
    }
}
