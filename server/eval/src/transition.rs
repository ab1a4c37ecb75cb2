//! The transition scenarios: every env starts in one mode, all switch on cue, and each trial
//! succeeds when the robot reaches and holds the other mode's posture in time without falling.
//!
//! The strict count asks more: no body but the feet on the terrain (head, thighs, calves) over
//! the same window either, from the switch until the settle time after the posture is reached
//! (for biped -> quad this holds the switch's first 2 s: the posture is reached after the
//! switch). Falls are also counted over the whole observed window.

use std::collections::BTreeMap;

use unigait_sim::terrain::Terrain;

use crate::error::EvalError;
use crate::evaluate::{EvalOptions, RunTotals, merge_tracking, steps_for};
use crate::metrics::{
    HOLD_S, QUAD_PITCH, Summary, UPRIGHT_PITCH, first_sustained, insert_rate, median, rate,
    wilson_interval,
};
use crate::report::{HeightTrace, TransitionReport, TransitionTrial};
use crate::runner::{BodyContact, Policies, Rollout, StepObserver, probe};
use crate::scenario::{Mode, TransitionSpec, transition_config};

/// Time shown before the switch in the height trace (s).
const TRACE_BEFORE_S: f32 = 1.0;

/// Per-env traces of a transition run.
struct TransitionTraces {
    pitch: Vec<Vec<f32>>,
    height: Vec<Vec<f32>>,
    /// Bodies other than the feet on the terrain after each step (none once the first episode
    /// has ended).
    contact: Vec<Vec<BodyContact>>,
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
        contact: vec![Vec::with_capacity(total + 1); n],
        end: vec![None; n],
        command_before: vec![[0.0; 3]; n],
        command_after: vec![[0.0; 3]; n],
    };
    for i in 0..n {
        let p = probe(rollout.env(), i);
        tr.pitch[i].push(p.pitch);
        tr.height[i].push(p.height);
        tr.contact[i].push(p.contact);
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
            tr.contact[i].push(if alive {
                p.contact
            } else {
                BodyContact::default()
            });
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
        success_rate_ci95: None,
        strict_successes: 0,
        strict_success_rate: None,
        strict_success_rate_ci95: None,
        body_contact_trials: 0,
        head_contact_trials: 0,
        leg_contact_trials: 0,
        fall_trials: 0,
        fall_trials_whole_window: 0,
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
    let schedule = Schedule {
        switch,
        total,
        hold,
        settle,
        max_transition,
    };
    for &i in &trials {
        let Judgement {
            done,
            base_contact,
            success,
            body_contact,
            strict_success,
            fell_in_window,
        } = schedule.judge(&tr.pitch[i], &tr.contact[i], tr.end[i], in_to_posture);
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
        report.strict_successes += usize::from(strict_success);
        report.body_contact_trials += usize::from(body_contact.any());
        report.head_contact_trials += usize::from(body_contact.head);
        report.leg_contact_trials += usize::from(body_contact.legs);
        report.fall_trials_whole_window += usize::from(fell_in_window);
        report.outcomes.push(TransitionTrial {
            env: i,
            command_before: tr.command_before[i],
            command_after: tr.command_after[i],
            transition_time_s: time,
            base_contact,
            success,
            body_contact,
            strict_success,
            fell_in_window,
            height_std_m: h.std as f32,
            height_range_m: h.range() as f32,
        });
    }
    report.trials = trials.len();
    report.fall_trials = report.base_contacts;
    report.success_rate = rate(report.successes, report.trials);
    report.success_rate_ci95 = wilson_interval(report.successes, report.trials);
    report.strict_success_rate = rate(report.strict_successes, report.trials);
    report.strict_success_rate_ci95 = wilson_interval(report.strict_successes, report.trials);
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

/// The steps that decide a trial (trace index s is the state after policy step s).
#[derive(Clone, Copy, Debug)]
struct Schedule {
    /// Step of the switch.
    switch: usize,
    /// Last step observed.
    total: usize,
    /// Steps a posture must hold to count as reached.
    hold: usize,
    /// Steps after the posture is reached that are still watched.
    settle: usize,
    /// Most steps the transition may take.
    max_transition: usize,
}

/// How one trial went.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Judgement {
    /// Step from which the new posture held.
    done: Option<usize>,
    /// Fell (terminated) between the switch and `settle` after `done` (the whole run if never
    /// done).
    base_contact: bool,
    /// Done within `max_transition`, watched for the whole `settle`, and no fall.
    success: bool,
    /// Bodies other than the feet down over the same window.
    body_contact: BodyContact,
    /// A success with no body contact either.
    strict_success: bool,
    /// Fell at any step after the switch.
    fell_in_window: bool,
}

impl Schedule {
    /// Judge a trial from its pitch and contact traces and its first episode end (step, by
    /// termination?).
    fn judge(
        &self,
        pitch: &[f32],
        contact: &[BodyContact],
        end: Option<(usize, bool)>,
        in_to_posture: impl Fn(f32) -> bool,
    ) -> Judgement {
        let Schedule {
            switch,
            total,
            hold,
            settle,
            max_transition,
        } = *self;
        let done = first_sustained(pitch, switch, hold, in_to_posture);
        let fell_at = end.and_then(|(s, terminated)| terminated.then_some(s));
        // The base must stay off the ground until `settle` after completion (or the whole
        // window when the transition never completes).
        let watch_until = done.map_or(total, |d| (d + settle).min(total));
        let base_contact = fell_at.is_some_and(|s| s > switch && s <= watch_until);
        let success = done.is_some_and(|d| d - switch <= max_transition && d + settle <= total)
            && !base_contact;
        let body_contact = window_contact(contact, switch, watch_until);
        Judgement {
            done,
            base_contact,
            success,
            body_contact,
            strict_success: success && !body_contact.any(),
            fell_in_window: fell_at.is_some_and(|s| s > switch),
        }
    }
}

/// Which bodies other than the feet touched the terrain after the steps in (`from`, `to`]
/// (`contact[s]` is after step s).
fn window_contact(contact: &[BodyContact], from: usize, to: usize) -> BodyContact {
    let end = (to + 1).min(contact.len());
    let start = (from + 1).min(end);
    contact[start..end]
        .iter()
        .fold(BodyContact::default(), |a, c| BodyContact {
            trunk: a.trunk || c.trunk,
            head: a.head || c.head,
            legs: a.legs || c.legs,
        })
}

pub(crate) fn transition_metrics(t: &TransitionReport, m: &mut BTreeMap<String, f64>) {
    insert_rate(m, "success_rate", t.successes, t.trials);
    insert_rate(m, "strict_success_rate", t.strict_successes, t.trials);
    if t.trials > 0 {
        m.insert("body_contact_trials".into(), t.body_contact_trials as f64);
        m.insert("head_contact_trials".into(), t.head_contact_trials as f64);
        m.insert("leg_contact_trials".into(), t.leg_contact_trials as f64);
        m.insert("fall_trials".into(), t.fall_trials as f64);
        m.insert(
            "fall_trials_whole_window".into(),
            t.fall_trials_whole_window as f64,
        );
    }
    if t.success_rate.is_some() {
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

#[cfg(test)]
mod test {
    use super::*;

    const HEAD: BodyContact = BodyContact {
        trunk: false,
        head: true,
        legs: false,
    };
    const KNEE: BodyContact = BodyContact {
        trunk: false,
        head: false,
        legs: true,
    };
    const NONE: BodyContact = BodyContact {
        trunk: false,
        head: false,
        legs: false,
    };

    /// Switch after step 2, posture held 2 steps, watched 3 steps after, at most 4 steps to
    /// get there, 12 steps in all.
    const SCHEDULE: Schedule = Schedule {
        switch: 2,
        total: 12,
        hold: 2,
        settle: 3,
        max_transition: 4,
    };

    fn up(p: f32) -> bool {
        p > UPRIGHT_PITCH
    }

    /// Upright from step 4 on (done = 4, watched until step 7).
    fn rising() -> Vec<f32> {
        vec![
            0.0, 0.0, 0.0, 0.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5,
        ]
    }

    #[test]
    fn a_clean_switch_is_a_strict_success() {
        let j = SCHEDULE.judge(&rising(), &[NONE; 13], None, up);
        assert_eq!(j.done, Some(4));
        assert!(j.success && j.strict_success && !j.base_contact && !j.fell_in_window);
    }

    #[test]
    fn a_head_or_knee_down_in_the_window_fails_only_the_strict_count() {
        for (step, kind) in [(3, HEAD), (7, KNEE)] {
            let mut contact = [NONE; 13];
            contact[step] = kind;
            let j = SCHEDULE.judge(&rising(), &contact, None, up);
            assert!(j.success, "today's count ignores it (step {step})");
            assert!(!j.strict_success, "step {step}");
            assert_eq!(j.body_contact, kind);
        }
        // Before (or at) the switch, or after the settle time: outside the window.
        for step in [0, 2, 8, 12] {
            let mut contact = [NONE; 13];
            contact[step] = HEAD;
            let j = SCHEDULE.judge(&rising(), &contact, None, up);
            assert!(j.strict_success, "step {step}: {j:?}");
        }
    }

    #[test]
    fn falls_count_in_the_window_and_after_it_apart() {
        // A fall at step 6 (before the settle time is over) fails both counts.
        let j = SCHEDULE.judge(&rising(), &[NONE; 13], Some((6, true)), up);
        assert!(j.base_contact && !j.success && !j.strict_success && j.fell_in_window);
        // A fall at step 10 is after the window: a success today and strictly, but counted
        // as a fall in the whole observed window.
        let j = SCHEDULE.judge(&rising(), &[NONE; 13], Some((10, true)), up);
        assert!(!j.base_contact && j.success && j.strict_success && j.fell_in_window);
        // A time-out is no fall.
        let j = SCHEDULE.judge(&rising(), &[NONE; 13], Some((6, false)), up);
        assert!(!j.base_contact && !j.fell_in_window);
    }

    #[test]
    fn a_switch_never_completed_is_watched_to_the_end() {
        let pitch = vec![0.0; 13];
        let mut contact = [NONE; 13];
        contact[12] = KNEE;
        let j = SCHEDULE.judge(&pitch, &contact, None, up);
        assert_eq!(j.done, None);
        assert!(!j.success && !j.strict_success);
        assert_eq!(j.body_contact, KNEE);
        // Too slow: upright only from step 7, 5 steps after the switch (at most 4).
        let late = [vec![0.0; 7], vec![1.5; 6]].concat();
        let j = SCHEDULE.judge(&late, &[NONE; 13], None, up);
        assert_eq!(j.done, Some(7));
        assert!(!j.success && !j.strict_success);
    }
}
