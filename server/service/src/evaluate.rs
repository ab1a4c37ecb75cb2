//! The Evaluate RPC: roll a client's ONNX policy out on the server's own envs over a named
//! scenario and return the metrics, the JSON report and, on request, a rerun recording that
//! follows one trial (`record_env`, default 0, numbered across the scenario's cases).
//!
//! [`handle`] is blocking (it builds envs and steps them): call it from the handler on a
//! blocking thread, e.g. `blocking(move || crate::evaluate::handle(request, &ctx)).await`.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use prost::Message;
use tracing::info;
use unigait_eval::{EvalError, EvalOptions, Policies, StepObserver, evaluate};
use unigait_policy::{OnnxPolicy, Policy, PolicyError, PolicySpec, SandboxLimits, SandboxedPolicy};
use unigait_proto::v1;
use unigait_record::{RecordError, RecordOptions, Recorder};
use unigait_sim::env::VecEnv;
use unigait_sim::physics::EngineKind;
use unigait_sim::robot::RobotModel;
use unigait_sim::task::TaskConfig;

use crate::error::ServiceError;
use crate::limits::Limits;
use crate::overrides;

/// What an evaluation borrows from the server.
#[derive(Clone)]
pub struct EvaluateContext {
    /// The server's task config (the one its sessions start from).
    pub base_config: TaskConfig,
    /// The robot.
    pub model: Arc<RobotModel>,
    /// The server's env worker pool (None: a pool of its own, one thread per core).
    pub pool: Option<Arc<rayon::ThreadPool>>,
    /// The executable client policies are loaded and run in (a binary whose
    /// `policy-worker` subcommand runs [`unigait_policy::run_worker`]), with its limits. None:
    /// in this process, after the static checks only (tests and trusted use).
    pub policy_worker: Option<(PathBuf, SandboxLimits)>,
    /// The server's limits: envs (its per-session limit), duration, reply and policy sizes,
    /// and the checks on a request's task overrides.
    pub limits: Limits,
}

impl EvaluateContext {
    fn max_duration(&self) -> Duration {
        Duration::from_secs(self.limits.max_evaluation_s)
    }
}

/// Set to stop an evaluation (its caller went away or its deadline passed).
pub type StopFlag = Arc<AtomicBool>;

/// A policy that refuses to act once its evaluation should stop: the rollout ends at the next
/// step.
struct Stoppable {
    inner: Arc<dyn Policy>,
    stop: StopFlag,
    deadline: Instant,
    max_duration: Duration,
}

impl Policy for Stoppable {
    fn spec(&self) -> PolicySpec {
        self.inner.spec()
    }

    fn act(&self, history: &[f32], batch: usize, actions: &mut [f32]) -> Result<(), PolicyError> {
        if self.stop.load(Ordering::Acquire) {
            return Err(PolicyError::Stopped(
                "the evaluation was stopped: its caller went away or its deadline passed".into(),
            ));
        }
        if Instant::now() > self.deadline {
            return Err(PolicyError::ResourceLimit(format!(
                "the evaluation ran longer than the {} s this server allows; use fewer envs or a shorter scenario",
                self.max_duration.as_secs()
            )));
        }
        self.inner.act(history, batch, actions)
    }
}

impl From<EvalError> for ServiceError {
    fn from(e: EvalError) -> Self {
        match e {
            EvalError::Sim(sim) => ServiceError::Sim(sim),
            EvalError::Policy(p) => policy_error("policy", p),
            other => ServiceError::InvalidArgument(other.to_string()),
        }
    }
}

/// A policy the client sent that cannot be loaded or run: the client's to fix, or over a
/// limit. Only a worker that cannot start is the server's fault.
fn policy_error(which: &str, e: PolicyError) -> ServiceError {
    let message = format!("{which}: {e}");
    match e {
        PolicyError::TooLarge { .. } | PolicyError::ResourceLimit(_) => {
            ServiceError::LimitExceeded(message)
        }
        PolicyError::Stopped(_) => ServiceError::Deadline(message),
        PolicyError::Worker(_) => ServiceError::Internal(message),
        _ => ServiceError::InvalidArgument(message),
    }
}

fn load(
    which: &str,
    bytes: &[u8],
    ctx: &EvaluateContext,
    stop: &StopFlag,
    deadline: Instant,
) -> Result<Arc<dyn Policy>, ServiceError> {
    if bytes.is_empty() {
        return Err(ServiceError::InvalidArgument(format!(
            "EvaluateRequest.{which} is empty: send the ONNX policy's bytes"
        )));
    }
    if bytes.len() > ctx.limits.max_policy_bytes {
        return Err(ServiceError::LimitExceeded(format!(
            "EvaluateRequest.{which} has {} bytes; this server takes policies up to {}",
            bytes.len(),
            ctx.limits.max_policy_bytes
        )));
    }
    let spec = unigait_eval::sim_policy_spec();
    let policy: Arc<dyn Policy> = match &ctx.policy_worker {
        Some((exe, limits)) => Arc::new(
            SandboxedPolicy::spawn(exe, bytes, spec, *limits)
                .map_err(|e| policy_error(which, e))?,
        ),
        None => Arc::new(
            OnnxPolicy::from_untrusted_bytes(bytes, spec, &Default::default())
                .map_err(|e| policy_error(which, e))?,
        ),
    };
    Ok(Arc::new(Stoppable {
        inner: policy,
        stop: stop.clone(),
        deadline,
        max_duration: ctx.max_duration(),
    }))
}

/// The engine the policies were trained on, from their ONNX metadata: None when neither says;
/// two policies that name different engines are the client's to reconcile.
fn trained_engine(policy: &[u8], biped: &[u8]) -> Result<Option<EngineKind>, ServiceError> {
    let mut found: Option<(EngineKind, &str)> = None;
    for (which, bytes) in [("policy_onnx", policy), ("biped_policy_onnx", biped)] {
        if bytes.is_empty() {
            continue;
        }
        let Some(name) =
            unigait_policy::trained_engine(bytes).map_err(|e| policy_error(which, e))?
        else {
            continue;
        };
        let names = EngineKind::ALL.map(EngineKind::name).join(", ");
        let engine = EngineKind::from_name(&name).ok_or_else(|| {
            ServiceError::InvalidArgument(format!(
                "{which}: its metadata says it trained on physics engine {name:?}, which this \
                 server does not have ({names}); set physics.engine in task_overrides_toml"
            ))
        })?;
        match found {
            Some((first, first_which)) if first != engine => {
                return Err(ServiceError::InvalidArgument(format!(
                    "{first_which} trained on the {} engine and {which} on the {} engine; set \
                     physics.engine in task_overrides_toml to choose one",
                    first.name(),
                    engine.name()
                )));
            }
            _ => found = Some((engine, which)),
        }
    }
    Ok(found.map(|(e, _)| e))
}

/// Records the case holding the asked trial (`record_env`), following that trial's env.
///
/// Trials are numbered across the cases in the order they run, which is the order the report
/// lists their outcomes: with a traversal's 10 forward and 10 backward trials, trial 12 is the
/// third backward one. The recorder opens when its case begins.
struct TrialRecorder {
    /// The recording's options until its case begins (`env_index` set then).
    pending: Option<RecordOptions>,
    /// Trials still to pass before the followed one.
    skip: usize,
    /// Trials of the cases begun so far.
    seen: usize,
    recorder: Option<Recorder>,
    active: bool,
    done: bool,
    error: Option<RecordError>,
}

impl TrialRecorder {
    fn new(options: Option<RecordOptions>, trial: usize) -> Self {
        Self {
            pending: options,
            skip: trial,
            seen: 0,
            recorder: None,
            active: false,
            done: false,
            error: None,
        }
    }

    fn keep(&mut self, r: Result<(), RecordError>) {
        if let Err(e) = r {
            self.error.get_or_insert(e);
            self.active = false;
            self.done = true;
        }
    }

    /// Whether a recording was asked for and its trial never ran.
    fn missed(&self) -> bool {
        self.pending.is_some()
    }
}

impl StepObserver for TrialRecorder {
    fn begin_case(&mut self, _case: usize, name: &str, env: &VecEnv) {
        self.seen += env.num_envs();
        if self.done || self.pending.is_none() {
            return;
        }
        if self.skip >= env.num_envs() {
            self.skip -= env.num_envs();
            return;
        }
        let Some(mut options) = self.pending.take() else {
            return;
        };
        options.env_index = self.skip;
        options.name = format!("{}, {name}", options.name);
        match Recorder::in_memory(options) {
            Ok(mut r) => {
                self.active = true;
                let result = r.begin(env);
                self.recorder = Some(r);
                self.keep(result);
            }
            Err(e) => self.keep(Err(e)),
        }
    }

    fn after_step(&mut self, _case: usize, step: u32, env: &VecEnv) {
        if !self.active {
            return;
        }
        if let Some(r) = self.recorder.as_mut() {
            let result = r.log_step(env, u64::from(step));
            self.keep(result);
        }
    }

    fn end_case(&mut self, _case: usize) {
        if self.active {
            self.active = false;
            self.done = true;
        }
    }
}

/// Run one Evaluate request (blocking).
pub fn handle(
    request: v1::EvaluateRequest,
    ctx: &EvaluateContext,
    stop: &StopFlag,
) -> Result<v1::EvaluateResponse, ServiceError> {
    let deadline = Instant::now() + ctx.max_duration();
    let n = request.num_envs as usize;
    if n > ctx.limits.max_envs_per_session {
        return Err(ServiceError::LimitExceeded(format!(
            "{n} envs requested; this server evaluates at most {} (--max-envs)",
            ctx.limits.max_envs_per_session
        )));
    }
    // Check the scenario before the (slower) policy load, so a typo fails fast.
    if request.scenario != unigait_eval::TABLE_VI {
        unigait_eval::scenario(&request.scenario)?;
    }
    let unified = load("policy_onnx", &request.policy_onnx, ctx, stop, deadline)?;
    let policies = if request.biped_policy_onnx.is_empty() {
        Policies::Unified(unified)
    } else {
        Policies::TwoPolicy {
            quad: unified,
            biped: load(
                "biped_policy_onnx",
                &request.biped_policy_onnx,
                ctx,
                stop,
                deadline,
            )?,
        }
    };
    // The scenario sets the task's commands, modes and terrain; the overrides set the rest
    // (the physics engine, friction, ...). Where they leave the engine, it is the one the
    // policies name in their metadata (decision record 0026), else the server's.
    let mut base_config = overrides::apply(
        &ctx.base_config,
        &request.task_overrides_toml,
        "EvaluateRequest.task_overrides_toml",
        &ctx.limits,
    )?;
    if !TaskConfig::overrides_set(&request.task_overrides_toml, "physics.engine")
        && let Some(engine) = trained_engine(&request.policy_onnx, &request.biped_policy_onnx)?
    {
        base_config.physics.engine = engine;
    }
    let options = EvalOptions {
        num_envs: (n > 0).then_some(n),
        seed: request.seed,
        base_config,
        model: ctx.model.clone(),
        pool: ctx.pool.clone(),
        threads: 0,
        max_envs: ctx.limits.max_envs_per_session,
    };
    let record_env = request.record_env.map_or(0, |k| k as usize);
    if request.record && request.scenario != unigait_eval::TABLE_VI {
        let envs = options.envs(&unigait_eval::scenario(&request.scenario)?)?;
        if record_env >= envs {
            return Err(ServiceError::InvalidArgument(format!(
                "record_env {record_env} is not among the {envs} envs this evaluation runs"
            )));
        }
    }
    let recording = request.record.then(|| RecordOptions {
        name: format!("{} ({})", request.scenario, policies.kind()),
        ..RecordOptions::default()
    });
    let mut observer = TrialRecorder::new(recording, record_env);
    let report = evaluate(&request.scenario, &policies, &options, &mut observer)?;
    if let Some(e) = observer.error.take() {
        return Err(ServiceError::Internal(format!("recording failed: {e}")));
    }
    if observer.missed() {
        // Table VI's trials are counted as it runs them (the other scenarios are checked above).
        return Err(ServiceError::InvalidArgument(format!(
            "record_env {record_env} is not among the {} trials this evaluation ran",
            observer.seen
        )));
    }
    let recording_rrd = match observer.recorder.take() {
        Some(r) => r
            .finish()
            .map_err(|e| ServiceError::Internal(e.to_string()))?
            .unwrap_or_default(),
        None => Vec::new(),
    };
    info!(
        scenario = %report.scenario,
        policy = %report.policy,
        envs = report.num_envs,
        wall_s = report.wall_s,
        rrd_bytes = recording_rrd.len(),
        "evaluation done"
    );
    let reply = v1::EvaluateResponse {
        metrics: report
            .metrics
            .iter()
            .map(|(k, v)| (k.clone(), *v))
            .collect(),
        report_json: report.to_json(),
        recording_rrd: recording_rrd.into(),
    };
    let size = reply.encoded_len();
    if size > ctx.limits.max_evaluation_reply_bytes {
        return Err(ServiceError::LimitExceeded(format!(
            "the evaluation's reply would be {size} bytes, over this server's limit of {}; evaluate fewer envs or record a shorter scenario",
            ctx.limits.max_evaluation_reply_bytes
        )));
    }
    Ok(reply)
}
