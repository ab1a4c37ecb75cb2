//! The named scenarios of the paper's evaluation (Section IV) and the task configs they run.
//!
//! The env layer draws task modes and commands at random from the [`TaskConfig`]; a scenario
//! controls them through the config, and switches modes through the sim:
//! - a pinned mode: `modes.biped_probability` 0 or 1 and a mode resampling time longer than
//!   the run, so the env never redraws it (a reset draws it again, with the same outcome);
//! - pinned commands: each mode's command ranges collapsed to one value (or the paper's range),
//!   with a command resampling time longer than the run;
//! - a mid-episode switch `from -> to` at time T: the mode is pinned to `from` for the whole run
//!   and at T the evaluation switches every env to `to` with `VecEnv::set_modes` (via
//!   [`crate::Rollout::set_modes`]), exactly as a drawn mode change would: the command is
//!   redrawn from the `to` ranges, the gait clock runs on, and the observation the next action
//!   is computed from already carries the new mode. Every env is switched, so every env that is
//!   still in its first episode and in the `from` posture at T is a trial.
//!
//! Every scenario starts calm (joints at the default pose, no initial velocity, level base: the
//! training distribution of Table IV is for learning, not for measuring) and turns pushes off
//! (but `tracking_*_push`, which has Table V's); the rest of the domain randomisation and the
//! observation noise stay as the base config has them.

use serde::Serialize;
pub use unigait_sim::task::heading_hold;
use unigait_sim::task::{TaskConfig, TaskMode};

use crate::error::EvalError;
use crate::terrain::Obstacle;

/// A task mode, as reports name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Bipedal locomotion on the front legs (x = 1).
    Biped,
    /// Quadrupedal locomotion (x = 2).
    Quad,
}

impl Mode {
    /// The sim's mode.
    pub fn task_mode(self) -> TaskMode {
        match self {
            Mode::Biped => TaskMode::Biped,
            Mode::Quad => TaskMode::Quad,
        }
    }

    /// The mode of a `StepOutput::mode` entry (1 biped, 2 quad).
    pub fn from_code(code: u8) -> Option<Mode> {
        match code {
            1 => Some(Mode::Biped),
            2 => Some(Mode::Quad),
            _ => None,
        }
    }

    /// `biped` or `quad`.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Biped => "biped",
            Mode::Quad => "quad",
        }
    }
}

/// One terrain and direction of a traversal scenario.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TraversalCase {
    /// Short name (`forward`, `backward`, `up_forward`, `down_backward`, ...).
    pub name: &'static str,
    /// The part of the terrain a slope case crosses (`up` or `down`), whichever way the robot
    /// faces; None for stairs and flat ground, whose cases differ by direction only.
    pub group: Option<&'static str>,
    /// What the robot crosses.
    pub obstacle: Obstacle,
    /// +1 walks forward (command vx > 0), -1 backward.
    pub direction: f32,
}

/// Cross an obstacle: success = the base got `distance` along the commanded direction from its
/// spawn point (past the obstacle's far edge) with no termination on the way.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TraversalSpec {
    /// Mode for the whole run.
    pub mode: Mode,
    /// Commanded speed along the direction (m/s).
    pub speed_mps: f32,
    /// Terrains and directions; the trials are split evenly between them.
    pub cases: Vec<TraversalCase>,
    /// Success distance beyond the obstacle's far edge (m).
    pub margin_m: f32,
    /// Time allowed (s): see [`traversal_time_limit_s`].
    pub time_limit_s: f32,
    /// The Table VI column this reproduces.
    pub table_vi_column: Option<&'static str>,
    /// Yaw-rate command per radian the heading is off its start (1/s): the operator who kept
    /// the paper's robots on course; 0 leaves the yaw-rate command at 0 (decision record 0032).
    pub heading_gain: f32,
}

/// A mode switch on flat ground.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TransitionSpec {
    /// Mode before the switch.
    pub from: Mode,
    /// Mode after it.
    pub to: Mode,
    /// Command vx range before the switch (m/s; vy and yaw rate are 0).
    pub vx_from: [f32; 2],
    /// Command vx range after the switch (m/s).
    pub vx_to: [f32; 2],
    /// Time of the switch (s).
    pub switch_s: f32,
    /// Observed time after the switch (s).
    pub window_s: f32,
    /// The base must not touch the ground until this long after the transition completes (s).
    pub settle_s: f32,
    /// The transition must complete within this time (s).
    pub max_transition_s: f32,
}

/// Velocity tracking in one mode with commands drawn from the base config's ranges.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrackingSpec {
    /// The mode.
    pub mode: Mode,
    /// Run time (s).
    pub duration_s: f32,
    /// Table V's pushes on: every [`PUSH_INTERVAL_S`] the base's xy velocity is shifted by
    /// U(-[`PUSH_VELOCITY_MPS`], +[`PUSH_VELOCITY_MPS`]) per axis.
    pub pushes: bool,
}

/// What a scenario measures.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum ScenarioKind {
    /// Terrain traversal success (Table VI).
    Traversal(TraversalSpec),
    /// Mode switch success, time and CoM height (Section IV-C, Fig. 5).
    Transition(TransitionSpec),
    /// Velocity tracking error.
    Tracking(TrackingSpec),
}

/// A named scenario.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Scenario {
    /// Registry name.
    pub name: &'static str,
    /// One line on what it reproduces.
    pub description: &'static str,
    /// Envs (trials) when the request names none.
    pub default_envs: usize,
    /// What it measures.
    pub kind: ScenarioKind,
}

/// The composite scenario running every Table VI column.
pub const TABLE_VI: &str = "table_vi";

/// Quad traversal speed (m/s).
const QUAD_SPEED: f32 = 0.8;
/// Biped traversal speed (m/s), inside the biped command range of training.
const BIPED_SPEED: f32 = 0.4;
/// Yaw-rate command per radian of heading error in the traversals (1/s), within the mode's
/// yaw-rate range (decision record 0032).
const HEADING_GAIN: f32 = 1.0;
/// Trials per Table VI column in the paper.
const TABLE_VI_TRIALS: usize = 20;
/// Success distance beyond the obstacle's far edge (m).
const MARGIN_M: f32 = 0.5;
/// The time limit every traversal had before it followed the commanded speed (s); no limit is
/// shorter, so the quad columns keep theirs.
const MIN_TIME_LIMIT_S: f32 = 16.0;
/// Slack on the time the commanded speed needs to cover the distance.
const TIME_SLACK: f32 = 1.5;
/// Table V's push interval (s).
pub const PUSH_INTERVAL_S: f32 = 10.0;
/// Table V's push: the base's xy velocity is shifted by up to this much per axis (m/s).
pub const PUSH_VELOCITY_MPS: f32 = 1.0;

/// Time a traversal in `mode` allows to cover `distance_m` at `speed_mps`: the distance 1.5
/// times over at the commanded speed, after the time to settle into the gait (1 s on four legs,
/// [`crate::metrics::UPRIGHT_SETTLE_S`] = 2 s to get up onto the front legs), and never under
/// 16 s. With every tile's 4 m to its edge plus the 0.5 m margin (4.5 m):
/// - quad at 0.8 m/s: 4.5 / 0.8 x 1.5 + 1 = 9.4 s, so the 16 s floor;
/// - biped at 0.4 m/s: 4.5 / 0.4 x 1.5 + 2 = 18.9 s (it had 16 s, and at the 0.33 m/s the
///   shipped policy walks, 4.5 m takes 13.6 s after the 2 s of getting up).
pub fn traversal_time_limit_s(mode: Mode, speed_mps: f32, distance_m: f32) -> f32 {
    let settle = match mode {
        Mode::Quad => crate::metrics::TRACKING_SETTLE_S,
        Mode::Biped => crate::metrics::UPRIGHT_SETTLE_S,
    };
    (distance_m / speed_mps * TIME_SLACK + settle).max(MIN_TIME_LIMIT_S)
}

/// Forward and backward across `obstacle`, as the paper's 10 + 10 trials.
fn both_ways(obstacle: Obstacle) -> Vec<TraversalCase> {
    vec![
        TraversalCase {
            name: "forward",
            group: None,
            obstacle,
            direction: 1.0,
        },
        TraversalCase {
            name: "backward",
            group: None,
            obstacle,
            direction: -1.0,
        },
    ]
}

/// Up and down the slope, each forward and backward: half the trials face each way (the
/// paper's 10 + 10) and both halves climb and descend.
fn up_and_down(degrees: f32) -> Vec<TraversalCase> {
    let up = Obstacle::SlopeUp { degrees };
    let down = Obstacle::SlopeDown { degrees };
    vec![
        TraversalCase {
            name: "up_forward",
            group: Some("up"),
            obstacle: up,
            direction: 1.0,
        },
        TraversalCase {
            name: "down_forward",
            group: Some("down"),
            obstacle: down,
            direction: 1.0,
        },
        TraversalCase {
            name: "up_backward",
            group: Some("up"),
            obstacle: up,
            direction: -1.0,
        },
        TraversalCase {
            name: "down_backward",
            group: Some("down"),
            obstacle: down,
            direction: -1.0,
        },
    ]
}

fn traversal(
    name: &'static str,
    description: &'static str,
    mode: Mode,
    cases: Vec<TraversalCase>,
    column: Option<&'static str>,
) -> Scenario {
    let speed_mps = match mode {
        Mode::Quad => QUAD_SPEED,
        Mode::Biped => BIPED_SPEED,
    };
    let distance = cases
        .iter()
        .map(|c| c.obstacle.half_extent() + MARGIN_M)
        .fold(0.0, f32::max);
    Scenario {
        name,
        description,
        default_envs: TABLE_VI_TRIALS,
        kind: ScenarioKind::Traversal(TraversalSpec {
            mode,
            speed_mps,
            cases,
            margin_m: MARGIN_M,
            time_limit_s: traversal_time_limit_s(mode, speed_mps, distance),
            table_vi_column: column,
            heading_gain: HEADING_GAIN,
        }),
    }
}

fn tracking(name: &'static str, description: &'static str, mode: Mode, pushes: bool) -> Scenario {
    Scenario {
        name,
        description,
        default_envs: 64,
        kind: ScenarioKind::Tracking(TrackingSpec {
            mode,
            // One whole episode: the milestones ask for 18 s without a termination.
            duration_s: 18.0,
            pushes,
        }),
    }
}

/// Every registered scenario, Table VI columns first.
pub fn scenarios() -> Vec<Scenario> {
    vec![
        traversal(
            "stairs_up_quad",
            "Table VI: 15 cm stairs up, quadrupedal (10 forward + 10 backward)",
            Mode::Quad,
            both_ways(Obstacle::StairsUp { step_height: 0.15 }),
            Some("15cm Stairs up (q)"),
        ),
        traversal(
            "stairs_down_quad",
            "Table VI: 15 cm stairs down, quadrupedal (10 forward + 10 backward)",
            Mode::Quad,
            both_ways(Obstacle::StairsDown { step_height: 0.15 }),
            Some("15cm Stairs down (q)"),
        ),
        traversal(
            "slope_quad",
            "Table VI: 30 deg slope, quadrupedal (10 forward + 10 backward, each half up and \
             half down)",
            Mode::Quad,
            up_and_down(30.0),
            Some("30° Slope (q)"),
        ),
        traversal(
            "slope_biped",
            "Table VI: 30 deg slope, bipedal (10 forward + 10 backward, each half up and half \
             down)",
            Mode::Biped,
            up_and_down(30.0),
            Some("30° Slope (b)"),
        ),
        traversal(
            "stairs_up_biped",
            "Table VI: 12 cm stairs up, bipedal (10 forward + 10 backward, as the paper)",
            Mode::Biped,
            both_ways(Obstacle::StairsUp { step_height: 0.12 }),
            Some("12cm Stairs up (b)"),
        ),
        traversal(
            "stairs_down_biped",
            "Table VI: 15 cm stairs down, bipedal (10 forward + 10 backward)",
            Mode::Biped,
            both_ways(Obstacle::StairsDown { step_height: 0.15 }),
            Some("15 cm Stairs down (b)"),
        ),
        traversal(
            "flat_quad",
            "Sanity: walk 4.5 m forward on flat ground, quadrupedal",
            Mode::Quad,
            vec![TraversalCase {
                name: "forward",
                group: None,
                obstacle: Obstacle::Flat,
                direction: 1.0,
            }],
            None,
        ),
        traversal(
            "flat_biped",
            "Sanity: walk 4.5 m forward on flat ground, bipedal",
            Mode::Biped,
            vec![TraversalCase {
                name: "forward",
                group: None,
                obstacle: Obstacle::Flat,
                direction: 1.0,
            }],
            None,
        ),
        Scenario {
            name: "transition_biped_to_quad",
            description: "Section IV-C: biped -> quad on flat ground, commands vx in [-0.5, 0.5] \
                          m/s; success = no base contact during the switch and 2 s after; CoM \
                          height through the switch (Fig. 5)",
            default_envs: 256,
            kind: ScenarioKind::Transition(TransitionSpec {
                from: Mode::Biped,
                to: Mode::Quad,
                vx_from: [-0.5, 0.5],
                vx_to: [-0.5, 0.5],
                switch_s: 4.0,
                window_s: 3.9,
                settle_s: 2.0,
                max_transition_s: 1.9,
            }),
        },
        Scenario {
            name: "transition_quad_to_biped",
            description: "Section IV-C: quad -> biped while running at 1.5 m/s (biped command \
                          0.5 m/s after the switch); transition time until pitch > 1.4 rad holds",
            default_envs: 256,
            kind: ScenarioKind::Transition(TransitionSpec {
                from: Mode::Quad,
                to: Mode::Biped,
                vx_from: [1.5, 1.5],
                vx_to: [0.5, 0.5],
                switch_s: 4.0,
                window_s: 3.9,
                settle_s: 2.0,
                max_transition_s: 1.9,
            }),
        },
        tracking(
            "tracking_quad",
            "Velocity tracking error, quadrupedal, commands from the training ranges",
            Mode::Quad,
            false,
        ),
        tracking(
            "tracking_biped",
            "Velocity tracking error, bipedal (upright steps), commands from the training ranges",
            Mode::Biped,
            false,
        ),
        tracking(
            "tracking_quad_push",
            "Velocity tracking error, quadrupedal, with Table V's pushes (base xy velocity \
             shifted by U(-1, 1) m/s every 10 s)",
            Mode::Quad,
            true,
        ),
        tracking(
            "tracking_biped_push",
            "Velocity tracking error, bipedal (upright steps), with Table V's pushes (base xy \
             velocity shifted by U(-1, 1) m/s every 10 s)",
            Mode::Biped,
            true,
        ),
    ]
}

/// Every scenario name, plus the composite `table_vi`.
pub fn scenario_names() -> Vec<&'static str> {
    let mut names: Vec<&'static str> = scenarios().iter().map(|s| s.name).collect();
    names.push(TABLE_VI);
    names
}

/// The scenario called `name`.
pub fn scenario(name: &str) -> Result<Scenario, EvalError> {
    scenarios()
        .into_iter()
        .find(|s| s.name == name)
        .ok_or_else(|| EvalError::UnknownScenario {
            name: name.to_string(),
            known: scenario_names().join(", "),
        })
}

/// The names of the Table VI scenarios, in the table's column order.
pub fn table_vi_scenarios() -> Vec<Scenario> {
    scenarios()
        .into_iter()
        .filter(|s| matches!(&s.kind, ScenarioKind::Traversal(t) if t.table_vi_column.is_some()))
        .collect()
}

/// A long time (s): the longest resampling time the config accepts, so nothing is redrawn.
const NEVER_S: f32 = 3600.0;

/// The base config made calm and deterministic for an evaluation of `run_s` seconds: default
/// joints, no initial velocity or tilt, no pushes, no spread of episode start times, no command
/// or mode redraws (callers set those they want).
pub fn calm_config(base: &TaskConfig, run_s: f32) -> TaskConfig {
    let mut c = base.clone();
    c.env.random_initial_episode_step = false;
    c.env.episode_length_s = c.env.episode_length_s.max(run_s + 1.0);
    c.init.hip = [0.0, 0.0];
    c.init.thigh = [0.0, 0.0];
    c.init.calf = [0.0, 0.0];
    c.init.linvel = [0.0, 0.0];
    c.init.angvel = [0.0, 0.0];
    c.init.pitch = [0.0, 0.0];
    c.init.yaw = [0.0, 0.0];
    c.randomization.push_interval_s = 0.0;
    c.modes.resampling_time_s = NEVER_S;
    c.commands.resampling_time_s = NEVER_S;
    c
}

/// Pin the mode for the whole run.
pub fn pin_mode(c: &mut TaskConfig, mode: Mode) {
    c.modes.biped_probability = match mode {
        Mode::Biped => 1.0,
        Mode::Quad => 0.0,
    };
    c.modes.resampling_time_s = NEVER_S;
}

/// Set `mode`'s commands to vx in `vx`, vy = 0, yaw rate 0.
pub fn pin_command(c: &mut TaskConfig, mode: Mode, vx: [f32; 2]) {
    let ranges = match mode {
        Mode::Biped => &mut c.commands.biped,
        Mode::Quad => &mut c.commands.quad,
    };
    ranges.vx = vx;
    ranges.vy = [0.0, 0.0];
    ranges.wz = [0.0, 0.0];
}

/// The config of one traversal case.
pub fn traversal_config(
    base: &TaskConfig,
    spec: &TraversalSpec,
    case: &TraversalCase,
) -> Result<TaskConfig, EvalError> {
    let mut c = calm_config(base, spec.time_limit_s);
    pin_mode(&mut c, spec.mode);
    let v = spec.speed_mps * case.direction;
    pin_command(&mut c, Mode::Quad, [v, v]);
    pin_command(&mut c, Mode::Biped, [v, v]);
    c.validate()?;
    Ok(c)
}

/// The config of a transition scenario: the mode pinned to `from` for the whole run (the
/// evaluation switches the envs itself at `switch_s`), commands pinned for both modes.
pub fn transition_config(
    base: &TaskConfig,
    spec: &TransitionSpec,
) -> Result<TaskConfig, EvalError> {
    // `!(x > 0)` rather than `x <= 0` so that NaN is refused too.
    if !(spec.switch_s > 0.0 && spec.window_s > 0.0) {
        return Err(EvalError::InvalidOption(format!(
            "transition switch time {} s and window {} s must both be positive",
            spec.switch_s, spec.window_s
        )));
    }
    let mut c = calm_config(base, spec.switch_s + spec.window_s);
    pin_mode(&mut c, spec.from);
    pin_command(&mut c, spec.from, spec.vx_from);
    pin_command(&mut c, spec.to, spec.vx_to);
    c.validate()?;
    Ok(c)
}

/// The config of a tracking scenario: the mode pinned, commands as the base config draws them,
/// Table V's pushes if the spec asks for them (they act only with the base config's domain
/// randomisation enabled, as in training).
pub fn tracking_config(base: &TaskConfig, spec: &TrackingSpec) -> Result<TaskConfig, EvalError> {
    let mut c = calm_config(base, spec.duration_s);
    c.commands.resampling_time_s = base.commands.resampling_time_s;
    if spec.pushes {
        c.randomization.push_interval_s = PUSH_INTERVAL_S;
        c.randomization.push_velocity = PUSH_VELOCITY_MPS;
    }
    pin_mode(&mut c, spec.mode);
    c.validate()?;
    Ok(c)
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn every_table_vi_traversal_steers_with_the_same_gain() {
        for s in table_vi_scenarios() {
            assert_eq!(
                traversal_spec(s.name).heading_gain,
                HEADING_GAIN,
                "{}",
                s.name
            );
        }
    }

    fn traversal_spec(name: &str) -> TraversalSpec {
        match scenario(name).expect(name).kind {
            ScenarioKind::Traversal(t) => t,
            other => panic!("{name} is no traversal: {other:?}"),
        }
    }

    #[test]
    fn time_limits_follow_the_commanded_speed() {
        // 4 m to the tile's edge + 0.5 m: 4.5 / 0.4 * 1.5 + 2 = 18.875 s on two legs; on four,
        // 4.5 / 0.8 * 1.5 + 1 = 9.44 s, under the 16 s floor.
        assert_eq!(Obstacle::Flat.half_extent(), 4.0);
        for name in [
            "slope_biped",
            "stairs_up_biped",
            "stairs_down_biped",
            "flat_biped",
        ] {
            let t = traversal_spec(name);
            assert!((t.time_limit_s - 18.875).abs() < 1e-4, "{name}: {t:?}");
        }
        for name in [
            "slope_quad",
            "stairs_up_quad",
            "stairs_down_quad",
            "flat_quad",
        ] {
            assert_eq!(traversal_spec(name).time_limit_s, 16.0, "{name}");
        }
        assert!((traversal_time_limit_s(Mode::Quad, 0.5, 6.0) - 19.0).abs() < 1e-5);
    }

    #[test]
    fn table_vi_columns_walk_half_forward_half_backward() {
        let columns = table_vi_scenarios();
        assert_eq!(columns.len(), 6);
        for s in columns {
            let ScenarioKind::Traversal(t) = &s.kind else {
                panic!("{}", s.name)
            };
            let forward = t.cases.iter().filter(|c| c.direction > 0.0).count();
            let backward = t.cases.iter().filter(|c| c.direction < 0.0).count();
            assert_eq!(forward, backward, "{}", s.name);
            assert_eq!(s.default_envs % t.cases.len(), 0, "{}: even split", s.name);
            if s.name.starts_with("slope") {
                // Both ways up and both ways down.
                let names: Vec<_> = t.cases.iter().map(|c| c.name).collect();
                assert_eq!(
                    names,
                    ["up_forward", "down_forward", "up_backward", "down_backward"]
                );
                for c in &t.cases {
                    let up = matches!(c.obstacle, Obstacle::SlopeUp { .. });
                    assert_eq!(c.group, Some(if up { "up" } else { "down" }), "{c:?}");
                }
            }
        }
    }

    #[test]
    fn push_scenarios_push_as_table_v() {
        let base = TaskConfig::embedded_default();
        for (name, pushes) in [
            ("tracking_quad", false),
            ("tracking_biped", false),
            ("tracking_quad_push", true),
            ("tracking_biped_push", true),
        ] {
            let ScenarioKind::Tracking(spec) = scenario(name).expect(name).kind else {
                panic!("{name}")
            };
            assert_eq!(spec.pushes, pushes, "{name}");
            let c = tracking_config(&base, &spec).expect(name);
            // 10 s at the 50 Hz policy rate.
            let want = pushes.then_some(500);
            assert_eq!(c.push_interval_steps(), want, "{name}");
            if pushes {
                assert_eq!(c.randomization.push_velocity, 1.0);
            }
        }
        assert!(scenario_names().contains(&"tracking_biped_push"));
    }
}
