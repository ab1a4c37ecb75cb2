//! The index of an env in its batch.

/// Index of an env in a [`super::VecEnv`] (0-based, stable for the batch's lifetime).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(transparent)]
pub struct EnvId(pub u32);

impl EnvId {
    /// As a slice index.
    pub fn index(self) -> usize {
        self.0 as usize
    }
}
