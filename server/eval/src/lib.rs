//! unigait-eval: the paper's evaluation (Section IV) as server-side rollouts of ONNX policies
//! on unigait-sim envs, with a typed report.
//!
//! - Scenarios ([`scenarios`]): Table VI terrain traversal (15 cm stairs up/down and 30 deg
//!   slopes in quad mode; 30 deg slopes, 12 cm stairs up and 15 cm stairs down in biped mode;
//!   20 trials each), biped -> quad transitions on flat ground with commands in [-0.5, 0.5]
//!   m/s, quad -> biped switches at 1.5 m/s with the transition time, the CoM (base) height
//!   through the switch, velocity tracking per mode (also under Table V's pushes:
//!   `tracking_*_push`), plus flat sanity walks and the composite `table_vi`.
//! - Honest figures: every success rate X comes with `X_ci95_low` / `X_ci95_high` (Wilson);
//!   tracking errors with those of a policy that does nothing under the same commands
//!   (`tracking/<mode>/do_nothing/...`); transitions with a strict count (no body but the feet
//!   on the terrain); traversals walk half forward, half backward, with falls and time-outs
//!   apart.
//! - Controllers ([`Policies`]): one unified policy, or the two-policy baseline (a quad and a
//!   biped policy switched at the mode change).
//! - Runs ([`evaluate`]): each case builds a `VecEnv` from the base task config with the
//!   scenario's settings ([`scenario::calm_config`] and friends), keeps every env's 3-step
//!   observation history ([`unigait_policy::ObsHistory`]; an env that resets restarts its
//!   history with its new first observation), and measures; a [`StepObserver`] sees every step
//!   (the service records env 0 with it).
//! - Mode switches: transition scenarios pin the starting mode and switch every env on cue with
//!   the sim's `VecEnv::set_modes` ([`Rollout::set_modes`] also refreshes the observation
//!   histories), so every env is switched and every env still running at the switch can be a
//!   trial.
#![warn(missing_docs)]

mod error;
mod evaluate;
pub mod metrics;
mod report;
mod runner;
pub mod scenario;
pub mod terrain;
mod transition;

pub use error::EvalError;
pub use evaluate::{EvalOptions, evaluate, evaluate_scenario};
pub use metrics::{DoNothingStats, Summary, TrackingStats, TraversalEnd, wilson_interval};
pub use report::{
    EvalReport, HeightTrace, TransitionReport, TransitionTrial, TraversalCaseReport,
    TraversalReport, TraversalTrial,
};
pub use runner::{
    BodyContact, EnvProbe, NoObserver, Policies, Rollout, StepObserver, probe, sim_policy_spec,
};
pub use scenario::{
    Mode, Scenario, ScenarioKind, TABLE_VI, heading_hold, scenario, scenario_names, scenarios,
};
pub use terrain::{Obstacle, obstacle_terrain};
