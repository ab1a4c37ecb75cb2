//! The policy interface and its shape contract.

use crate::error::PolicyError;

/// The shapes a policy must fit: input `[batch, history, obs_dim]`, output `[batch, num_actions]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PolicySpec {
    /// Observations in the history (o_t first). Default 3.
    pub history: usize,
    /// Values per observation. Default 53.
    pub obs_dim: usize,
    /// Actions per env. Default 12.
    pub num_actions: usize,
}

impl Default for PolicySpec {
    fn default() -> Self {
        Self {
            history: 3,
            obs_dim: 53,
            num_actions: 12,
        }
    }
}

impl PolicySpec {
    /// Values in one env's history row: `history * obs_dim` (159 by default).
    pub fn input_width(&self) -> usize {
        self.history * self.obs_dim
    }

    /// Check a batch of histories: `batch * input_width` values.
    pub fn check_batch(&self, history: &[f32], batch: usize) -> Result<(), PolicyError> {
        let expected = batch * self.input_width();
        if history.len() != expected {
            return Err(PolicyError::Batch {
                got: history.len(),
                expected,
                detail: format!("[{batch}, {}, {}]", self.history, self.obs_dim),
            });
        }
        Ok(())
    }

    /// Check an [`Policy::act`] call: histories `[batch, history, obs_dim]` and an action buffer
    /// `[batch, num_actions]`.
    pub fn check_call(
        &self,
        history: &[f32],
        batch: usize,
        actions: &[f32],
    ) -> Result<(), PolicyError> {
        self.check_batch(history, batch)?;
        if actions.len() != batch * self.num_actions {
            return Err(PolicyError::Batch {
                got: actions.len(),
                expected: batch * self.num_actions,
                detail: format!("action buffer [{batch}, {}]", self.num_actions),
            });
        }
        Ok(())
    }
}

/// Something that maps observation histories to actions, batched.
pub trait Policy: Send + Sync {
    /// The shapes this policy fits.
    fn spec(&self) -> PolicySpec;

    /// Actions `[batch, num_actions]` into `actions` from histories `[batch, history, obs_dim]`.
    fn act(&self, history: &[f32], batch: usize, actions: &mut [f32]) -> Result<(), PolicyError>;

    /// Allocating form of [`Policy::act`].
    fn act_vec(&self, history: &[f32], batch: usize) -> Result<Vec<f32>, PolicyError> {
        let mut actions = vec![0.0; batch * self.spec().num_actions];
        self.act(history, batch, &mut actions)?;
        Ok(actions)
    }
}

/// A policy that always returns the same action (zeros: stand at the default pose).
#[derive(Clone, Debug, PartialEq)]
pub struct ConstantPolicy {
    spec: PolicySpec,
    action: Vec<f32>,
}

impl ConstantPolicy {
    /// A policy returning `action` (length `spec.num_actions`, else padded or cut with zeros).
    pub fn new(spec: PolicySpec, mut action: Vec<f32>) -> Self {
        action.resize(spec.num_actions, 0.0);
        Self { spec, action }
    }

    /// The zero action: joint targets at the default pose.
    pub fn zeros(spec: PolicySpec) -> Self {
        Self::new(spec, Vec::new())
    }
}

impl Policy for ConstantPolicy {
    fn spec(&self) -> PolicySpec {
        self.spec
    }

    fn act(&self, history: &[f32], batch: usize, actions: &mut [f32]) -> Result<(), PolicyError> {
        self.spec.check_batch(history, batch)?;
        for row in actions.chunks_mut(self.spec.num_actions).take(batch) {
            row.copy_from_slice(&self.action);
        }
        Ok(())
    }
}
