//! The typed evaluation report (serialised to JSON as it is).

use std::collections::BTreeMap;

use serde::Serialize;

use crate::metrics::{Summary, TrackingStats, TraversalEnd};
use crate::runner::BodyContact;
use crate::scenario::Mode;
use crate::terrain::Obstacle;

/// One traversal trial.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TraversalTrial {
    /// Env index in its case's batch.
    pub env: usize,
    /// Case name.
    pub case: &'static str,
    /// How it ended.
    pub end: TraversalEnd,
    /// Furthest progress along the commanded direction (m).
    pub progress_m: f32,
    /// When it ended (s).
    pub time_s: f32,
    /// Where it ended across its course (m): the base's offset from the straight line out of its
    /// spawn point, positive to the left of its direction of travel. A trial that paced along a
    /// riser or a rim ends far off its course.
    pub lateral_m: f32,
    /// Its heading at the end against the heading it started with (rad, counterclockwise
    /// positive, in [-pi, pi)).
    pub heading_off_rad: f32,
    /// The friction coefficient of the trial's contacts with the ground (the robot's drawn one
    /// combined with the ground's, decision record 0034).
    pub contact_friction: f32,
}

/// Results of one traversal case (one terrain and direction).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TraversalCaseReport {
    /// Case name.
    pub name: &'static str,
    /// `up` or `down` for a slope case (see [`crate::scenario::TraversalCase::group`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub group: Option<&'static str>,
    /// The obstacle.
    pub obstacle: Obstacle,
    /// +1 forward, -1 backward.
    pub direction: f32,
    /// Distance that counts as crossed (m).
    pub distance_m: f32,
    /// Trials.
    pub trials: usize,
    /// Crossed.
    pub successes: usize,
    /// Crossed / trials.
    pub success_rate: Option<f64>,
    /// Wilson 95% interval of the success rate.
    pub success_rate_ci95: Option<[f64; 2]>,
    /// Ended by a base contact.
    pub terminations: usize,
    /// Ran out of time.
    pub timeouts: usize,
    /// Mean furthest progress (m).
    pub mean_progress_m: f64,
}

/// Terrain traversal results (a Table VI column).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TraversalReport {
    /// The column of Table VI this reproduces.
    pub table_vi_column: Option<&'static str>,
    /// Locomotion mode.
    pub mode: Mode,
    /// Commanded speed (m/s).
    pub speed_mps: f32,
    /// Time allowed per trial (s).
    pub time_limit_s: f32,
    /// Trials over all cases.
    pub trials: usize,
    /// Crossed.
    pub successes: usize,
    /// Crossed / trials.
    pub success_rate: Option<f64>,
    /// Wilson 95% interval of the success rate.
    pub success_rate_ci95: Option<[f64; 2]>,
    /// Ended by a base contact (falls).
    pub terminations: usize,
    /// Neither crossed nor fell within the time limit.
    pub timeouts: usize,
    /// Falls / trials.
    pub fall_rate: Option<f64>,
    /// Time-outs / trials.
    pub timeout_rate: Option<f64>,
    /// Per case.
    pub cases: Vec<TraversalCaseReport>,
    /// Per trial.
    pub outcomes: Vec<TraversalTrial>,
}

/// One transition trial.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TransitionTrial {
    /// Env index.
    pub env: usize,
    /// Command before the switch (vx, vy, wz).
    pub command_before: [f32; 3],
    /// Command after it.
    pub command_after: [f32; 3],
    /// Time from the switch until the new posture held (s), if it did.
    pub transition_time_s: Option<f32>,
    /// The base touched the ground during the switch or the settle time after it (a fall:
    /// the episode terminated).
    pub base_contact: bool,
    /// Completed in time with no base contact.
    pub success: bool,
    /// Bodies other than the feet that touched the terrain, without a fall, over the same
    /// window (head, thighs or calves; the trunk only ever touches in a fall).
    pub body_contact: BodyContact,
    /// A success with no such contact either: the paper's collision-free switch.
    pub strict_success: bool,
    /// The episode terminated at any time from the switch to the end of the observed window.
    pub fell_in_window: bool,
    /// Standard deviation of the base height from the switch to the end (m).
    pub height_std_m: f32,
    /// Peak-to-peak base height over the same time (m).
    pub height_range_m: f32,
}

/// Base (CoM) height through the switch, over the trials (Fig. 5).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct HeightTrace {
    /// Time relative to the switch (s).
    pub t_s: Vec<f32>,
    /// Mean base height above the terrain (m).
    pub mean_m: Vec<f32>,
    /// Standard deviation over the trials (m).
    pub std_m: Vec<f32>,
    /// Trials still running at each time.
    pub count: Vec<u32>,
}

/// Mode switch results.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TransitionReport {
    /// Mode before the switch.
    pub from: Mode,
    /// Mode after it.
    pub to: Mode,
    /// Switch time (s).
    pub switch_s: f32,
    /// Envs run.
    pub envs: usize,
    /// Envs read back in `from` at the start and in `to` right after the switch: every env, as
    /// the evaluation switches them all (fewer would mean the switch failed).
    pub switched: usize,
    /// Switched envs whose first episode ended before the switch (not trials).
    pub fell_before_switch: usize,
    /// Switched envs still running but not in the `from` posture at the switch (e.g. never
    /// stood up).
    pub not_in_posture_at_switch: usize,
    /// Trials: switched, running and in posture at the switch (`switched` =
    /// `fell_before_switch` + `not_in_posture_at_switch` + `trials`).
    pub trials: usize,
    /// Successful trials.
    pub successes: usize,
    /// Successes / trials.
    pub success_rate: Option<f64>,
    /// Wilson 95% interval of the success rate.
    pub success_rate_ci95: Option<[f64; 2]>,
    /// Successes with no body other than the feet on the terrain during the switch or the
    /// settle time.
    pub strict_successes: usize,
    /// Strict successes / trials.
    pub strict_success_rate: Option<f64>,
    /// Wilson 95% interval of the strict success rate.
    pub strict_success_rate_ci95: Option<[f64; 2]>,
    /// Trials with a body other than the feet on the terrain (without a fall) during the switch
    /// or the settle time.
    pub body_contact_trials: usize,
    /// Of those, the trials with the head down.
    pub head_contact_trials: usize,
    /// Of those, the trials with a thigh or a calf down.
    pub leg_contact_trials: usize,
    /// Trials with a base contact during the switch or the settle time (= `base_contacts`).
    pub fall_trials: usize,
    /// Trials that fell at any time from the switch to the end of the observed window.
    pub fall_trials_whole_window: usize,
    /// Trials with a base contact during the switch or the settle time.
    pub base_contacts: usize,
    /// Transition times of the trials that completed (s).
    pub transition_time_s: Summary,
    /// Median transition time (s).
    pub transition_time_median_s: Option<f64>,
    /// Per-trial standard deviation of the base height after the switch (m).
    pub height_std_m: Summary,
    /// Per-trial peak-to-peak base height after the switch (m).
    pub height_range_m: Summary,
    /// Mean base height over time.
    pub height_trace: HeightTrace,
    /// Per trial.
    pub outcomes: Vec<TransitionTrial>,
}

/// The result of one evaluation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvalReport {
    /// Scenario name.
    pub scenario: String,
    /// What it reproduces.
    pub description: String,
    /// `unified` or `two_policy`.
    pub policy: String,
    /// Envs run (over all cases).
    pub num_envs: usize,
    /// Seed.
    pub seed: u64,
    /// The physics engine the rollouts ran on (`physics.engine`: `rapier` or `articulated`).
    pub physics_engine: String,
    /// Scalar results by name (what the gRPC reply's map carries).
    pub metrics: BTreeMap<String, f64>,
    /// Traversal details.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub traversal: Option<TraversalReport>,
    /// Transition details.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transition: Option<TransitionReport>,
    /// Velocity tracking error per mode over every settled step of the run.
    pub tracking: BTreeMap<String, TrackingStats>,
    /// Sub-reports of a composite scenario (`table_vi`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub parts: Vec<EvalReport>,
    /// Wall time (s).
    pub wall_s: f64,
    /// How the scenario was set up, and caveats.
    pub notes: Vec<String>,
}

impl EvalReport {
    /// The report as pretty JSON (non-finite numbers become null).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }
}
