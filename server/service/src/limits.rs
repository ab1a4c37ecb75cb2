//! Server limits and the message size they imply.

/// Upper bounds a server enforces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Envs per session.
    pub max_envs_per_session: usize,
    /// Concurrent sessions.
    pub max_sessions: usize,
    /// Seconds a session may stay unused before it is closed.
    pub idle_timeout_s: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_envs_per_session: 8192,
            max_sessions: 16,
            idle_timeout_s: 600,
        }
    }
}

/// Bytes of one env's share of the largest step reply: obs, labels, privileged, reward, reward
/// terms, flags, mode, level and the final rows (all envs may end at once), with headroom.
const BYTES_PER_ENV: usize = 1024;

impl Limits {
    /// The largest message either side may send (bytes): fits the largest batch.
    pub fn max_message_bytes(&self) -> usize {
        self.max_envs_per_session * BYTES_PER_ENV + (1 << 20)
    }
}
