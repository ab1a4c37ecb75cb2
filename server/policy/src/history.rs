//! The observation history a policy reads: o_t, o_{t-1}, o_{t-2} per env.

use crate::policy::PolicySpec;

/// Per-env observation histories, `[num_envs, history, obs_dim]` row-major, newest first.
///
/// An env that starts a new episode gets its whole history filled with its first observation
/// (as the Python learner's `ObsHistory` does), so the policy never sees the previous episode.
#[derive(Clone, Debug, PartialEq)]
pub struct ObsHistory {
    spec: PolicySpec,
    num_envs: usize,
    buffer: Vec<f32>,
}

impl ObsHistory {
    /// Histories of `num_envs` envs, all filled from `obs` (`[num_envs, obs_dim]`).
    pub fn new(spec: PolicySpec, num_envs: usize, obs: &[f32]) -> Self {
        let mut h = Self {
            spec,
            num_envs,
            buffer: vec![0.0; num_envs * spec.input_width()],
        };
        for env in 0..num_envs {
            h.reset_env(env, &obs[env * spec.obs_dim..(env + 1) * spec.obs_dim]);
        }
        h
    }

    /// Number of envs.
    pub fn num_envs(&self) -> usize {
        self.num_envs
    }

    /// The flat buffer, ready for [`crate::Policy::act`].
    pub fn as_slice(&self) -> &[f32] {
        &self.buffer
    }

    /// History of env `env`: `history * obs_dim` values, o_t first.
    pub fn env(&self, env: usize) -> &[f32] {
        let w = self.spec.input_width();
        &self.buffer[env * w..(env + 1) * w]
    }

    /// Start env `env`'s history afresh: every slot holds `first_obs`.
    pub fn reset_env(&mut self, env: usize, first_obs: &[f32]) {
        let w = self.spec.input_width();
        for slot in self.buffer[env * w..(env + 1) * w].chunks_mut(self.spec.obs_dim) {
            slot.copy_from_slice(first_obs);
        }
    }

    /// Overwrite every env's newest entry (o_t) with `obs` (`[num_envs, obs_dim]`), the older
    /// entries unchanged: for an observation rewritten in place (a mode switch) rather than a
    /// new step.
    pub fn replace_newest(&mut self, obs: &[f32]) {
        let (d, w) = (self.spec.obs_dim, self.spec.input_width());
        for (row, o) in self.buffer.chunks_mut(w).zip(obs.chunks(d)) {
            row[..d].copy_from_slice(o);
        }
    }

    /// Push the new observations `obs` (`[num_envs, obs_dim]`); envs whose `reset` entry is
    /// non-zero began a new episode with this observation and get a fresh history.
    pub fn push(&mut self, obs: &[f32], reset: &[u8]) {
        let (d, w) = (self.spec.obs_dim, self.spec.input_width());
        for env in 0..self.num_envs {
            let o = &obs[env * d..(env + 1) * d];
            if reset.get(env).copied().unwrap_or(0) != 0 {
                self.reset_env(env, o);
                continue;
            }
            let row = &mut self.buffer[env * w..(env + 1) * w];
            row.copy_within(0..w - d, d);
            row[..d].copy_from_slice(o);
        }
    }
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn push_shifts_and_reset_refills() {
        let spec = PolicySpec {
            history: 3,
            obs_dim: 2,
            num_actions: 1,
        };
        let mut h = ObsHistory::new(spec, 2, &[1.0, 1.0, 5.0, 5.0]);
        assert_eq!(h.env(0), &[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]);
        h.push(&[2.0, 2.0, 6.0, 6.0], &[0, 0]);
        h.push(&[3.0, 3.0, 7.0, 7.0], &[0, 1]);
        assert_eq!(h.env(0), &[3.0, 3.0, 2.0, 2.0, 1.0, 1.0]);
        assert_eq!(h.env(1), &[7.0, 7.0, 7.0, 7.0, 7.0, 7.0]);
        h.replace_newest(&[4.0, 4.0, 8.0, 8.0]);
        assert_eq!(h.env(0), &[4.0, 4.0, 2.0, 2.0, 1.0, 1.0]);
        assert_eq!(h.env(1), &[8.0, 8.0, 7.0, 7.0, 7.0, 7.0]);
    }
}
