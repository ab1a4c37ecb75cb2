//! Running a scenario: build the envs of each case, roll the policies out, measure.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use unigait_sim::env::{VecEnv, VecEnvOptions};
use unigait_sim::robot::RobotModel;
use unigait_sim::task::{TaskConfig, angle_from};
use unigait_sim::terrain::Terrain;

use crate::error::EvalError;
use crate::metrics::{
    EpisodeOutcomes, HOLD_S, HeadHits, QUAD_PITCH, Summary, TrackingAccumulator, TraversalEnd,
    UPRIGHT_PITCH, UPRIGHT_SETTLE_S, insert_rate, rate, traversal_step, wilson_interval,
};
use crate::report::{EvalReport, TraversalCaseReport, TraversalReport, TraversalTrial};
use crate::runner::{Policies, Rollout, StepObserver, probe};
use crate::scenario::{
    Mode, PUSH_INTERVAL_S, PUSH_VELOCITY_MPS, Scenario, ScenarioKind, TABLE_VI, TrackingSpec,
    TraversalSpec, heading_hold, scenario, table_vi_scenarios, tracking_config, traversal_config,
};
use crate::terrain::obstacle_terrain;
use crate::transition::{run_transition, transition_metrics};

/// How an evaluation runs.
#[derive(Clone)]
pub struct EvalOptions {
    /// Envs (trials); None = the scenario's default.
    pub num_envs: Option<usize>,
    /// Seed of the envs (and of generated terrains).
    pub seed: u64,
    /// The task config the scenario starts from (the server's, so policies see what they
    /// were trained on).
    pub base_config: TaskConfig,
    /// The robot.
    pub model: Arc<RobotModel>,
    /// Step the envs on this pool (a server's shared one); None = a pool of `threads`.
    pub pool: Option<Arc<rayon::ThreadPool>>,
    /// Worker threads when there is no pool (0 = one per core).
    pub threads: usize,
    /// Most envs one case may run.
    pub max_envs: usize,
}

impl std::fmt::Debug for EvalOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EvalOptions")
            .field("num_envs", &self.num_envs)
            .field("seed", &self.seed)
            .field("threads", &self.threads)
            .field("max_envs", &self.max_envs)
            .finish_non_exhaustive()
    }
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            num_envs: None,
            seed: 0,
            base_config: TaskConfig::embedded_default(),
            model: Arc::new(RobotModel::go2()),
            pool: None,
            threads: 0,
            max_envs: 8192,
        }
    }
}

impl EvalOptions {
    /// Envs (trials) a run of `scenario` uses: `num_envs`, or the scenario's default.
    pub fn envs(&self, scenario: &Scenario) -> Result<usize, EvalError> {
        let n = self.num_envs.unwrap_or(scenario.default_envs);
        if n == 0 || n > self.max_envs {
            return Err(EvalError::InvalidOption(format!(
                "num_envs {n} out of range [1, {}]",
                self.max_envs
            )));
        }
        Ok(n)
    }

    pub(crate) fn make_env(
        &self,
        config: TaskConfig,
        terrain: Terrain,
        num_envs: usize,
        seed: u64,
    ) -> Result<VecEnv, EvalError> {
        let options = VecEnvOptions {
            num_envs,
            seed,
            threads: self.threads,
            physics_only: false,
            autoreset: true,
        };
        let terrain = Arc::new(terrain);
        Ok(match &self.pool {
            Some(pool) => {
                VecEnv::with_pool(self.model.clone(), config, terrain, options, pool.clone())?
            }
            None => VecEnv::new(self.model.clone(), config, terrain, options)?,
        })
    }
}

/// Evaluate `policies` on the scenario called `name` (or the composite `table_vi`).
pub fn evaluate(
    name: &str,
    policies: &Policies,
    options: &EvalOptions,
    observer: &mut dyn StepObserver,
) -> Result<EvalReport, EvalError> {
    policies.check()?;
    if name == TABLE_VI {
        return evaluate_table_vi(policies, options, observer);
    }
    evaluate_scenario(&scenario(name)?, policies, options, observer)
}

/// Evaluate `policies` on `scenario`.
pub fn evaluate_scenario(
    scenario: &Scenario,
    policies: &Policies,
    options: &EvalOptions,
    observer: &mut dyn StepObserver,
) -> Result<EvalReport, EvalError> {
    policies.check()?;
    let t0 = Instant::now();
    let n = options.envs(scenario)?;
    let mut report = empty_report(scenario.name, scenario.description, policies, n, options);
    let pushes = matches!(&scenario.kind, ScenarioKind::Tracking(t) if t.pushes);
    report.notes.push(format!(
        "calm start: default joints, no initial velocity or tilt; {}; the base config's other \
         domain randomisation and observation noise stay on",
        if pushes {
            format!(
                "Table V's pushes on (base xy velocity shifted by U(-{PUSH_VELOCITY_MPS}, \
                 {PUSH_VELOCITY_MPS}) m/s per axis every {PUSH_INTERVAL_S} s of an episode, \
                 when the base config's domain randomisation is enabled: {})",
                options.base_config.randomization.enabled
            )
        } else {
            "pushes off".to_string()
        }
    ));
    let mut tracking = RunTotals::default();
    match &scenario.kind {
        ScenarioKind::Traversal(spec) => {
            let t = run_traversal(spec, n, policies, options, observer, &mut tracking)?;
            traversal_metrics(&t, &mut report.metrics);
            report.notes.push(format!(
                "success = the base got {} m past the obstacle's far edge along the commanded \
                 direction within {} s with no base contact; fall_rate: ended by a base \
                 contact; timeout_rate: neither crossed nor fell in time; \
                 success_rate_forward / _backward: the trials facing the way they walk or \
                 walking backward; every rate X has X_ci95_low / X_ci95_high, its Wilson 95% \
                 interval",
                spec.margin_m, spec.time_limit_s
            ));
            report.traversal = Some(t);
        }
        ScenarioKind::Transition(spec) => {
            let t = run_transition(spec, n, policies, options, observer, &mut tracking)?;
            transition_metrics(&t, &mut report.metrics);
            report.notes.push(format!(
                "every env starts in {} mode (pinned) and is switched to {} at {} s, its command \
                 redrawn from the {} ranges; trials are the envs still in their first episode \
                 and in the {} posture at the switch; posture reached = {} held {HOLD_S} s; \
                 success = reached within {} s and no base contact from the switch until {} s \
                 after; strict_success_rate: a success with no body but the feet (head, \
                 thighs, calves) on the terrain over the same window either (contacts as read \
                 back after each policy step); fall_trials: base contacts in that window, \
                 fall_trials_whole_window: until the end of the run; every rate X has \
                 X_ci95_low / X_ci95_high, its Wilson 95% interval",
                spec.from.name(),
                spec.to.name(),
                spec.switch_s,
                spec.to.name(),
                spec.from.name(),
                match spec.to {
                    Mode::Biped => format!("pitch > {UPRIGHT_PITCH} rad"),
                    Mode::Quad => format!("|pitch| < {QUAD_PITCH} rad"),
                },
                spec.max_transition_s,
                spec.settle_s
            ));
            report.transition = Some(t);
        }
        ScenarioKind::Tracking(spec) => {
            run_tracking(spec, n, policies, options, observer, &mut tracking)?;
            report.notes.push(format!(
                "commands drawn from the base config's {} ranges",
                spec.mode.name()
            ));
        }
    }
    let head = &tracking.head;
    report.metrics.insert("head_hits".into(), head.hits as f64);
    report
        .metrics
        .insert("head_contact_share".into(), head.contact_share());
    report.notes.push(
        "head hits: times a robot's head came down on the terrain (neither terminating nor \
         penalised; the paper's failure walking forward up stairs on two legs); \
         head_contact_share: share of env steps with the head on the terrain"
            .into(),
    );
    let outcomes = tracking.outcomes;
    for (m, mode) in [Mode::Biped, Mode::Quad].into_iter().enumerate() {
        if let Some(r) = outcomes.termination_rate(m) {
            let name = format!("tracking/{}/termination_rate", mode.name());
            report.metrics.insert(name, r);
        }
    }
    if let Some(share) = outcomes.upright_share() {
        report
            .metrics
            .insert("tracking/biped/upright_share".into(), share);
    }
    if let Some(pitch) = outcomes.mean_biped_pitch() {
        report
            .metrics
            .insert("tracking/biped/mean_pitch_rad".into(), pitch);
    }
    report.notes.push(format!(
        "tracking/<mode>/termination_rate: share of the episodes (ended, or running at the end) \
         ended by a termination, by the mode they ended in; tracking/biped/upright_share: share \
         of biped-mode steps at least {UPRIGHT_SETTLE_S} s into their episode and mode with \
         pitch > {UPRIGHT_PITCH} rad; tracking/biped/mean_pitch_rad: their mean pitch"
    ));
    let tracking = &tracking.tracking;
    for (mode, acc) in [(Mode::Biped, &tracking[0]), (Mode::Quad, &tracking[1])] {
        if let Some(stats) = acc.stats() {
            let m = &mut report.metrics;
            let prefix = format!("tracking/{}", mode.name());
            m.insert(
                format!("{prefix}/lin_vel_error_mps"),
                stats.lin_vel_error_mps,
            );
            m.insert(
                format!("{prefix}/lin_vel_error_forward_mps"),
                stats.forward_error_mps,
            );
            m.insert(
                format!("{prefix}/lin_vel_error_lateral_mps"),
                stats.lateral_error_mps,
            );
            m.insert(
                format!("{prefix}/ang_vel_error_radps"),
                stats.ang_vel_error_radps,
            );
            m.insert(format!("{prefix}/samples"), stats.samples as f64);
            let idle = &stats.do_nothing;
            for (name, value) in [
                ("lin_vel_error_mps", idle.lin_vel_error_mps),
                ("lin_vel_error_forward_mps", idle.forward_error_mps),
                ("lin_vel_error_lateral_mps", idle.lateral_error_mps),
                ("ang_vel_error_radps", idle.ang_vel_error_radps),
            ] {
                m.insert(format!("{prefix}/do_nothing/{name}"), value);
            }
            report.tracking.insert(mode.name().to_string(), stats);
        }
    }
    report.notes.push(format!(
        "tracking error: heading-frame velocity, steps at least {} s after a reset or mode \
         change; biped steps only when upright (pitch > {UPRIGHT_PITCH} rad); \
         lin_vel_error_forward_mps / _lateral_mps: the same along and across the heading; \
         do_nothing/*: the same figures over the same steps for a policy that does nothing \
         (velocity and yaw rate 0), from the commands alone",
        crate::metrics::TRACKING_SETTLE_S
    ));
    report.wall_s = t0.elapsed().as_secs_f64();
    report.metrics.insert("wall_s".into(), report.wall_s);
    Ok(report)
}

/// A report with its header filled in and no results yet.
fn empty_report(
    scenario: &str,
    description: &str,
    policies: &Policies,
    num_envs: usize,
    options: &EvalOptions,
) -> EvalReport {
    EvalReport {
        scenario: scenario.into(),
        description: description.into(),
        policy: policies.kind().to_string(),
        num_envs,
        seed: options.seed,
        physics_engine: options.base_config.physics.engine.name().into(),
        metrics: BTreeMap::new(),
        traversal: None,
        transition: None,
        tracking: BTreeMap::new(),
        parts: Vec::new(),
        wall_s: 0.0,
        notes: Vec::new(),
    }
}

/// Every Table VI column, one after the other; metrics are prefixed with the scenario name.
fn evaluate_table_vi(
    policies: &Policies,
    options: &EvalOptions,
    observer: &mut dyn StepObserver,
) -> Result<EvalReport, EvalError> {
    let t0 = Instant::now();
    let description = "Table VI: terrain traversal success of every column";
    let mut report = empty_report(TABLE_VI, description, policies, 0, options);
    for s in table_vi_scenarios() {
        let part = evaluate_scenario(&s, policies, options, observer)?;
        report.num_envs += part.num_envs;
        for (k, v) in &part.metrics {
            report.metrics.insert(format!("{}/{k}", s.name), *v);
        }
        report.parts.push(part);
    }
    report.wall_s = t0.elapsed().as_secs_f64();
    report.metrics.insert("wall_s".into(), report.wall_s);
    Ok(report)
}

/// What every rollout of a scenario adds up to.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct RunTotals {
    /// Tracking error by mode (biped, quad).
    tracking: [TrackingAccumulator; 2],
    /// Head contacts.
    head: HeadHits,
    /// Episode ends and upright time.
    outcomes: EpisodeOutcomes,
}

pub(crate) fn merge_tracking(into: &mut RunTotals, rollout: &Rollout) {
    into.tracking[0].merge(rollout.tracking(Mode::Biped));
    into.tracking[1].merge(rollout.tracking(Mode::Quad));
    into.head.merge(rollout.head_hits());
    into.outcomes.merge(&rollout.outcomes());
}

/// Env `i`'s heading (rad, world yaw of the heading frame's forward axis).
fn heading_yaw(env: &VecEnv, i: usize) -> f32 {
    unigait_sim::task::heading_yaw(env.robot_state(i).base_rot)
}

/// The largest yaw-rate command of `mode`'s training range.
fn yaw_rate_limit(config: &TaskConfig, mode: Mode) -> f32 {
    let wz = match mode {
        Mode::Biped => config.commands.biped.wz,
        Mode::Quad => config.commands.quad.wz,
    };
    wz[0].abs().max(wz[1].abs())
}

pub(crate) fn steps_for(config: &TaskConfig, seconds: f32) -> u32 {
    (seconds / config.policy_dt()).round().max(1.0) as u32
}

fn run_traversal(
    spec: &TraversalSpec,
    n: usize,
    policies: &Policies,
    options: &EvalOptions,
    observer: &mut dyn StepObserver,
    tracking: &mut RunTotals,
) -> Result<TraversalReport, EvalError> {
    let cases = spec.cases.len().max(1);
    let mut report = TraversalReport {
        table_vi_column: spec.table_vi_column,
        mode: spec.mode,
        speed_mps: spec.speed_mps,
        time_limit_s: spec.time_limit_s,
        trials: 0,
        successes: 0,
        success_rate: None,
        success_rate_ci95: None,
        terminations: 0,
        timeouts: 0,
        fall_rate: None,
        timeout_rate: None,
        cases: Vec::new(),
        outcomes: Vec::new(),
    };
    for (k, case) in spec.cases.iter().enumerate() {
        let envs = n / cases + usize::from(k < n % cases);
        if envs == 0 {
            continue;
        }
        let config = traversal_config(&options.base_config, spec, case)?;
        let dt = config.policy_dt();
        let steps = steps_for(&config, spec.time_limit_s);
        let distance = case.obstacle.half_extent() + spec.margin_m;
        let seed = options.seed.wrapping_add(k as u64);
        let terrain = obstacle_terrain(&case.obstacle, seed)?;
        let mut rollout = Rollout::new(options.make_env(config, terrain, envs, seed)?);
        observer.begin_case(k, case.name, rollout.env());
        // Drawn at the trial's reset: a terminated env redraws, so read them now.
        let ranges = &rollout.env().context().config.randomization;
        let contact_friction: Vec<f32> = (0..envs)
            .map(|i| {
                let drawn = rollout.env().env_state(i).randomization.friction;
                ranges.friction_combine.apply(drawn, ranges.ground_friction)
            })
            .collect();
        let mut ended: Vec<Option<(TraversalEnd, u32)>> = vec![None; envs];
        let mut best = vec![0.0f32; envs];
        // Where each trial stands at its end: (lateral offset, heading off its course).
        let mut last_pose = vec![(0.0f32, 0.0f32); envs];
        let direction = case.direction.signum();
        // The course is the heading each robot starts with; a trial that drifts off it is
        // steered back within the mode's yaw-rate range (decision record 0032).
        let course: Vec<f32> = (0..envs).map(|i| heading_yaw(rollout.env(), i)).collect();
        let wz_limit = yaw_rate_limit(&options.base_config, spec.mode);
        let mut commands: Vec<Option<[f32; 3]>> = vec![None; envs];
        while rollout.steps() < steps && ended.iter().any(Option::is_none) {
            if spec.heading_gain > 0.0 {
                for (i, command) in commands.iter_mut().enumerate() {
                    *command = ended[i].is_none().then(|| {
                        let mut c = rollout.env().env_state(i).command;
                        let yaw = heading_yaw(rollout.env(), i);
                        c[2] =
                            heading_hold(course[i], yaw, spec.heading_gain, [-wz_limit, wz_limit]);
                        c
                    });
                }
                rollout.set_commands(&commands)?;
            }
            rollout.step(policies)?;
            let step = rollout.steps();
            observer.after_step(k, step, rollout.env());
            let last = step >= steps;
            for i in 0..envs {
                if ended[i].is_some() {
                    continue;
                }
                let p = probe(rollout.env(), i);
                // After a termination the env is already reset: keep the progress of before.
                let progress = if p.terminated || p.truncated {
                    best[i]
                } else {
                    let lateral = direction * (p.base[1] - p.origin[1]);
                    last_pose[i] = (
                        lateral,
                        angle_from(course[i], heading_yaw(rollout.env(), i)),
                    );
                    direction * (p.base[0] - p.origin[0])
                };
                best[i] = best[i].max(progress);
                ended[i] = traversal_step(progress, distance, p.terminated, p.truncated || last)
                    .map(|end| (end, step));
            }
        }
        observer.end_case(k);
        merge_tracking(tracking, &rollout);
        let mut c = TraversalCaseReport {
            name: case.name,
            group: case.group,
            obstacle: case.obstacle,
            direction,
            distance_m: distance,
            trials: envs,
            successes: 0,
            success_rate: None,
            success_rate_ci95: None,
            terminations: 0,
            timeouts: 0,
            mean_progress_m: Summary::of(best.iter().map(|&b| f64::from(b))).mean,
        };
        for (i, e) in ended.iter().enumerate() {
            let (end, step) = e.unwrap_or((TraversalEnd::TimedOut, rollout.steps()));
            match end {
                TraversalEnd::Crossed => c.successes += 1,
                TraversalEnd::Terminated => c.terminations += 1,
                TraversalEnd::TimedOut => c.timeouts += 1,
            }
            report.outcomes.push(TraversalTrial {
                env: i,
                case: case.name,
                end,
                progress_m: best[i],
                time_s: step as f32 * dt,
                lateral_m: last_pose[i].0,
                heading_off_rad: last_pose[i].1,
                contact_friction: contact_friction[i],
            });
        }
        c.success_rate = rate(c.successes, c.trials);
        c.success_rate_ci95 = wilson_interval(c.successes, c.trials);
        report.trials += c.trials;
        report.successes += c.successes;
        report.terminations += c.terminations;
        report.timeouts += c.timeouts;
        report.cases.push(c);
    }
    report.success_rate = rate(report.successes, report.trials);
    report.success_rate_ci95 = wilson_interval(report.successes, report.trials);
    report.fall_rate = rate(report.terminations, report.trials);
    report.timeout_rate = rate(report.timeouts, report.trials);
    Ok(report)
}

/// Successes and trials of the cases `pick` selects.
fn tally(t: &TraversalReport, pick: impl Fn(&TraversalCaseReport) -> bool) -> (usize, usize) {
    t.cases
        .iter()
        .filter(|c| pick(c))
        .fold((0, 0), |(s, n), c| (s + c.successes, n + c.trials))
}

fn traversal_metrics(t: &TraversalReport, m: &mut BTreeMap<String, f64>) {
    insert_rate(m, "success_rate", t.successes, t.trials);
    insert_rate(m, "fall_rate", t.terminations, t.trials);
    insert_rate(m, "timeout_rate", t.timeouts, t.trials);
    m.insert("trials".into(), t.trials as f64);
    m.insert("successes".into(), t.successes as f64);
    m.insert("terminations".into(), t.terminations as f64);
    m.insert("timeouts".into(), t.timeouts as f64);
    m.insert("time_limit_s".into(), f64::from(t.time_limit_s));
    let progress = Summary::of(t.outcomes.iter().map(|o| f64::from(o.progress_m)));
    m.insert("mean_progress_m".into(), progress.mean);
    for (way, forward) in [("forward", true), ("backward", false)] {
        let (hits, trials) = tally(t, |c| (c.direction > 0.0) == forward);
        if trials > 0 {
            insert_rate(m, &format!("success_rate_{way}"), hits, trials);
            m.insert(format!("trials_{way}"), trials as f64);
        }
    }
    for c in &t.cases {
        insert_rate(
            m,
            &format!("case/{}/success_rate", c.name),
            c.successes,
            c.trials,
        );
    }
    // A slope's `up` and `down` over both directions (the names the slope cases had).
    for group in ["up", "down"] {
        let (hits, trials) = tally(t, |c| c.group == Some(group));
        insert_rate(m, &format!("case/{group}/success_rate"), hits, trials);
    }
}

fn run_tracking(
    spec: &TrackingSpec,
    n: usize,
    policies: &Policies,
    options: &EvalOptions,
    observer: &mut dyn StepObserver,
    tracking: &mut RunTotals,
) -> Result<(), EvalError> {
    let config = tracking_config(&options.base_config, spec)?;
    if spec.pushes && config.push_interval_steps().is_none() {
        tracing::warn!(
            "pushes asked for, but the base config's domain randomisation is off: no pushes"
        );
    }
    let steps = steps_for(&config, spec.duration_s);
    let mut rollout = Rollout::new(options.make_env(config, Terrain::Flat, n, options.seed)?);
    observer.begin_case(0, spec.mode.name(), rollout.env());
    while rollout.steps() < steps {
        rollout.step(policies)?;
        observer.after_step(0, rollout.steps(), rollout.env());
    }
    observer.end_case(0);
    merge_tracking(tracking, &rollout);
    Ok(())
}
