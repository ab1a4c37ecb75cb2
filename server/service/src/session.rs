//! One client's batch of envs, and the registry of all sessions.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use unigait_proto::TensorView;
use unigait_proto::v1::{self, AutoresetMode};
use unigait_sim::env::{VecEnv, VecEnvOptions};
use unigait_sim::prelude::*;

use crate::convert;
use crate::error::ServiceError;
use crate::limits::Limits;

/// A session: its envs behind a lock (stepped on the shared worker pool), its spec and bookkeeping.
pub struct Session {
    /// The session id.
    pub id: String,
    /// The spec sent at creation.
    pub spec: v1::Spec,
    env: Mutex<VecEnv>,
    reward_terms: bool,
    streaming: AtomicBool,
    steps: AtomicU64,
    last_used: Mutex<Instant>,
}

/// Marks a session as having an open step stream until dropped.
pub struct StreamGuard(Arc<Session>);

impl Drop for StreamGuard {
    fn drop(&mut self) {
        self.0.streaming.store(false, Ordering::Release);
    }
}

impl Session {
    fn lock(&self) -> Result<MutexGuard<'_, VecEnv>, ServiceError> {
        *self
            .last_used
            .lock()
            .map_err(|_| ServiceError::Internal("poisoned lock".into()))? = Instant::now();
        self.env.lock().map_err(|_| {
            ServiceError::Internal(format!(
                "session `{}` is broken by an earlier panic",
                self.id
            ))
        })
    }

    /// Claim the session's single step stream.
    pub fn open_stream(self: &Arc<Self>) -> Result<StreamGuard, ServiceError> {
        if self.streaming.swap(true, Ordering::AcqRel) {
            return Err(ServiceError::Precondition(format!(
                "session `{}` already has an open step stream; close it first (one stream per session)",
                self.id
            )));
        }
        Ok(StreamGuard(self.clone()))
    }

    /// One batched step (blocking: call from a blocking thread).
    pub fn step(&self, request: &v1::StepRequest) -> Result<v1::StepResult, ServiceError> {
        let actions = request.actions.as_ref().ok_or_else(|| {
            ServiceError::InvalidArgument("StepRequest.actions is missing".into())
        })?;
        let values = actions.f32_values("actions")?;
        let mut env = self.lock()?;
        let n = env.num_envs();
        actions.expect_shape("actions", &[n, NUM_JOINTS])?;
        let before = env.nonfinite_resets();
        env.step(&values)?;
        let steps = self.steps.fetch_add(1, Ordering::Relaxed) + 1;
        let nonfinite = (env.nonfinite_resets() - before) as u32;
        Ok(convert::step_result(
            env.output(),
            self.reward_terms || request.reward_terms,
            steps,
            nonfinite,
        ))
    }

    /// Reset all envs, or those where `mask` is non-zero (blocking).
    pub fn reset(&self, mask: Option<&v1::Tensor>) -> Result<v1::StepResult, ServiceError> {
        let mut env = self.lock()?;
        let n = env.num_envs();
        match mask {
            None => {
                env.reset();
            }
            Some(m) => {
                m.expect_shape("mask", &[n])?;
                env.reset_envs(m.u8_values("mask")?)?;
            }
        }
        Ok(convert::step_result(
            env.output(),
            self.reward_terms,
            self.steps.load(Ordering::Relaxed),
            0,
        ))
    }

    fn idle_for(&self) -> Duration {
        self.last_used
            .lock()
            .map(|t| t.elapsed())
            .unwrap_or_default()
    }
}

/// All sessions of a server.
pub struct Sessions {
    map: Mutex<HashMap<String, Arc<Session>>>,
    limits: Limits,
    model: Arc<RobotModel>,
    base_config: TaskConfig,
    pool: Arc<rayon::ThreadPool>,
}

impl Sessions {
    /// An empty registry.
    pub fn new(limits: Limits, base_config: TaskConfig, pool: Arc<rayon::ThreadPool>) -> Self {
        Self {
            map: Mutex::new(HashMap::new()),
            limits,
            model: Arc::new(RobotModel::go2()),
            base_config,
            pool,
        }
    }

    /// The limits.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// Worker threads stepping envs.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    fn map(&self) -> Result<MutexGuard<'_, HashMap<String, Arc<Session>>>, ServiceError> {
        self.map
            .lock()
            .map_err(|_| ServiceError::Internal("session table lock poisoned".into()))
    }

    /// Number of open sessions.
    pub fn len(&self) -> usize {
        self.map().map(|m| m.len()).unwrap_or(0)
    }

    fn check_room(&self) -> Result<(), ServiceError> {
        let open = self.map()?.len();
        if open >= self.limits.max_sessions {
            return Err(ServiceError::LimitExceeded(format!(
                "the server holds its maximum of {} sessions; close one or start the server with a higher --max-sessions",
                self.limits.max_sessions
            )));
        }
        Ok(())
    }

    /// Build a session (blocking: it creates and resets every env).
    pub fn create(
        &self,
        config: &v1::SessionConfig,
    ) -> Result<(Arc<Session>, v1::StepResult), ServiceError> {
        let n = config.num_envs as usize;
        if n == 0 || n > self.limits.max_envs_per_session {
            return Err(if n == 0 {
                ServiceError::InvalidArgument("SessionConfig.num_envs must be at least 1".into())
            } else {
                ServiceError::LimitExceeded(format!(
                    "{n} envs requested; this server allows at most {} per session (--max-envs)",
                    self.limits.max_envs_per_session
                ))
            });
        }
        self.check_room()?;
        let task = if config.task_overrides_toml.trim().is_empty() {
            self.base_config.clone()
        } else {
            self.base_config
                .with_overrides(&config.task_overrides_toml)?
        };
        let autoreset = match AutoresetMode::try_from(config.autoreset) {
            Ok(AutoresetMode::Disabled) => AutoresetMode::Disabled,
            Ok(_) => AutoresetMode::SameStep,
            Err(_) => {
                return Err(ServiceError::InvalidArgument(format!(
                    "unknown autoreset mode {}",
                    config.autoreset
                )));
            }
        };
        let (terrain, terrain_name) =
            crate::terrain::terrain_for(config.terrain.as_ref(), config.seed)?;
        let options = VecEnvOptions {
            num_envs: n,
            seed: config.seed,
            threads: 0,
            physics_only: false,
            autoreset: autoreset == AutoresetMode::SameStep,
        };
        let env = VecEnv::with_pool(
            self.model.clone(),
            task,
            terrain,
            options,
            self.pool.clone(),
        )?;
        let spec = convert::spec(&env, autoreset, &terrain_name)?;
        let initial = convert::step_result(env.output(), config.reward_terms, 0, 0);
        let session = Arc::new(Session {
            id: uuid::Uuid::new_v4().to_string(),
            spec,
            env: Mutex::new(env),
            reward_terms: config.reward_terms,
            streaming: AtomicBool::new(false),
            steps: AtomicU64::new(0),
            last_used: Mutex::new(Instant::now()),
        });
        let mut map = self.map()?;
        // Another request may have taken the last slot while the envs were being built.
        if map.len() >= self.limits.max_sessions {
            return Err(ServiceError::LimitExceeded(format!(
                "the server holds its maximum of {} sessions",
                self.limits.max_sessions
            )));
        }
        map.insert(session.id.clone(), session.clone());
        Ok((session, initial))
    }

    /// The session `id`.
    pub fn get(&self, id: &str) -> Result<Arc<Session>, ServiceError> {
        self.map()?
            .get(id)
            .cloned()
            .ok_or_else(|| ServiceError::UnknownSession(id.into()))
    }

    /// Close the session `id`.
    pub fn close(&self, id: &str) -> Result<(), ServiceError> {
        self.map()?
            .remove(id)
            .map(|_| ())
            .ok_or_else(|| ServiceError::UnknownSession(id.into()))
    }

    /// Close sessions unused for longer than the idle timeout; returns their ids.
    pub fn reap_idle(&self) -> Vec<String> {
        let timeout = Duration::from_secs(self.limits.idle_timeout_s);
        let Ok(mut map) = self.map() else {
            return vec![];
        };
        let idle: Vec<String> = map
            .iter()
            .filter(|(_, s)| !s.streaming.load(Ordering::Acquire) && s.idle_for() > timeout)
            .map(|(id, _)| id.clone())
            .collect();
        for id in &idle {
            map.remove(id);
        }
        idle
    }
}
