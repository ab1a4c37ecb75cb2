//! The Evaluate RPC: roll a client's ONNX policy out on the server's own envs over a named
//! scenario and return the metrics, the JSON report and, on request, a rerun recording of env 0.
//!
//! [`handle`] is blocking (it builds envs and steps them): call it from the handler on a
//! blocking thread, e.g. `blocking(move || crate::evaluate::handle(request, &ctx)).await`.

use std::sync::Arc;

use tracing::info;
use unigait_eval::{EvalError, EvalOptions, Policies, StepObserver, evaluate};
use unigait_policy::{OnnxPolicy, Policy, PolicyError};
use unigait_proto::v1;
use unigait_record::{RecordError, RecordOptions, Recorder};
use unigait_sim::env::VecEnv;
use unigait_sim::robot::RobotModel;
use unigait_sim::task::TaskConfig;

use crate::error::ServiceError;

/// What an evaluation borrows from the server.
#[derive(Clone)]
pub struct EvaluateContext {
    /// The server's task config (the one its sessions start from).
    pub base_config: TaskConfig,
    /// The robot.
    pub model: Arc<RobotModel>,
    /// The server's env worker pool (None: a pool of its own, one thread per core).
    pub pool: Option<Arc<rayon::ThreadPool>>,
    /// Most envs an evaluation may run (the server's per-session limit).
    pub max_envs: usize,
}

impl EvaluateContext {
    /// The embedded task config and Go2, a private pool, at most `max_envs` envs.
    pub fn new(max_envs: usize) -> Self {
        Self {
            base_config: TaskConfig::embedded_default(),
            model: Arc::new(RobotModel::go2()),
            pool: None,
            max_envs,
        }
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

/// A policy the client sent that cannot be loaded or run: the client's to fix.
fn policy_error(which: &str, e: PolicyError) -> ServiceError {
    ServiceError::InvalidArgument(format!("{which}: {e}"))
}

fn load(which: &str, bytes: &[u8]) -> Result<Arc<dyn Policy>, ServiceError> {
    if bytes.is_empty() {
        return Err(ServiceError::InvalidArgument(format!(
            "EvaluateRequest.{which} is empty: send the ONNX policy's bytes"
        )));
    }
    let policy = OnnxPolicy::from_bytes(bytes, unigait_eval::sim_policy_spec())
        .map_err(|e| policy_error(which, e))?;
    Ok(Arc::new(policy))
}

/// Records env 0 of the first case the evaluation runs.
struct FirstCaseRecorder {
    recorder: Option<Recorder>,
    active: bool,
    done: bool,
    error: Option<RecordError>,
}

impl FirstCaseRecorder {
    fn keep(&mut self, r: Result<(), RecordError>) {
        if let Err(e) = r {
            self.error.get_or_insert(e);
            self.active = false;
            self.done = true;
        }
    }
}

impl StepObserver for FirstCaseRecorder {
    fn begin_case(&mut self, _case: usize, _name: &str, env: &VecEnv) {
        if self.done {
            return;
        }
        if let Some(r) = self.recorder.as_mut() {
            self.active = true;
            let result = r.begin(env);
            self.keep(result);
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
) -> Result<v1::EvaluateResponse, ServiceError> {
    let n = request.num_envs as usize;
    if n > ctx.max_envs {
        return Err(ServiceError::LimitExceeded(format!(
            "{n} envs requested; this server evaluates at most {} (--max-envs)",
            ctx.max_envs
        )));
    }
    // Check the scenario before the (slower) policy load, so a typo fails fast.
    if request.scenario != unigait_eval::TABLE_VI {
        unigait_eval::scenario(&request.scenario)?;
    }
    let unified = load("policy_onnx", &request.policy_onnx)?;
    let policies = if request.biped_policy_onnx.is_empty() {
        Policies::Unified(unified)
    } else {
        Policies::TwoPolicy {
            quad: unified,
            biped: load("biped_policy_onnx", &request.biped_policy_onnx)?,
        }
    };
    let options = EvalOptions {
        num_envs: (n > 0).then_some(n),
        seed: request.seed,
        base_config: ctx.base_config.clone(),
        model: ctx.model.clone(),
        pool: ctx.pool.clone(),
        threads: 0,
        max_envs: ctx.max_envs,
    };
    let mut observer = FirstCaseRecorder {
        recorder: if request.record {
            let options = RecordOptions {
                name: format!("{} ({})", request.scenario, policies.kind()),
                ..RecordOptions::default()
            };
            Some(Recorder::in_memory(options).map_err(|e| ServiceError::Internal(e.to_string()))?)
        } else {
            None
        },
        active: false,
        done: false,
        error: None,
    };
    let report = evaluate(&request.scenario, &policies, &options, &mut observer)?;
    if let Some(e) = observer.error.take() {
        return Err(ServiceError::Internal(format!("recording failed: {e}")));
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
    Ok(v1::EvaluateResponse {
        metrics: report
            .metrics
            .iter()
            .map(|(k, v)| (k.clone(), *v))
            .collect(),
        report_json: report.to_json(),
        recording_rrd: recording_rrd.into(),
    })
}
