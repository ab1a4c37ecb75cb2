//! What happens to each recorded env (falls, head hits, time-outs, mode switches), logged as
//! events on its outcome entity.

use rerun::{RecordingStream, TextLog, TextLogLevel};
use unigait_sim::env::VecEnv;

use crate::entity;
use crate::error::{RecordError, log_err};
use crate::scene::ScenePaths;

/// What the recorder remembers of one recorded env between steps.
#[derive(Clone, Debug)]
pub(crate) struct Tracked {
    pub(crate) index: usize,
    pub(crate) paths: ScenePaths,
    pub(crate) mode: u8,
    pub(crate) head_contact: bool,
    pub(crate) falls: u32,
    pub(crate) head_hits: u32,
    pub(crate) time_outs: u32,
    pub(crate) mode_switches: u32,
}

pub(crate) fn mode_name(code: u8) -> &'static str {
    match code {
        1 => "biped",
        2 => "quad",
        _ => "unknown",
    }
}

/// Falls, head hits (each new contact), time-outs and mode switches of a recorded env after a
/// step, as events on its outcome entity.
pub(crate) fn log_outcome_events(
    rec: &RecordingStream,
    t: &mut Tracked,
    env: &VecEnv,
    step: u64,
    t_s: f64,
) -> Result<(), RecordError> {
    let out = env.output();
    let k = t.index;
    let mut events: Vec<(String, &str)> = Vec::new();
    let head = out.head_contact[k] != 0;
    if step > 0 {
        if head && !t.head_contact {
            t.head_hits += 1;
            events.push((
                format!("env {k}: head hit the ground at {t_s:.2} s"),
                TextLogLevel::WARN,
            ));
        }
        if out.terminated[k] != 0 {
            t.falls += 1;
            events.push((
                format!("env {k}: fell (base contact) at {t_s:.2} s; reset"),
                TextLogLevel::WARN,
            ));
        } else if out.truncated[k] != 0 {
            t.time_outs += 1;
            events.push((
                format!("env {k}: episode time-out at {t_s:.2} s; reset"),
                TextLogLevel::INFO,
            ));
        }
        if out.mode[k] != t.mode {
            t.mode_switches += 1;
            events.push((
                format!(
                    "env {k}: mode {} -> {} at {t_s:.2} s",
                    mode_name(t.mode),
                    mode_name(out.mode[k])
                ),
                TextLogLevel::INFO,
            ));
        }
    }
    t.head_contact = head;
    t.mode = out.mode[k];
    for (text, level) in events {
        rec.log(entity::outcome(k), &TextLog::new(text).with_level(level))
            .map_err(log_err)?;
    }
    Ok(())
}
