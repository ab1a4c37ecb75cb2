//! The envs as the learner sees them: one step's tensors owned as plain vectors, the
//! observation history the learner keeps (the service sends o_t only), and the per-env episode
//! bookkeeping (client-py's `unigait.env`: `TorchStep`, `ObservationHistory`, `EpisodeStats`).

use std::borrow::Cow;

use unigait_client::{Spec, Step};
use unigait_proto::TensorView;
use unigait_proto::v1;

use crate::{Error, Result};

/// The sizes a session's spec gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Dims {
    /// o_t (53).
    pub obs: usize,
    /// e_t (14).
    pub labels: usize,
    /// s_t (10).
    pub privileged: usize,
    /// Actions per env (12).
    pub actions: usize,
    /// Observations in the history (3).
    pub history_length: usize,
}

impl Dims {
    /// From a session's spec and the config's history length.
    pub fn from_spec(spec: &Spec, history_length: usize) -> Result<Self> {
        let size = |name: &str| {
            spec.row_size(name)
                .ok_or_else(|| Error::Spec(format!("the spec has no `{name}` tensor")))
        };
        let actions = match spec.0.joint_names.len() {
            0 => 12,
            n => n,
        };
        Ok(Self {
            obs: size("obs")?,
            labels: size("labels")?,
            privileged: size("privileged")?,
            actions,
            history_length,
        })
    }

    /// The flat history (H * obs).
    pub fn history(&self) -> usize {
        self.history_length * self.obs
    }

    /// The actor's input: history then the estimate.
    pub fn actor_in(&self) -> usize {
        self.history() + self.labels
    }

    /// The critic's input: o_t, e_t, s_t.
    pub fn critic_in(&self) -> usize {
        self.obs + self.labels + self.privileged
    }
}

/// One batched step, owned (N envs, K of them ended in it).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepData {
    /// f32 [N, obs] o_t after autoreset.
    pub obs: Vec<f32>,
    /// f32 [N, labels].
    pub labels: Vec<f32>,
    /// f32 [N, privileged].
    pub privileged: Vec<f32>,
    /// f32 [N] (zeros for the initial reset).
    pub reward: Vec<f32>,
    /// f32 [N, terms], when the server sent them.
    pub reward_terms: Option<Vec<f32>>,
    /// [N] ended by a trunk contact (or a blow-up): not bootstrapped.
    pub terminated: Vec<bool>,
    /// [N] ended by time-out: bootstrapped from the final critic input.
    pub truncated: Vec<bool>,
    /// [K] envs that ended.
    pub final_env_ids: Vec<usize>,
    /// f32 [K, obs].
    pub final_obs: Vec<f32>,
    /// f32 [K, labels].
    pub final_labels: Vec<f32>,
    /// f32 [K, privileged].
    pub final_privileged: Vec<f32>,
    /// [N] task mode for the next action (1 biped, 2 quad).
    pub mode: Vec<u8>,
    /// [N] terrain level.
    pub terrain_level: Vec<u32>,
    /// The upright indicator's threshold, when the server reports it.
    pub upright_pitch: Option<f32>,
    /// [N] the head touched the terrain in this step (None from servers that do not say).
    pub head_contact: Option<Vec<bool>>,
    /// Envs the server reset after a physics blow-up in this step.
    pub nonfinite_resets: u32,
    /// [N, 2] each env's (quad, biped) levels (empty from servers that do not report them).
    pub mode_levels: Vec<u32>,
}

fn f32s(t: &Option<v1::Tensor>, name: &str) -> Result<Option<Vec<f32>>> {
    t.as_ref()
        .map(|t| t.f32_values(name).map(Cow::into_owned))
        .transpose()
        .map_err(Error::from)
}

fn flags(t: &Option<v1::Tensor>, name: &str, n: usize) -> Result<Vec<bool>> {
    match t {
        Some(t) => Ok(t.u8_values(name)?.iter().map(|&x| x != 0).collect()),
        None => Ok(vec![false; n]),
    }
}

impl StepData {
    /// Copy a reply's tensors, checked against `dims` and `n` envs.
    pub fn from_step(step: &Step, dims: &Dims, n: usize) -> Result<Self> {
        let r = &step.0;
        let obs = step.obs()?.into_owned();
        let labels = step.labels()?.into_owned();
        let privileged = step.privileged()?.into_owned();
        let final_env_ids: Vec<usize> = match &r.final_env_ids {
            Some(t) => t
                .u32_values("final_env_ids")?
                .iter()
                .map(|&e| e as usize)
                .collect(),
            None => Vec::new(),
        };
        let k = final_env_ids.len();
        let data = Self {
            reward: f32s(&r.reward, "reward")?.unwrap_or_else(|| vec![0.0; n]),
            reward_terms: f32s(&r.reward_terms, "reward_terms")?,
            terminated: flags(&r.terminated, "terminated", n)?,
            truncated: flags(&r.truncated, "truncated", n)?,
            final_obs: f32s(&r.final_obs, "final_obs")?.unwrap_or_default(),
            final_labels: f32s(&r.final_labels, "final_labels")?.unwrap_or_default(),
            final_privileged: f32s(&r.final_privileged, "final_privileged")?.unwrap_or_default(),
            mode: match &r.mode {
                Some(t) => t.u8_values("mode")?.to_vec(),
                None => vec![0; n],
            },
            terrain_level: match &r.terrain_level {
                Some(t) => t.u32_values("terrain_level")?.into_owned(),
                None => vec![0; n],
            },
            upright_pitch: r.upright_pitch,
            nonfinite_resets: r.nonfinite_resets,
            mode_levels: match &r.mode_levels {
                Some(t) => t.u32_values("mode_levels")?.into_owned(),
                None => Vec::new(),
            },
            head_contact: match &r.head_contact {
                Some(t) => Some(
                    t.u8_values("head_contact")?
                        .iter()
                        .map(|&x| x != 0)
                        .collect(),
                ),
                None => None,
            },
            obs,
            labels,
            privileged,
            final_env_ids,
        };
        let checks = [
            ("obs", data.obs.len(), n * dims.obs),
            ("labels", data.labels.len(), n * dims.labels),
            ("privileged", data.privileged.len(), n * dims.privileged),
            ("reward", data.reward.len(), n),
            ("terminated", data.terminated.len(), n),
            ("truncated", data.truncated.len(), n),
            ("mode", data.mode.len(), n),
            ("terrain_level", data.terrain_level.len(), n),
            (
                "head_contact",
                data.head_contact.as_ref().map_or(n, Vec::len),
                n,
            ),
            ("final_obs", data.final_obs.len(), k * dims.obs),
            ("final_labels", data.final_labels.len(), k * dims.labels),
            (
                "final_privileged",
                data.final_privileged.len(),
                k * dims.privileged,
            ),
        ];
        for (name, got, expected) in checks {
            if got != expected {
                return Err(Error::Spec(format!(
                    "the reply's `{name}` has {got} values, expected {expected}"
                )));
            }
        }
        if let Some(&e) = data.final_env_ids.iter().find(|&&e| e >= n) {
            return Err(Error::Spec(format!("final env id {e} of {n} envs")));
        }
        Ok(data)
    }

    /// Terminated or truncated, per env.
    pub fn dones(&self) -> Vec<bool> {
        self.terminated
            .iter()
            .zip(&self.truncated)
            .map(|(a, b)| *a || *b)
            .collect()
    }

    /// f32 [N, obs + labels + privileged]: the critic's input.
    pub fn critic_obs(&self, dims: &Dims) -> Vec<f32> {
        critic_rows(
            &self.obs,
            &self.labels,
            &self.privileged,
            dims,
            self.obs.len() / dims.obs.max(1),
        )
    }

    /// f32 [K, obs + labels + privileged]: the critic's input of the ended episodes' last state.
    pub fn final_critic_obs(&self, dims: &Dims) -> Vec<f32> {
        critic_rows(
            &self.final_obs,
            &self.final_labels,
            &self.final_privileged,
            dims,
            self.final_env_ids.len(),
        )
    }
}

fn critic_rows(obs: &[f32], labels: &[f32], privileged: &[f32], d: &Dims, rows: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(rows * d.critic_in());
    for i in 0..rows {
        out.extend_from_slice(&obs[i * d.obs..(i + 1) * d.obs]);
        out.extend_from_slice(&labels[i * d.labels..(i + 1) * d.labels]);
        out.extend_from_slice(&privileged[i * d.privileged..(i + 1) * d.privileged]);
    }
    out
}

/// The last `length` observations per env, newest first: row e is o_t, o_{t-1}, ... of env e.
/// An env that resets gets its whole history filled with its new first observation.
#[derive(Debug, Clone, PartialEq)]
pub struct ObservationHistory {
    length: usize,
    obs_dim: usize,
    /// f32 [N, length * obs_dim].
    pub buffer: Vec<f32>,
}

impl ObservationHistory {
    /// Every env's history filled with its `obs` (f32 [N, obs_dim]).
    pub fn new(obs: &[f32], length: usize, obs_dim: usize) -> Self {
        let n = obs.len() / obs_dim.max(1);
        let mut h = Self {
            length,
            obs_dim,
            buffer: vec![0.0; n * length * obs_dim],
        };
        for e in 0..n {
            h.fill(e, &obs[e * obs_dim..(e + 1) * obs_dim]);
        }
        h
    }

    fn fill(&mut self, e: usize, o: &[f32]) {
        let w = self.length * self.obs_dim;
        for k in 0..self.length {
            self.buffer[e * w + k * self.obs_dim..][..self.obs_dim].copy_from_slice(o);
        }
    }

    /// Append o_t (f32 [N, obs_dim]); envs where `reset` holds start a fresh history with it.
    pub fn push(&mut self, obs: &[f32], reset: &[bool]) {
        let (d, w) = (self.obs_dim, self.length * self.obs_dim);
        for (e, &r) in reset.iter().enumerate() {
            let o = &obs[e * d..(e + 1) * d];
            if r {
                self.fill(e, o);
            } else {
                let row = &mut self.buffer[e * w..(e + 1) * w];
                row.copy_within(0..w - d, d);
                row[..d].copy_from_slice(o);
            }
        }
    }
}

/// What the episodes that ended in one rollout summed to.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Ended {
    /// Total reward per episode.
    pub reward: Vec<f64>,
    /// Length in steps per episode.
    pub length: Vec<u64>,
    /// Sum of every reward term, over the episodes (`[terms]`).
    pub terms: Vec<f64>,
    /// Episodes that ended by time-out alone.
    pub time_outs: u64,
}

/// Running sums of the total reward and of every reward term, per env.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeStats {
    terms: usize,
    reward_sum: Vec<f64>,
    term_sums: Vec<f64>,
    length: Vec<u64>,
}

impl EpisodeStats {
    /// For `n` envs and `terms` reward terms.
    pub fn new(n: usize, terms: usize) -> Self {
        Self {
            terms,
            reward_sum: vec![0.0; n],
            term_sums: vec![0.0; n * terms],
            length: vec![0; n],
        }
    }

    /// Add one step; the episodes that ended in it go into `ended`.
    pub fn update(&mut self, step: &StepData, ended: &mut Ended) {
        let t = self.terms;
        if ended.terms.len() != t {
            ended.terms = vec![0.0; t];
        }
        for e in 0..self.reward_sum.len() {
            self.reward_sum[e] += f64::from(step.reward[e]);
            if let Some(rt) = &step.reward_terms {
                for (s, v) in self.term_sums[e * t..(e + 1) * t]
                    .iter_mut()
                    .zip(&rt[e * t..(e + 1) * t])
                {
                    *s += f64::from(*v);
                }
            }
            self.length[e] += 1;
            if step.terminated[e] || step.truncated[e] {
                ended.reward.push(self.reward_sum[e]);
                ended.length.push(self.length[e]);
                for (acc, s) in ended
                    .terms
                    .iter_mut()
                    .zip(&self.term_sums[e * t..(e + 1) * t])
                {
                    *acc += s;
                }
                if step.truncated[e] && !step.terminated[e] {
                    ended.time_outs += 1;
                }
                self.reward_sum[e] = 0.0;
                self.term_sums[e * t..(e + 1) * t].fill(0.0);
                self.length[e] = 0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two envs, o of size 2, history 3: env 1 resets at the second push.
    #[test]
    fn history_shifts_newest_first_and_refills_on_reset() {
        let mut h = ObservationHistory::new(&[1.0, 1.5, 2.0, 2.5], 3, 2);
        assert_eq!(&h.buffer[..6], &[1.0, 1.5, 1.0, 1.5, 1.0, 1.5]);
        h.push(&[3.0, 3.5, 4.0, 4.5], &[false, false]);
        assert_eq!(&h.buffer[..6], &[3.0, 3.5, 1.0, 1.5, 1.0, 1.5]);
        assert_eq!(&h.buffer[6..], &[4.0, 4.5, 2.0, 2.5, 2.0, 2.5]);
        h.push(&[5.0, 5.5, 6.0, 6.5], &[false, true]);
        assert_eq!(&h.buffer[..6], &[5.0, 5.5, 3.0, 3.5, 1.0, 1.5]);
        assert_eq!(&h.buffer[6..], &[6.0, 6.5, 6.0, 6.5, 6.0, 6.5]);
    }

    fn step(reward: [f32; 2], terms: [f32; 4], term: [bool; 2], trunc: [bool; 2]) -> StepData {
        StepData {
            reward: reward.to_vec(),
            reward_terms: Some(terms.to_vec()),
            terminated: term.to_vec(),
            truncated: trunc.to_vec(),
            ..Default::default()
        }
    }

    /// Env 0 times out after 2 steps (reward 1 + 2, terms [0.5 + 1, 0.5 + 1]); env 1
    /// terminates after 1 (reward 5, terms [4, 1]) and then runs on.
    #[test]
    fn episodes_sum_until_they_end() {
        let mut s = EpisodeStats::new(2, 2);
        let mut ended = Ended::default();
        s.update(
            &step(
                [1.0, 5.0],
                [0.5, 0.5, 4.0, 1.0],
                [false, true],
                [false, false],
            ),
            &mut ended,
        );
        s.update(
            &step(
                [2.0, 7.0],
                [1.0, 1.0, 3.0, 4.0],
                [false, false],
                [true, false],
            ),
            &mut ended,
        );
        assert_eq!(ended.reward, [5.0, 3.0]);
        assert_eq!(ended.length, [1, 2]);
        assert_eq!(ended.terms, [4.0 + 1.5, 1.0 + 1.5]);
        assert_eq!(ended.time_outs, 1);
        // env 1's second episode holds 7 so far.
        assert_eq!(s.reward_sum, [0.0, 7.0]);
    }

    #[test]
    fn critic_rows_concatenate_o_e_s() {
        let d = Dims {
            obs: 2,
            labels: 1,
            privileged: 1,
            actions: 1,
            history_length: 1,
        };
        let s = StepData {
            obs: vec![1.0, 2.0, 3.0, 4.0],
            labels: vec![5.0, 6.0],
            privileged: vec![7.0, 8.0],
            final_env_ids: vec![1],
            final_obs: vec![9.0, 10.0],
            final_labels: vec![11.0],
            final_privileged: vec![12.0],
            ..Default::default()
        };
        assert_eq!(s.critic_obs(&d), [1.0, 2.0, 5.0, 7.0, 3.0, 4.0, 6.0, 8.0]);
        assert_eq!(s.final_critic_obs(&d), [9.0, 10.0, 11.0, 12.0]);
    }
}
