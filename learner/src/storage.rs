//! Rollout buffer of T steps x N envs: one row of every per-sample field, returns and shuffles.

use crate::gae;

/// Column layout of a sample row: labels first (the estimator's inputs are one leading block
/// with the history), then everything PPO reads.
#[derive(Debug, Clone, Copy)]
pub struct Layout {
    /// Estimator target size (14).
    pub labels: usize,
    /// Actor input (history + estimate, 173).
    pub actor_obs: usize,
    /// Estimator input: the first `history` columns of the actor input (159).
    pub history: usize,
    /// Critic input (77).
    pub critic_obs: usize,
    /// Action size (12).
    pub actions: usize,
}

impl Layout {
    /// First column of the actor input.
    pub fn actor_col(&self) -> usize {
        self.labels
    }
    /// First column of the critic input.
    pub fn critic_col(&self) -> usize {
        self.actor_col() + self.actor_obs
    }
    /// First column of the actions.
    pub fn actions_col(&self) -> usize {
        self.critic_col() + self.critic_obs
    }
    /// Old log-probability.
    pub fn log_prob_col(&self) -> usize {
        self.actions_col() + self.actions
    }
    /// First column of the old mean.
    pub fn mu_col(&self) -> usize {
        self.log_prob_col() + 1
    }
    /// First column of the old std.
    pub fn sigma_col(&self) -> usize {
        self.mu_col() + self.actions
    }
    /// Old value.
    pub fn value_col(&self) -> usize {
        self.sigma_col() + self.actions
    }
    /// Advantage.
    pub fn advantage_col(&self) -> usize {
        self.value_col() + 1
    }
    /// Return.
    pub fn return_col(&self) -> usize {
        self.advantage_col() + 1
    }
    /// Row width.
    pub fn width(&self) -> usize {
        self.return_col() + 1
    }
}

/// One step of N envs, each field row-major `[N, width]`.
#[derive(Debug, Clone, Copy)]
pub struct Step<'a> {
    /// f32 [N, actor_obs].
    pub actor_obs: &'a [f32],
    /// f32 [N, critic_obs].
    pub critic_obs: &'a [f32],
    /// f32 [N, labels]: e_t of the observation the actor acted on.
    pub labels: &'a [f32],
    /// f32 [N, actions].
    pub actions: &'a [f32],
    /// f32 [N].
    pub log_prob: &'a [f32],
    /// f32 [N, actions].
    pub mu: &'a [f32],
    /// f32 [N, actions].
    pub sigma: &'a [f32],
    /// f32 [N].
    pub values: &'a [f32],
    /// f32 [N] rewards (time-out bootstrap already added).
    pub rewards: &'a [f32],
    /// bool [N]: the episode ended after this step.
    pub dones: &'a [bool],
}

/// A fixed-size rollout: `data` is f32 [T * N, width], step-major.
#[derive(Debug)]
pub struct RolloutStorage {
    /// The column layout.
    pub layout: Layout,
    /// T.
    pub num_steps: usize,
    /// N.
    pub num_envs: usize,
    /// f32 [T * N, width].
    pub data: Vec<f32>,
    rewards: Vec<f32>,
    dones: Vec<bool>,
    step: usize,
}

/// Errors of the storage.
#[derive(Debug, thiserror::Error)]
pub enum StorageError {
    /// `add` past T steps.
    #[error("rollout storage is full ({0} steps); clear it first")]
    Full(usize),
    /// A field of the wrong length.
    #[error("field {name} has {got} values, expected {expected}")]
    Length {
        /// The field.
        name: &'static str,
        /// Its length.
        got: usize,
        /// N x its width.
        expected: usize,
    },
}

/// The largest magnitude of one stored field, and where it sits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Largest {
    /// |value| (infinite for a NaN).
    pub magnitude: f32,
    /// The rollout step.
    pub step: usize,
    /// The env.
    pub env: usize,
    /// The column within the field.
    pub column: usize,
}

impl RolloutStorage {
    /// An empty rollout of `num_steps` x `num_envs`.
    pub fn new(num_steps: usize, num_envs: usize, layout: Layout) -> Self {
        Self {
            layout,
            num_steps,
            num_envs,
            data: vec![0.0; num_steps * num_envs * layout.width()],
            rewards: vec![0.0; num_steps * num_envs],
            dones: vec![false; num_steps * num_envs],
            step: 0,
        }
    }

    /// Store the next step.
    pub fn add(&mut self, s: &Step) -> Result<(), StorageError> {
        if self.step >= self.num_steps {
            return Err(StorageError::Full(self.num_steps));
        }
        let (n, l) = (self.num_envs, self.layout);
        let fields: [(&'static str, &[f32], usize, usize); 8] = [
            ("labels", s.labels, 0, l.labels),
            ("actor_obs", s.actor_obs, l.actor_col(), l.actor_obs),
            ("critic_obs", s.critic_obs, l.critic_col(), l.critic_obs),
            ("actions", s.actions, l.actions_col(), l.actions),
            ("log_prob", s.log_prob, l.log_prob_col(), 1),
            ("mu", s.mu, l.mu_col(), l.actions),
            ("sigma", s.sigma, l.sigma_col(), l.actions),
            ("values", s.values, l.value_col(), 1),
        ];
        for (name, src, _, w) in fields {
            if src.len() != n * w {
                return Err(StorageError::Length {
                    name,
                    got: src.len(),
                    expected: n * w,
                });
            }
        }
        for (name, got) in [("rewards", s.rewards.len()), ("dones", s.dones.len())] {
            if got != n {
                return Err(StorageError::Length {
                    name,
                    got,
                    expected: n,
                });
            }
        }
        let width = l.width();
        for e in 0..n {
            let row = &mut self.data[((self.step * n) + e) * width..][..width];
            for (_, src, col, w) in fields {
                row[col..col + w].copy_from_slice(&src[e * w..(e + 1) * w]);
            }
        }
        let base = self.step * n;
        self.rewards[base..base + n].copy_from_slice(s.rewards);
        self.dones[base..base + n].copy_from_slice(s.dones);
        self.step += 1;
        Ok(())
    }

    /// Per stored field (labels, actor and critic inputs, actions, means, values, rewards), the
    /// largest magnitude so far and where it sits; NaN counts as infinite, and the first of equal
    /// magnitudes wins (the Python learner's `RolloutStorage.largest`, decision record 0031).
    pub fn largest(&self) -> Vec<(&'static str, Largest)> {
        let (n, l, width) = (self.num_envs, self.layout, self.layout.width());
        let rows = self.step * n;
        let magnitude = |v: f32| if v.is_nan() { f32::INFINITY } else { v.abs() };
        let scan = |values: &mut dyn Iterator<Item = (usize, usize, f32)>| {
            let mut best = Largest {
                magnitude: -1.0,
                step: 0,
                env: 0,
                column: 0,
            };
            for (row, column, v) in values {
                let m = magnitude(v);
                if m > best.magnitude {
                    best = Largest {
                        magnitude: m,
                        step: row / n,
                        env: row % n,
                        column,
                    };
                }
            }
            best
        };
        let blocks = [
            ("labels", 0, l.labels),
            ("actor_obs", l.actor_col(), l.actor_obs),
            ("critic_obs", l.critic_col(), l.critic_obs),
            ("actions", l.actions_col(), l.actions),
            ("mu", l.mu_col(), l.actions),
            ("values", l.value_col(), 1),
        ];
        let mut out: Vec<(&'static str, Largest)> = blocks
            .iter()
            .map(|&(name, col, w)| {
                let mut cells = (0..rows)
                    .flat_map(|r| (0..w).map(move |c| (r, c, self.data[r * width + col + c])));
                (name, scan(&mut cells))
            })
            .collect();
        let mut rewards = self.rewards[..rows]
            .iter()
            .enumerate()
            .map(|(r, &v)| (r, 0, v));
        out.push(("rewards", scan(&mut rewards)));
        out.retain(|(_, b)| b.magnitude >= 0.0);
        out
    }

    /// Start a new rollout.
    pub fn clear(&mut self) {
        self.step = 0;
    }

    /// GAE over the stored rollout; advantages normalised over the whole batch if asked.
    pub fn compute_returns(&mut self, last_values: &[f32], gamma: f32, lam: f32, normalize: bool) {
        let (w, l) = (self.layout.width(), self.layout);
        let values: Vec<f32> = self.data.chunks(w).map(|r| r[l.value_col()]).collect();
        let (mut adv, ret) =
            gae::compute_gae(&self.rewards, &values, &self.dones, last_values, gamma, lam);
        if normalize {
            gae::normalize(&mut adv);
        }
        for ((row, a), r) in self.data.chunks_mut(w).zip(adv).zip(ret) {
            row[l.advantage_col()] = a;
            row[l.return_col()] = r;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAYOUT: Layout = Layout {
        labels: 1,
        actor_obs: 2,
        history: 1,
        critic_obs: 1,
        actions: 1,
    };

    #[test]
    fn rows_hold_each_field_and_returns() {
        let mut s = RolloutStorage::new(2, 1, LAYOUT);
        assert_eq!(LAYOUT.width(), 11);
        for t in 0..2 {
            let v = t as f32;
            s.add(&Step {
                actor_obs: &[10.0 + v, 20.0 + v],
                critic_obs: &[30.0],
                labels: &[40.0],
                actions: &[0.5],
                log_prob: &[-1.0],
                mu: &[0.1],
                sigma: &[1.0],
                values: &[1.0],
                rewards: &[1.0],
                dones: &[false],
            })
            .unwrap();
        }
        assert!(matches!(
            s.add(&Step {
                actor_obs: &[],
                critic_obs: &[],
                labels: &[],
                actions: &[],
                log_prob: &[],
                mu: &[],
                sigma: &[],
                values: &[],
                rewards: &[],
                dones: &[]
            }),
            Err(StorageError::Full(2))
        ));
        // gamma 1, lambda 1, last value 0: A1 = 1 + 0 - 1 = 0, A0 = 1 + 1 - 1 + 0 = 1.
        s.compute_returns(&[0.0], 1.0, 1.0, false);
        let row0 = &s.data[..11];
        assert_eq!(
            row0,
            &[40.0, 10.0, 20.0, 30.0, 0.5, -1.0, 0.1, 1.0, 1.0, 1.0, 2.0]
        );
        assert_eq!(&s.data[11 + 9..], &[0.0, 1.0]);
    }

    /// Three steps of two envs: a label of -7.5 at step 1, env 1 and a NaN in the actor input
    /// at step 2, env 0, column 1 are found there; NaN counts as infinite.
    #[test]
    fn the_largest_value_of_each_field_and_where_it_sits() {
        let mut s = RolloutStorage::new(3, 2, LAYOUT);
        for t in 0..3 {
            let labels = if t == 1 { [0.5, -7.5] } else { [0.5, 0.5] };
            let actor = if t == 2 {
                [1.0, f32::NAN, 1.0, 1.0]
            } else {
                [1.0; 4]
            };
            s.add(&Step {
                actor_obs: &actor,
                critic_obs: &[0.0, 0.0],
                labels: &labels,
                actions: &[0.5, -2.0],
                log_prob: &[-1.0, -1.0],
                mu: &[0.1, 0.1],
                sigma: &[1.0, 1.0],
                values: &[1.0, 3.0],
                rewards: &[0.25, 0.0],
                dones: &[false, false],
            })
            .unwrap();
        }
        let largest: std::collections::HashMap<_, _> = s.largest().into_iter().collect();
        let at = |m: f32, step: usize, env: usize, column: usize| Largest {
            magnitude: m,
            step,
            env,
            column,
        };
        assert_eq!(largest["labels"], at(7.5, 1, 1, 0));
        assert_eq!(largest["actor_obs"], at(f32::INFINITY, 2, 0, 1));
        assert_eq!(largest["critic_obs"], at(0.0, 0, 0, 0));
        assert_eq!(largest["actions"], at(2.0, 0, 1, 0));
        assert_eq!(largest["values"], at(3.0, 0, 1, 0));
        assert_eq!(largest["rewards"], at(0.25, 0, 0, 0));
        assert_eq!(largest.len(), 7);
    }

    #[test]
    fn wrong_lengths_are_errors() {
        let mut s = RolloutStorage::new(1, 2, LAYOUT);
        let err = s
            .add(&Step {
                actor_obs: &[0.0; 3],
                critic_obs: &[0.0; 2],
                labels: &[0.0; 2],
                actions: &[0.0; 2],
                log_prob: &[0.0; 2],
                mu: &[0.0; 2],
                sigma: &[0.0; 2],
                values: &[0.0; 2],
                rewards: &[0.0; 2],
                dones: &[false; 2],
            })
            .unwrap_err();
        assert!(matches!(
            err,
            StorageError::Length {
                name: "actor_obs",
                got: 3,
                expected: 4
            }
        ));
    }
}
