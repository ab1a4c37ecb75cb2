//! The batch's per-step results: flat, env-major arrays, ready to be sent as tensors.

use crate::robot::NUM_JOINTS;
use crate::task::{LABEL_DIM, OBS_DIM, PRIVILEGED_DIM, RewardTerm};

/// Results of one batched step (or of a reset) for N envs. Row `i` of each array is env `i`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepOutput {
    /// o_t after autoreset: [N, 53].
    pub obs: Vec<f32>,
    /// e_t estimator labels: [N, 14].
    pub labels: Vec<f32>,
    /// s_t privileged randomisation values: [N, 10].
    pub privileged: Vec<f32>,
    /// Total reward: [N].
    pub reward: Vec<f32>,
    /// Weighted reward per term: [N, RewardTerm::COUNT] (RewardTerm order).
    pub reward_terms: Vec<f32>,
    /// The episode ended by a trunk contact (or a physics blow-up): [N], 0/1.
    pub terminated: Vec<u8>,
    /// The episode ended by time-out: [N], 0/1.
    pub truncated: Vec<u8>,
    /// For envs that ended: o of the final state before the reset, [N, 53] (zeros elsewhere).
    pub final_obs: Vec<f32>,
    /// For envs that ended: e of the final state, [N, 14].
    pub final_labels: Vec<f32>,
    /// For envs that ended: s of the final state, [N, 10].
    pub final_privileged: Vec<f32>,
    /// Length in steps of the episode that ended (0 where none ended): [N].
    pub episode_length: Vec<u32>,
    /// Task mode x (1 biped, 2 quad) in force for the next action: [N].
    pub mode: Vec<u8>,
    /// Terrain difficulty level of each env: [N].
    pub terrain_level: Vec<u32>,
    /// Each env's own level per mode, (quad, biped): [N, 2]. Both are `terrain_level` unless
    /// the curriculum keeps a level per mode (decision record 0036).
    pub mode_levels: Vec<u32>,
    /// 1 where the env's physics turned non-finite this step and it was reset: [N].
    pub nonfinite: Vec<u8>,
    /// 1 where the robot's head touched the terrain during the step (neither terminating nor
    /// penalised; the paper's failure on biped stairs): [N].
    pub head_contact: Vec<u8>,
    /// Motor torques of the last physics step: [N, 12].
    pub torques: Vec<f32>,
    /// Pitch above which the upright indicator fires from the next step on (rad): the task's
    /// `rewards.upright_pitch`, or where its upright curriculum has got to.
    pub upright_pitch: f32,
}

impl StepOutput {
    /// Zeroed arrays for `n` envs.
    pub fn new(n: usize) -> Self {
        Self {
            obs: vec![0.0; n * OBS_DIM],
            labels: vec![0.0; n * LABEL_DIM],
            privileged: vec![0.0; n * PRIVILEGED_DIM],
            reward: vec![0.0; n],
            reward_terms: vec![0.0; n * RewardTerm::COUNT],
            terminated: vec![0; n],
            truncated: vec![0; n],
            final_obs: vec![0.0; n * OBS_DIM],
            final_labels: vec![0.0; n * LABEL_DIM],
            final_privileged: vec![0.0; n * PRIVILEGED_DIM],
            episode_length: vec![0; n],
            mode: vec![0; n],
            terrain_level: vec![0; n],
            mode_levels: vec![0; 2 * n],
            nonfinite: vec![0; n],
            head_contact: vec![0; n],
            torques: vec![0.0; n * NUM_JOINTS],
            upright_pitch: 0.0,
        }
    }

    /// Number of envs.
    pub fn len(&self) -> usize {
        self.reward.len()
    }

    /// Whether it holds no env.
    pub fn is_empty(&self) -> bool {
        self.reward.is_empty()
    }

    /// After a reset: no episode ended and no reward was earned, whatever the last step said.
    pub fn forget_episode_ends(&mut self) {
        self.terminated.fill(0);
        self.truncated.fill(0);
        self.episode_length.fill(0);
        self.reward.fill(0.0);
        self.reward_terms.fill(0.0);
    }

    /// Split into consecutive chunks of `envs` envs each (the last may be shorter).
    pub fn chunks_mut(&mut self, envs: usize) -> Vec<OutputChunk<'_>> {
        let mut obs = self.obs.chunks_mut(envs * OBS_DIM);
        let mut labels = self.labels.chunks_mut(envs * LABEL_DIM);
        let mut privileged = self.privileged.chunks_mut(envs * PRIVILEGED_DIM);
        let mut reward = self.reward.chunks_mut(envs);
        let mut reward_terms = self.reward_terms.chunks_mut(envs * RewardTerm::COUNT);
        let mut terminated = self.terminated.chunks_mut(envs);
        let mut truncated = self.truncated.chunks_mut(envs);
        let mut final_obs = self.final_obs.chunks_mut(envs * OBS_DIM);
        let mut final_labels = self.final_labels.chunks_mut(envs * LABEL_DIM);
        let mut final_privileged = self.final_privileged.chunks_mut(envs * PRIVILEGED_DIM);
        let mut episode_length = self.episode_length.chunks_mut(envs);
        let mut mode = self.mode.chunks_mut(envs);
        let mut terrain_level = self.terrain_level.chunks_mut(envs);
        let mut mode_levels = self.mode_levels.chunks_mut(2 * envs);
        let mut nonfinite = self.nonfinite.chunks_mut(envs);
        let mut head_contact = self.head_contact.chunks_mut(envs);
        let mut torques = self.torques.chunks_mut(envs * NUM_JOINTS);
        let mut chunks = Vec::new();
        for reward in reward.by_ref() {
            // Every array has the same number of chunks, so the other iterators cannot run dry.
            chunks.push(OutputChunk {
                obs: obs.next().unwrap_or_default(),
                labels: labels.next().unwrap_or_default(),
                privileged: privileged.next().unwrap_or_default(),
                reward,
                reward_terms: reward_terms.next().unwrap_or_default(),
                terminated: terminated.next().unwrap_or_default(),
                truncated: truncated.next().unwrap_or_default(),
                final_obs: final_obs.next().unwrap_or_default(),
                final_labels: final_labels.next().unwrap_or_default(),
                final_privileged: final_privileged.next().unwrap_or_default(),
                episode_length: episode_length.next().unwrap_or_default(),
                mode: mode.next().unwrap_or_default(),
                terrain_level: terrain_level.next().unwrap_or_default(),
                mode_levels: mode_levels.next().unwrap_or_default(),
                nonfinite: nonfinite.next().unwrap_or_default(),
                head_contact: head_contact.next().unwrap_or_default(),
                torques: torques.next().unwrap_or_default(),
            });
        }
        chunks
    }
}

/// Mutable views of a [`StepOutput`] for one group of envs.
#[allow(missing_docs)]
pub struct OutputChunk<'a> {
    pub obs: &'a mut [f32],
    pub labels: &'a mut [f32],
    pub privileged: &'a mut [f32],
    pub reward: &'a mut [f32],
    pub reward_terms: &'a mut [f32],
    pub terminated: &'a mut [u8],
    pub truncated: &'a mut [u8],
    pub final_obs: &'a mut [f32],
    pub final_labels: &'a mut [f32],
    pub final_privileged: &'a mut [f32],
    pub episode_length: &'a mut [u32],
    pub mode: &'a mut [u8],
    pub terrain_level: &'a mut [u32],
    pub mode_levels: &'a mut [u32],
    pub nonfinite: &'a mut [u8],
    pub head_contact: &'a mut [u8],
    pub torques: &'a mut [f32],
}
