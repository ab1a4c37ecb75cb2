//! Rolling a policy out on a `VecEnv`: the per-env observation history, one policy or two
//! switched by mode, and an observer hook (for recordings).

use std::sync::Arc;

use serde::Serialize;
use unigait_policy::{ObsHistory, Policy, PolicyError, PolicySpec};
use unigait_sim::env::VecEnv;
use unigait_sim::robot::NUM_JOINTS;
use unigait_sim::task::{OBS_DIM, TaskMode, euler_pitch, heading_direction, to_heading_frame};

use crate::error::EvalError;
use crate::metrics::{
    EpisodeOutcomes, HeadHits, TRACKING_SETTLE_S, TrackingAccumulator, UPRIGHT_PITCH,
    UPRIGHT_SETTLE_S,
};
use crate::scenario::Mode;

/// The shapes every policy must fit here: 3 observations of the sim's 53, 12 actions.
pub fn sim_policy_spec() -> PolicySpec {
    PolicySpec {
        history: 3,
        obs_dim: OBS_DIM,
        num_actions: NUM_JOINTS,
    }
}

/// The controller under evaluation.
#[derive(Clone)]
pub enum Policies {
    /// One policy for both modes (the paper's method).
    Unified(Arc<dyn Policy>),
    /// The two-policy baseline: each env runs the policy of its current mode, switched at the
    /// mode change.
    TwoPolicy {
        /// Runs envs in quad mode.
        quad: Arc<dyn Policy>,
        /// Runs envs in biped mode.
        biped: Arc<dyn Policy>,
    },
}

impl std::fmt::Debug for Policies {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.kind())
    }
}

impl Policies {
    /// `unified` or `two_policy`.
    pub fn kind(&self) -> &'static str {
        match self {
            Policies::Unified(_) => "unified",
            Policies::TwoPolicy { .. } => "two_policy",
        }
    }

    /// Check every policy fits the sim's observation and action sizes.
    pub fn check(&self) -> Result<(), EvalError> {
        let want = sim_policy_spec();
        let all: Vec<(&str, &Arc<dyn Policy>)> = match self {
            Policies::Unified(p) => vec![("policy", p)],
            Policies::TwoPolicy { quad, biped } => {
                vec![("quad policy", quad), ("biped policy", biped)]
            }
        };
        for (name, p) in all {
            if p.spec() != want {
                return Err(EvalError::InvalidOption(format!(
                    "the {name} fits {:?}, the sim needs {want:?}",
                    p.spec()
                )));
            }
        }
        Ok(())
    }

    /// Actions for every env from its history; `modes` (1 biped, 2 quad) picks the policy of
    /// each env for the two-policy baseline.
    pub fn act(
        &self,
        history: &ObsHistory,
        modes: &[u8],
        actions: &mut [f32],
    ) -> Result<(), PolicyError> {
        let n = history.num_envs();
        match self {
            Policies::Unified(p) => p.act(history.as_slice(), n, actions),
            Policies::TwoPolicy { quad, biped } => {
                for (policy, code) in [(quad, TaskMode::Quad as u8), (biped, TaskMode::Biped as u8)]
                {
                    let rows: Vec<usize> = (0..n).filter(|&i| modes[i] == code).collect();
                    if rows.is_empty() {
                        continue;
                    }
                    let w = history.env(0).len();
                    let mut sub = Vec::with_capacity(rows.len() * w);
                    for &i in &rows {
                        sub.extend_from_slice(history.env(i));
                    }
                    let out = policy.act_vec(&sub, rows.len())?;
                    for (k, &i) in rows.iter().enumerate() {
                        actions[i * NUM_JOINTS..(i + 1) * NUM_JOINTS]
                            .copy_from_slice(&out[k * NUM_JOINTS..(k + 1) * NUM_JOINTS]);
                    }
                }
                Ok(())
            }
        }
    }
}

/// Watches a rollout (e.g. to record it). Every method has an empty default.
pub trait StepObserver {
    /// A case (one `VecEnv`) starts; `env` holds the first observations.
    fn begin_case(&mut self, _case: usize, _name: &str, _env: &VecEnv) {}
    /// After policy step `step` (1-based) of case `case`.
    fn after_step(&mut self, _case: usize, _step: u32, _env: &VecEnv) {}
    /// The case is over.
    fn end_case(&mut self, _case: usize) {}
}

/// An observer that does nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoObserver;

impl StepObserver for NoObserver {}

/// What the evaluation reads of one env after a step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvProbe {
    /// Base position (m, world).
    pub base: [f32; 3],
    /// Base height above the terrain under it (m).
    pub height: f32,
    /// Euler pitch, positive nose down (rad).
    pub pitch: f32,
    /// Spawn point of the episode (m, world xy).
    pub origin: [f32; 2],
    /// Command (vx, vy, wz).
    pub command: [f32; 3],
    /// Base velocity in the heading frame (m/s).
    pub velocity_xy: [f32; 2],
    /// Yaw rate (rad/s).
    pub yaw_rate: f32,
    /// Mode in force for the next action.
    pub mode: Option<Mode>,
    /// The episode ended by a termination in this step.
    pub terminated: bool,
    /// The episode ended by time-out in this step.
    pub truncated: bool,
    /// Steps since the episode began.
    pub episode_step: u32,
    /// Bodies other than the feet on the terrain at the end of the step.
    pub contact: BodyContact,
}

/// Which bodies other than the feet touch the terrain, as the sim reads contacts back: from
/// the last physics step of the policy step, so a touch that is over within the step's
/// earlier physics steps goes unseen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct BodyContact {
    /// The trunk (the episode terminates).
    pub trunk: bool,
    /// The head (neither terminating nor penalised).
    pub head: bool,
    /// A thigh or a calf (penalised in training).
    pub legs: bool,
}

impl BodyContact {
    /// Any of them. Hips are left out: the sim counts their contacts without a force, so a
    /// near miss would count; a hip sits on the trunk's corner, which would touch with it.
    pub fn any(&self) -> bool {
        self.trunk || self.head || self.legs
    }
}

/// Read env `i` after the last step.
pub fn probe(env: &VecEnv, i: usize) -> EnvProbe {
    let s = env.robot_state(i);
    let e = env.env_state(i);
    let out = env.output();
    let heading = heading_direction(s.base_rot);
    let v = to_heading_frame(heading, s.base_linvel);
    // The env's own threshold for the trunk and head; thighs and calves are counted by the
    // physics at its (lower) threshold, as the collision penalty reads them.
    let threshold = env.context().config.rewards.contact_threshold;
    EnvProbe {
        base: [s.base_pos.x, s.base_pos.y, s.base_pos.z],
        height: s.base_pos.z - env.terrain().height(s.base_pos.x, s.base_pos.y),
        pitch: euler_pitch(s.base_rot),
        origin: e.origin,
        command: e.command,
        velocity_xy: [v.x, v.y],
        yaw_rate: s.base_angvel.z,
        mode: Mode::from_code(out.mode[i]),
        terminated: out.terminated[i] != 0,
        truncated: out.truncated[i] != 0,
        episode_step: e.episode_step,
        contact: BodyContact {
            trunk: s.trunk_force > threshold,
            head: s.head_force > threshold,
            legs: s.penalised_contacts > 0,
        },
    }
}

/// A batch being rolled out: the envs, their histories and the action buffer.
pub struct Rollout {
    env: VecEnv,
    history: ObsHistory,
    actions: Vec<f32>,
    step: u32,
    settle_steps: u32,
    since_mode_change: Vec<u32>,
    last_mode: Vec<u8>,
    tracking: [TrackingAccumulator; 2],
    head: HeadHits,
    head_before: Vec<bool>,
    upright_settle_steps: u32,
    outcomes: EpisodeOutcomes,
}

impl Rollout {
    /// Start rolling out `env` (its current observations start every history).
    pub fn new(env: VecEnv) -> Self {
        let n = env.num_envs();
        let history = ObsHistory::new(sim_policy_spec(), n, &env.output().obs);
        let dt = env.context().config.policy_dt();
        let settle_steps = (TRACKING_SETTLE_S / dt).round() as u32;
        let upright_settle_steps = (UPRIGHT_SETTLE_S / dt).round() as u32;
        Self {
            last_mode: env.output().mode.clone(),
            history,
            actions: vec![0.0; n * NUM_JOINTS],
            step: 0,
            settle_steps,
            since_mode_change: vec![0; n],
            tracking: Default::default(),
            head: HeadHits::default(),
            head_before: vec![false; n],
            upright_settle_steps,
            outcomes: EpisodeOutcomes::default(),
            env,
        }
    }

    /// The envs.
    pub fn env(&self) -> &VecEnv {
        &self.env
    }

    /// The observation histories the policy reads.
    pub fn history(&self) -> &ObsHistory {
        &self.history
    }

    /// Policy steps taken.
    pub fn steps(&self) -> u32 {
        self.step
    }

    /// Tracking error so far (biped steps count only upright), by mode.
    pub fn tracking(&self, mode: Mode) -> &TrackingAccumulator {
        &self.tracking[match mode {
            Mode::Biped => 0,
            Mode::Quad => 1,
        }]
    }

    /// How the episodes ended so far; episodes still running count as episodes without a
    /// termination.
    pub fn outcomes(&self) -> EpisodeOutcomes {
        let mut o = self.outcomes;
        for i in 0..self.env.num_envs() {
            if self.env.env_state(i).episode_step > 0 {
                o.episodes[mode_index(self.env.output().mode[i])] += 1;
            }
        }
        o
    }

    /// Head contacts so far.
    pub fn head_hits(&self) -> &HeadHits {
        &self.head
    }

    /// Switch the envs whose `mask` entry is non-zero (one entry per env) to `mode` now, with
    /// `command` or, when None, a command drawn from the new mode's ranges (see
    /// [`VecEnv::set_modes`]). The rewritten observations replace the newest entry of the
    /// histories, so the next action (and the policy picked for it, for the two-policy baseline)
    /// already sees the new mode; the older entries stay.
    pub fn set_modes(
        &mut self,
        mask: &[u8],
        mode: Mode,
        command: Option<[f32; 3]>,
    ) -> Result<(), EvalError> {
        self.env.set_modes(mask, mode.task_mode(), command)?;
        // Envs that did not switch are unchanged: their newest entry already is their current
        // observation.
        self.history.replace_newest(&self.env.output().obs);
        Ok(())
    }

    /// Give env `i` the command `commands[i]` where it is `Some`, in the mode it is in (the gait
    /// clock and mode draws run on, see [`VecEnv::set_mode`]); the rewritten observations
    /// replace the newest entry of the histories, so the next action already sees them.
    pub fn set_commands(&mut self, commands: &[Option<[f32; 3]>]) -> Result<(), EvalError> {
        for (i, command) in commands.iter().enumerate() {
            let Some(command) = command else { continue };
            let mode = self.env.env_state(i).mode;
            self.env.set_mode(i, mode, Some(*command))?;
        }
        self.history.replace_newest(&self.env.output().obs);
        Ok(())
    }

    /// One policy step of every env; ended envs start a fresh history with their new first
    /// observation.
    pub fn step(&mut self, policies: &Policies) -> Result<(), EvalError> {
        let out = self.env.output();
        policies.act(&self.history, &out.mode, &mut self.actions)?;
        let out = self.env.step(&self.actions)?;
        let n = out.len();
        let ended: Vec<u8> = (0..n)
            .map(|i| out.terminated[i] | out.truncated[i])
            .collect();
        self.history.push(&out.obs, &ended);
        self.head.add_step(&out.head_contact, &mut self.head_before);
        self.step += 1;
        for (i, &end) in ended.iter().enumerate() {
            let p = probe(&self.env, i);
            if end != 0 {
                // The mode the episode ended in is the one its last action was taken in.
                let m = mode_index(self.last_mode[i]);
                self.outcomes.episodes[m] += 1;
                self.outcomes.terminated[m] += u64::from(p.terminated);
            }
            let code = self.env.output().mode[i];
            if code != self.last_mode[i] || end != 0 {
                self.since_mode_change[i] = 0;
                self.last_mode[i] = code;
            } else {
                self.since_mode_change[i] += 1;
            }
            let in_mode = self.since_mode_change[i].min(p.episode_step);
            if end == 0 && p.mode == Some(Mode::Biped) && in_mode >= self.upright_settle_steps {
                self.outcomes.biped_steps += 1;
                self.outcomes.upright_steps += u64::from(p.pitch > UPRIGHT_PITCH);
                self.outcomes.pitch_sum += f64::from(p.pitch);
            }
            let settled = in_mode >= self.settle_steps;
            if !settled || end != 0 {
                continue;
            }
            match p.mode {
                Some(Mode::Quad) => self.tracking[1].add(p.command, p.velocity_xy, p.yaw_rate),
                Some(Mode::Biped) if p.pitch > UPRIGHT_PITCH => {
                    self.tracking[0].add(p.command, p.velocity_xy, p.yaw_rate)
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// Index of a mode code in per-mode arrays: 0 biped, 1 quad.
fn mode_index(code: u8) -> usize {
    usize::from(code != TaskMode::Biped as u8)
}
