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
    /// Envs over all sessions (reserved before a session's envs are built).
    pub max_total_envs: usize,
    /// Seconds a step stream may wait for the client's next request before it is ended (a
    /// half-open connection from a crashed learner host). The session stays, for the client
    /// to re-attach, until the idle timeout.
    pub stream_idle_timeout_s: u64,
    /// Cost caps on what a session's TOML overrides may set.
    pub cost: CostCaps,
    /// Bytes of a session's TOML overrides.
    pub max_overrides_bytes: usize,
    /// Nesting depth of a session's TOML overrides (tables, arrays, dotted keys).
    pub max_overrides_depth: usize,
    /// Evaluations running at once.
    pub max_concurrent_evaluations: usize,
    /// Seconds one evaluation may run.
    pub max_evaluation_s: u64,
    /// Bytes of an Evaluate reply (the recording included).
    pub max_evaluation_reply_bytes: usize,
    /// Bytes of one client ONNX policy.
    pub max_policy_bytes: usize,
    /// Calls on one session in flight at once (running, or waiting for the session); more are
    /// refused, so one client's flood waits on no one else's blocking threads.
    pub max_calls_per_session: usize,
}

/// Caps on the settings that set the cost of one step, so that one Step cannot hold the shared
/// worker pool for minutes. The defaults allow twice the default task's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CostCaps {
    /// `env.decimation` (physics steps per env step). Default 8 (task default 4).
    pub max_decimation: usize,
    /// `physics.solver_iterations`. Default 4 (task default 2).
    pub max_solver_iterations: usize,
    /// `physics.pgs_iterations`. Default 6 (task default 3).
    pub max_pgs_iterations: usize,
    /// `physics.extra_iterations_on_leg_contact`. Default 2 (task default 0).
    pub max_extra_iterations: usize,
    /// `physics.extra_pgs_iterations_on_leg_contact`. Default 12 (task default 6).
    pub max_extra_pgs_iterations: usize,
    /// `env.envs_per_world` (one world is stepped by one thread). Default 64 (task default 32).
    pub max_envs_per_world: usize,
    /// Smallest `physics.dt` (s): a smaller step makes more physics steps per simulated
    /// second. Default 0.0025 (task default 0.005).
    pub min_physics_dt_us: u32,
    /// Columns of a curriculum grid (`TerrainConfig.columns`). Default 40 (the default grid
    /// has 20).
    pub max_terrain_columns: usize,
    /// Rough-slope columns of a curriculum grid: their mesh keeps two triangles per cell, where
    /// the other types' flat faces merge (20 of them measured 307 MB resident against the
    /// default grid's 41 MB; decision record 0037). Default 4 (the default grid has 2).
    pub max_rough_slope_columns: usize,
}

impl Default for CostCaps {
    fn default() -> Self {
        Self {
            max_decimation: 8,
            max_solver_iterations: 4,
            max_pgs_iterations: 6,
            max_extra_iterations: 2,
            max_extra_pgs_iterations: 12,
            max_envs_per_world: 64,
            min_physics_dt_us: 2500,
            max_terrain_columns: 40,
            max_rough_slope_columns: 4,
        }
    }
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_envs_per_session: 8192,
            max_sessions: 16,
            idle_timeout_s: 600,
            max_total_envs: 65536,
            stream_idle_timeout_s: 300,
            cost: CostCaps::default(),
            max_overrides_bytes: 64 << 10,
            max_overrides_depth: 8,
            max_concurrent_evaluations: 1,
            max_evaluation_s: 900,
            max_evaluation_reply_bytes: 32 << 20,
            max_policy_bytes: 16 << 20,
            max_calls_per_session: 4,
        }
    }
}

/// Bytes of one env's share of the largest step reply: obs, labels, privileged, reward, reward
/// terms, flags, mode, level and the final rows (all envs may end at once), with headroom.
const BYTES_PER_ENV: usize = 1024;

impl Limits {
    /// The largest request a client may send (bytes): fits the largest batch and an Evaluate
    /// request with two policies.
    pub fn max_message_bytes(&self) -> usize {
        (self.max_envs_per_session * BYTES_PER_ENV + (1 << 20))
            .max(2 * self.max_policy_bytes + (1 << 20))
    }

    /// The largest reply the server sends (bytes): a step of the largest batch or an Evaluate
    /// reply.
    pub fn max_reply_bytes(&self) -> usize {
        self.max_message_bytes()
            .max(self.max_evaluation_reply_bytes)
    }
}
