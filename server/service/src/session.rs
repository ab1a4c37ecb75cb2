//! One client's batch of envs, and the registry of all sessions.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::Notify;
use unigait_proto::TensorView;
use unigait_proto::v1::{self, AutoresetMode};
use unigait_sim::env::{VecEnv, VecEnvOptions};
use unigait_sim::prelude::*;

use crate::convert;
use crate::error::ServiceError;
use crate::limits::Limits;
use crate::overrides;

/// A session's envs and what the service tracks about their episodes.
struct Batch {
    env: VecEnv,
    /// With autoreset disabled: envs whose episode ended and that were not reset since. Their
    /// end is reported once; later steps report neither a termination nor a reward for them.
    ended: Vec<u8>,
    /// The envs' share of `--max-total-envs`, given back when the batch (its memory) goes.
    _budget: EnvBudget,
}

/// Envs counted against the server's total until dropped.
struct EnvBudget {
    envs: usize,
    in_use: Arc<Mutex<usize>>,
}

impl Drop for EnvBudget {
    fn drop(&mut self) {
        let mut in_use = self.in_use.lock().unwrap_or_else(|e| e.into_inner());
        *in_use = in_use.saturating_sub(self.envs);
    }
}

/// The session's batch, locked; frees the batch when released after the session was closed
/// (a close that came while this call held the lock could not).
struct BatchGuard<'a> {
    guard: MutexGuard<'a, Option<Batch>>,
    session: &'a Session,
}

impl std::ops::Deref for BatchGuard<'_> {
    type Target = Option<Batch>;
    fn deref(&self) -> &Option<Batch> {
        &self.guard
    }
}

impl std::ops::DerefMut for BatchGuard<'_> {
    fn deref_mut(&mut self) -> &mut Option<Batch> {
        &mut self.guard
    }
}

impl Drop for BatchGuard<'_> {
    fn drop(&mut self) {
        if self.session.is_closed() {
            self.guard.take();
        }
    }
}

/// A call on a session in flight, counted until dropped.
pub struct CallSlot(Arc<Session>);

impl Drop for CallSlot {
    fn drop(&mut self) {
        self.0.in_flight.fetch_sub(1, Ordering::AcqRel);
    }
}

/// A session: its envs behind a lock (stepped on the shared worker pool), its spec and bookkeeping.
pub struct Session {
    /// The session id.
    pub id: String,
    /// The spec sent at creation.
    pub spec: v1::Spec,
    /// None once closed: the envs are freed at the close, whoever still holds the session.
    batch: Mutex<Option<Batch>>,
    autoreset: bool,
    reward_terms: bool,
    streaming: AtomicBool,
    closed: AtomicBool,
    /// Woken when the session is closed (ends its step stream).
    close_notify: Notify,
    steps: AtomicU64,
    /// Calls on this session in flight (running or waiting for its lock).
    in_flight: AtomicUsize,
    last_used: Mutex<Instant>,
    /// Test hook: panic while stepping (see `ServeOptions::fault_injection_seed`).
    panic_on_step: bool,
}

/// Marks a session as having an open step stream until dropped.
pub struct StreamGuard(Arc<Session>);

impl Drop for StreamGuard {
    fn drop(&mut self) {
        self.0.touch();
        self.0.streaming.store(false, Ordering::Release);
    }
}

fn closed_error(id: &str) -> ServiceError {
    ServiceError::UnknownSession(id.to_string())
}

impl Session {
    fn touch(&self) {
        if let Ok(mut t) = self.last_used.lock() {
            *t = Instant::now();
        }
    }

    /// The session's batch; a lock poisoned by a panic while stepping breaks the session.
    fn lock(&self) -> Result<BatchGuard<'_>, ServiceError> {
        self.touch();
        let guard = self
            .batch
            .lock()
            .map_err(|_| ServiceError::Broken(self.id.clone()))?;
        let guard = BatchGuard {
            guard,
            session: self,
        };
        if self.is_closed() {
            // Dropping the guard frees the batch.
            return Err(closed_error(&self.id));
        }
        Ok(guard)
    }

    /// Count one more call in flight on this session, or refuse it when `max` are.
    pub fn begin_call(self: &Arc<Self>, max: usize) -> Result<CallSlot, ServiceError> {
        if self.in_flight.fetch_add(1, Ordering::AcqRel) >= max {
            self.in_flight.fetch_sub(1, Ordering::AcqRel);
            return Err(ServiceError::LimitExceeded(format!(
                "session `{}` has {max} calls in flight already; wait for their replies (--max-calls-per-session)",
                self.id
            )));
        }
        Ok(CallSlot(self.clone()))
    }

    /// Whether the session was closed.
    pub fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Acquire)
    }

    /// Resolves once the session is closed.
    pub async fn closed(&self) {
        let notified = self.close_notify.notified();
        if self.is_closed() {
            return;
        }
        notified.await;
    }

    /// Mark closed, wake its stream and free its envs (unless a step holds them: then the step
    /// frees them when it ends, as its holder is the last).
    fn shut(&self) {
        self.closed.store(true, Ordering::Release);
        self.close_notify.notify_waiters();
        if let Ok(mut batch) = self.batch.try_lock() {
            batch.take();
        }
    }

    /// Claim the session's single step stream.
    pub fn open_stream(self: &Arc<Self>) -> Result<StreamGuard, ServiceError> {
        if self.streaming.swap(true, Ordering::AcqRel) {
            return Err(ServiceError::Precondition(format!(
                "session `{}` already has an open step stream; close it first (one stream per session)",
                self.id
            )));
        }
        self.touch();
        Ok(StreamGuard(self.clone()))
    }

    /// A unary Step: refused while the session has an open stream (its steps would interleave
    /// with the stream's unseen).
    pub fn step_unary(&self, request: &v1::StepRequest) -> Result<v1::StepResult, ServiceError> {
        if self.streaming.load(Ordering::Acquire) {
            return Err(ServiceError::Precondition(format!(
                "session `{}` has an open step stream: step it there (a unary Step would interleave)",
                self.id
            )));
        }
        self.step(request)
    }

    /// One batched step (blocking: call from a blocking thread).
    pub fn step(&self, request: &v1::StepRequest) -> Result<v1::StepResult, ServiceError> {
        let actions = request.actions.as_ref().ok_or_else(|| {
            ServiceError::InvalidArgument("StepRequest.actions is missing".into())
        })?;
        let mut guard = self.lock()?;
        let batch = guard.as_mut().ok_or_else(|| closed_error(&self.id))?;
        let n = batch.env.num_envs();
        actions.expect_shape("actions", &[n, NUM_JOINTS])?;
        let values = actions.f32_values("actions")?;
        convert::check_draw_envs(&request.draw_envs, n)?;
        if self.panic_on_step {
            panic!("injected fault in session `{}`", self.id);
        }
        let before = batch.env.nonfinite_resets();
        batch.env.step(&values)?;
        let steps = self.steps.fetch_add(1, Ordering::Relaxed) + 1;
        let nonfinite = (batch.env.nonfinite_resets() - before) as u32;
        let out = batch.env.output();
        let mut result = convert::step_result(
            out,
            self.reward_terms || request.reward_terms,
            steps,
            nonfinite,
            (!self.autoreset).then_some(&batch.ended[..]),
        );
        if !request.draw_envs.is_empty() {
            result.body_poses = Some(convert::body_poses(&batch.env, &request.draw_envs));
        }
        if !self.autoreset {
            for i in 0..n {
                let done = out.terminated[i] != 0 || out.truncated[i] != 0;
                // A blow-up is reset by the core even without autoreset: a new episode.
                if done && out.nonfinite[i] == 0 {
                    batch.ended[i] = 1;
                }
            }
        }
        Ok(result)
    }

    /// Reset all envs, or those where `mask` is non-zero (blocking).
    pub fn reset(&self, mask: Option<&v1::Tensor>) -> Result<v1::StepResult, ServiceError> {
        let mut guard = self.lock()?;
        let batch = guard.as_mut().ok_or_else(|| closed_error(&self.id))?;
        let n = batch.env.num_envs();
        match mask {
            None => {
                batch.env.reset();
                batch.ended.fill(0);
            }
            Some(m) => {
                m.expect_shape("mask", &[n])?;
                let mask = m.u8_values("mask")?;
                batch.env.reset_envs(mask)?;
                for (e, &m) in batch.ended.iter_mut().zip(mask) {
                    if m != 0 {
                        *e = 0;
                    }
                }
            }
        }
        Ok(convert::step_result(
            batch.env.output(),
            self.reward_terms,
            self.steps.load(Ordering::Relaxed),
            0,
            None,
        ))
    }

    fn idle_for(&self) -> Duration {
        self.last_used
            .lock()
            .map(|t| t.elapsed())
            .unwrap_or_default()
    }
}

/// The table of sessions and the envs and slots reserved for sessions being built.
#[derive(Default)]
struct Registry {
    map: HashMap<String, Arc<Session>>,
    /// Sessions being built.
    pending: usize,
}

/// A slot and envs reserved for a session being built; given back unless committed (the
/// envs go with the budget, when it is dropped).
struct Reservation<'a> {
    sessions: &'a Sessions,
    budget: Option<EnvBudget>,
    committed: bool,
}

impl Drop for Reservation<'_> {
    fn drop(&mut self) {
        if self.committed {
            return;
        }
        if let Ok(mut r) = self.sessions.registry() {
            r.pending = r.pending.saturating_sub(1);
        }
    }
}

/// All sessions of a server.
pub struct Sessions {
    registry: Mutex<Registry>,
    /// Envs whose memory is held: of open sessions, of sessions being built, and of closed
    /// sessions whose envs a call in flight still holds. Locked after `registry`.
    envs: Arc<Mutex<usize>>,
    limits: Limits,
    model: Arc<RobotModel>,
    base_config: TaskConfig,
    pool: Arc<rayon::ThreadPool>,
    fault_injection_seed: Option<u64>,
}

impl Sessions {
    /// An empty registry.
    pub fn new(
        limits: Limits,
        base_config: TaskConfig,
        pool: Arc<rayon::ThreadPool>,
        fault_injection_seed: Option<u64>,
    ) -> Self {
        Self {
            registry: Mutex::new(Registry::default()),
            envs: Arc::new(Mutex::new(0)),
            limits,
            model: Arc::new(RobotModel::go2()),
            base_config,
            pool,
            fault_injection_seed,
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

    fn registry(&self) -> Result<MutexGuard<'_, Registry>, ServiceError> {
        self.registry
            .lock()
            .map_err(|_| ServiceError::Internal("session table lock poisoned".into()))
    }

    /// Number of open sessions.
    pub fn len(&self) -> usize {
        self.registry().map(|r| r.map.len()).unwrap_or(0)
    }

    /// Envs whose memory is held (open sessions, sessions being built, closed sessions whose
    /// envs a call in flight still holds).
    pub fn envs_in_use(&self) -> usize {
        *self.envs.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Reserve a session slot and `n` envs before building them.
    fn reserve(&self, n: usize) -> Result<Reservation<'_>, ServiceError> {
        let mut r = self.registry()?;
        if r.map.len() + r.pending >= self.limits.max_sessions {
            return Err(ServiceError::LimitExceeded(format!(
                "the server holds its maximum of {} sessions; close one or start the server with a higher --max-sessions",
                self.limits.max_sessions
            )));
        }
        let mut envs = self.envs.lock().unwrap_or_else(|e| e.into_inner());
        if *envs + n > self.limits.max_total_envs {
            return Err(ServiceError::LimitExceeded(format!(
                "{n} envs requested but only {} of the server's {} are free (--max-total-envs)",
                self.limits.max_total_envs.saturating_sub(*envs),
                self.limits.max_total_envs
            )));
        }
        *envs += n;
        r.pending += 1;
        Ok(Reservation {
            sessions: self,
            budget: Some(EnvBudget {
                envs: n,
                in_use: self.envs.clone(),
            }),
            committed: false,
        })
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
        let task = overrides::apply(
            &self.base_config,
            &config.task_overrides_toml,
            "SessionConfig.task_overrides_toml",
            &self.limits,
        )?;
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
        let mut reservation = self.reserve(n)?;
        let (terrain, terrain_name) = crate::terrain::terrain_for(
            config.terrain.as_ref(),
            config.seed,
            n,
            &self.limits.cost,
        )?;
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
        let mut spec = convert::spec(&env, autoreset, &terrain_name)?;
        if config.robot_drawing {
            // The recordings' drawing (server/record), once per session that asks.
            spec.robot_drawing_rrd = unigait_record::robot_drawing_rrd(&self.model)
                .map_err(|e| ServiceError::Internal(format!("robot drawing: {e}")))?
                .into();
        }
        let initial = convert::step_result(env.output(), config.reward_terms, 0, 0, None);
        let session = Arc::new(Session {
            id: uuid::Uuid::new_v4().to_string(),
            spec,
            batch: Mutex::new(Some(Batch {
                env,
                ended: vec![0; n],
                _budget: reservation.budget.take().ok_or_else(|| {
                    ServiceError::Internal("a reservation without its envs".into())
                })?,
            })),
            autoreset: autoreset == AutoresetMode::SameStep,
            reward_terms: config.reward_terms,
            streaming: AtomicBool::new(false),
            closed: AtomicBool::new(false),
            close_notify: Notify::new(),
            steps: AtomicU64::new(0),
            in_flight: AtomicUsize::new(0),
            last_used: Mutex::new(Instant::now()),
            panic_on_step: self.fault_injection_seed == Some(config.seed),
        });
        let mut r = self.registry()?;
        r.map.insert(session.id.clone(), session.clone());
        r.pending = r.pending.saturating_sub(1);
        reservation.committed = true;
        Ok((session, initial))
    }

    /// The session `id`.
    pub fn get(&self, id: &str) -> Result<Arc<Session>, ServiceError> {
        self.registry()?
            .map
            .get(id)
            .cloned()
            .ok_or_else(|| ServiceError::UnknownSession(id.into()))
    }

    /// Close the session `id`: it leaves the table, its stream (if any) ends and its envs are
    /// freed (by the call in flight that holds them, if any, when it ends; they count against
    /// `--max-total-envs` until then).
    pub fn close(&self, id: &str) -> Result<(), ServiceError> {
        let session = self
            .registry()?
            .map
            .remove(id)
            .ok_or_else(|| ServiceError::UnknownSession(id.into()))?;
        session.shut();
        Ok(())
    }

    /// Close every session (at shutdown).
    pub fn close_all(&self) -> usize {
        let ids: Vec<String> = match self.registry() {
            Ok(r) => r.map.keys().cloned().collect(),
            Err(_) => return 0,
        };
        ids.iter().filter(|id| self.close(id).is_ok()).count()
    }

    /// Close sessions unused for longer than the idle timeout; returns their ids. A session
    /// with a stream counts as unused once the stream has done nothing for longer than a live
    /// stream can (it waits for a request, or to send a reply, up to the stream idle timeout
    /// each): its stream is stuck.
    pub fn reap_idle(&self) -> Vec<String> {
        let timeout = Duration::from_secs(self.limits.idle_timeout_s);
        let stuck = timeout.max(Duration::from_secs(
            2 * self.limits.stream_idle_timeout_s.max(1),
        ));
        let idle: Vec<String> = match self.registry() {
            Ok(r) => r
                .map
                .iter()
                .filter(|(_, s)| {
                    let limit = if s.streaming.load(Ordering::Acquire) {
                        stuck
                    } else {
                        timeout
                    };
                    s.idle_for() > limit
                })
                .map(|(id, _)| id.clone())
                .collect(),
            Err(_) => return vec![],
        };
        idle.into_iter()
            .filter(|id| self.close(id).is_ok())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sessions(max_total_envs: usize) -> Sessions {
        let limits = Limits {
            max_total_envs,
            ..Limits::default()
        };
        let pool = unigait_sim::env::worker_pool(1).expect("pool");
        Sessions::new(limits, TaskConfig::embedded_default(), pool, None)
    }

    fn config(num_envs: u32) -> v1::SessionConfig {
        v1::SessionConfig {
            num_envs,
            ..Default::default()
        }
    }

    #[test]
    fn issue_36_a_close_during_a_call_releases_the_envs_with_their_memory() {
        let sessions = sessions(6);
        let (session, _) = sessions.create(&config(4)).expect("create");
        // A call in flight holds the batch (as a step does) when the close lands.
        let held = session.lock().expect("lock");
        sessions.close(&session.id).expect("close");
        assert_eq!(sessions.len(), 0, "the slot is free at once");
        assert_eq!(sessions.envs_in_use(), 4, "the envs are still in memory");
        let refused = sessions.create(&config(4));
        assert!(
            matches!(refused, Err(ServiceError::LimitExceeded(_))),
            "4 + 4 > 6 while the first batch lives"
        );
        drop(held);
        assert_eq!(sessions.envs_in_use(), 0, "the call's end frees the batch");
        assert!(session.batch.lock().expect("lock").is_none());
        sessions.create(&config(4)).expect("now it fits");
    }

    #[test]
    fn issue_36_calls_in_flight_per_session_are_bounded() {
        let sessions = sessions(8);
        let (session, _) = sessions.create(&config(1)).expect("create");
        let slots: Vec<CallSlot> = (0..3)
            .map(|_| session.begin_call(3).expect("within the bound"))
            .collect();
        assert!(matches!(
            session.begin_call(3),
            Err(ServiceError::LimitExceeded(_))
        ));
        drop(slots);
        session.begin_call(3).expect("free again");
    }
}
