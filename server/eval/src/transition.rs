//! The transition scenarios: every env starts in one mode, all switch on cue, and each trial
//! succeeds when the robot reaches and holds the other mode's posture in time without falling.

use std::collections::BTreeMap;

use unigait_sim::terrain::Terrain;

use crate::error::EvalError;
use crate::evaluate::{EvalOptions, RunTotals, merge_tracking, steps_for};
use crate::metrics::{HOLD_S, QUAD_PITCH, Summary, UPRIGHT_PITCH, first_sustained, median, rate};
use crate::report::{HeightTrace, TransitionReport, TransitionTrial};
use crate::runner::{Policies, Rollout, StepObserver, probe};
use crate::scenario::{Mode, TransitionSpec, transition_config};

/// Time shown before the switch in the height trace (s).
const TRACE_BEFORE_S: f32 = 1.0;

/// Per-env traces of a transition run.
struct TransitionTraces {
    pitch: Vec<Vec<f32>>,
    height: Vec<Vec<f32>>,
    /// First step at which the episode ended (terminated or truncated), and whether by
    /// termination.
    end: Vec<Option<(usize, bool)>>,
    command_before: Vec<[f32; 3]>,
    command_after: Vec<[f32; 3]>,
}

pub(crate) fn run_transition(
    spec: &TransitionSpec,
    n: usize,
    policies: &Policies,
    options: &EvalOptions,
    observer: &mut dyn StepObserver,
    tracking: &mut RunTotals,
) -> Result<TransitionReport, EvalError> {
    let config = transition_config(&options.base_config, spec)?;
    let dt = config.policy_dt();
    let switch = steps_for(&config, spec.switch_s) as usize;
    let total = switch + steps_for(&config, spec.window_s) as usize;
    let hold = steps_for(&config, HOLD_S) as usize;
    let settle = steps_for(&config, spec.settle_s) as usize;
    let max_transition = steps_for(&config, spec.max_transition_s) as usize;
    let mut rollout = Rollout::new(options.make_env(config, Terrain::Flat, n, options.seed)?);
    observer.begin_case(0, "transition", rollout.env());
    let initial: Vec<Option<Mode>> = rollout
        .env()
        .output()
        .mode
        .iter()
        .map(|&c| Mode::from_code(c))
        .collect();
    let mut after: Vec<Option<Mode>> = vec![None; n];
    let mut tr = TransitionTraces {
        pitch: vec![Vec::with_capacity(total + 1); n],
        height: vec![Vec::with_capacity(total + 1); n],
        end: vec![None; n],
        command_before: vec![[0.0; 3]; n],
        command_after: vec![[0.0; 3]; n],
    };
    for i in 0..n {
        let p = probe(rollout.env(), i);
        tr.pitch[i].push(p.pitch);
        tr.height[i].push(p.height);
        tr.command_before[i] = p.command;
    }
    let every_env = vec![1u8; n];
    while (rollout.steps() as usize) < total {
        rollout.step(policies)?;
        let step = rollout.steps() as usize;
        if step == switch {
            // Switch every env now (an env already reset after a fall too: it is no trial, but
            // all envs then run the same schedule). Before the observer, so a recording shows
            // the observation the next action is computed from.
            rollout.set_modes(&every_env, spec.to, None)?;
        }
        observer.after_step(0, step as u32, rollout.env());
        for (i, after) in after.iter_mut().enumerate() {
            let p = probe(rollout.env(), i);
            if tr.end[i].is_none() && (p.terminated || p.truncated) {
                tr.end[i] = Some((step, p.terminated));
            }
            // Traces stop at the end of the first episode (the env is reset after it).
            let alive = tr.end[i].is_none();
            tr.pitch[i].push(if alive { p.pitch } else { f32::NAN });
            tr.height[i].push(if alive { p.height } else { f32::NAN });
            if step == switch {
                *after = p.mode;
                tr.command_after[i] = p.command;
            }
        }
    }
    observer.end_case(0);
    merge_tracking(tracking, &rollout);

    let mut report = TransitionReport {
        from: spec.from,
        to: spec.to,
        switch_s: switch as f32 * dt,
        envs: n,
        switched: 0,
        fell_before_switch: 0,
        not_in_posture_at_switch: 0,
        trials: 0,
        successes: 0,
        success_rate: None,
        base_contacts: 0,
        transition_time_s: Summary::default(),
        transition_time_median_s: None,
        height_std_m: Summary::default(),
        height_range_m: Summary::default(),
        height_trace: HeightTrace::default(),
        outcomes: Vec::new(),
    };
    let in_from_posture = |pitch: f32| match spec.from {
        Mode::Biped => pitch > UPRIGHT_PITCH,
        Mode::Quad => pitch.abs() < QUAD_PITCH,
    };
    let in_to_posture = |pitch: f32| match spec.to {
        Mode::Biped => pitch > UPRIGHT_PITCH,
        Mode::Quad => pitch.abs() < QUAD_PITCH,
    };
    let mut trials: Vec<usize> = Vec::new();
    for i in 0..n {
        // Read back from the outputs rather than assumed, so a switch that did not happen
        // shows in the report instead of being measured as one.
        if initial[i] != Some(spec.from) || after[i] != Some(spec.to) {
            continue;
        }
        report.switched += 1;
        if tr.end[i].is_some_and(|(s, _)| s <= switch) {
            // Its first episode ended before the switch: what follows is not a switch from a
            // walking gait.
            report.fell_before_switch += 1;
            continue;
        }
        if !in_from_posture(tr.pitch[i][switch]) {
            report.not_in_posture_at_switch += 1;
            continue;
        }
        trials.push(i);
    }
    let mut times = Vec::new();
    let mut stds = Vec::new();
    let mut ranges = Vec::new();
    for &i in &trials {
        let done = first_sustained(&tr.pitch[i], switch, hold, in_to_posture);
        let contact_at = tr.end[i].and_then(|(s, terminated)| terminated.then_some(s));
        // The base must stay off the ground until `settle` after completion (or the whole
        // window when the transition never completes).
        let watch_until = done.map_or(total, |d| (d + settle).min(total));
        let base_contact = contact_at.is_some_and(|s| s > switch && s <= watch_until);
        let success = done.is_some_and(|d| d - switch <= max_transition && d + settle <= total)
            && !base_contact;
        let heights: Vec<f64> = tr.height[i][switch..]
            .iter()
            .filter(|h| h.is_finite())
            .map(|&h| f64::from(h))
            .collect();
        let h = Summary::of(heights);
        let time = done.map(|d| (d - switch) as f32 * dt);
        if let Some(t) = time {
            times.push(f64::from(t));
        }
        stds.push(h.std);
        ranges.push(h.range());
        report.base_contacts += usize::from(base_contact);
        report.successes += usize::from(success);
        report.outcomes.push(TransitionTrial {
            env: i,
            command_before: tr.command_before[i],
            command_after: tr.command_after[i],
            transition_time_s: time,
            base_contact,
            success,
            height_std_m: h.std as f32,
            height_range_m: h.range() as f32,
        });
    }
    report.trials = trials.len();
    report.success_rate = rate(report.successes, report.trials);
    report.transition_time_s = Summary::of(times.iter().copied());
    report.transition_time_median_s = median(&times);
    report.height_std_m = Summary::of(stds);
    report.height_range_m = Summary::of(ranges);
    let before = steps_for(&rollout.env().context().config, TRACE_BEFORE_S) as usize;
    let start = switch.saturating_sub(before);
    for s in start..=total {
        let hs = trials
            .iter()
            .map(|&i| tr.height[i][s])
            .filter(|h| h.is_finite())
            .map(f64::from);
        let sum = Summary::of(hs);
        let t = &mut report.height_trace;
        t.t_s.push((s as f32 - switch as f32) * dt);
        t.mean_m.push(sum.mean as f32);
        t.std_m.push(sum.std as f32);
        t.count.push(sum.count as u32);
    }
    Ok(report)
}

pub(crate) fn transition_metrics(t: &TransitionReport, m: &mut BTreeMap<String, f64>) {
    if let Some(r) = t.success_rate {
        m.insert("success_rate".into(), r);
        m.insert(
            "base_contact_rate".into(),
            t.base_contacts as f64 / t.trials as f64,
        );
    }
    m.insert("trials".into(), t.trials as f64);
    m.insert("successes".into(), t.successes as f64);
    m.insert("switched_envs".into(), t.switched as f64);
    m.insert("fell_before_switch".into(), t.fell_before_switch as f64);
    m.insert(
        "not_in_posture_at_switch".into(),
        t.not_in_posture_at_switch as f64,
    );
    if t.transition_time_s.count > 0 {
        m.insert("transition_time_s_mean".into(), t.transition_time_s.mean);
        m.insert(
            "transitions_completed".into(),
            t.transition_time_s.count as f64,
        );
    }
    if let Some(med) = t.transition_time_median_s {
        m.insert("transition_time_s_median".into(), med);
    }
    if t.height_std_m.count > 0 {
        m.insert("com_height_std_m".into(), t.height_std_m.mean);
        m.insert("com_height_range_m".into(), t.height_range_m.mean);
        m.insert("com_height_range_max_m".into(), t.height_range_m.max);
    }
}
