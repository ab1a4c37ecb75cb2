//! The terrain curriculum as pure functions: which column an env starts in, what an episode
//! walked against what its commands asked for, and how its level changes between episodes.
//!
//! legged_gym promotes an env that ended more than half a tile (4 m) from its spawn point and
//! demotes one that ended less than half of |last command| x episode length away. That fits its
//! setup (one command per 10 s, mostly straight) and not ours: the mode, and with it the command
//! (forward or backward, with a yaw rate), is redrawn every 6 s of an 18 s episode. In a Monte
//! Carlo of our command schedule (2000 episodes, task.toml ranges) a robot that tracks every
//! command perfectly ends a median 3.3 m from its spawn (2.9 m in all-biped episodes): that rule
//! promotes it in 38 % of episodes (24 % all-biped) and demotes it in 44 %. Here both distances
//! are integrated per step instead: the commanded one is the integral of |commanded xy velocity|
//! (so a biped's slower commands ask for less, and a mode switch is accounted for), the walked
//! one the integral of the base's velocity along the commanded direction, so perfect tracking
//! walks exactly what was asked whatever the turns (promoted in 99 % of those episodes, 97 %
//! all-biped; the rest asked for less than the 2 m minimum).

use rand::{Rng, RngExt};

use crate::error::SimError;

/// The grid column of env `env_index` of `num_envs` with `num_columns` columns: envs fill the
/// columns in contiguous blocks, as legged_gym (`floor(index / (num_envs / num_columns))`).
pub fn initial_column(env_index: usize, num_envs: usize, num_columns: u32) -> u32 {
    let columns = num_columns.max(1) as usize;
    let n = num_envs.max(1);
    ((env_index.min(n - 1) * columns) / n) as u32
}

/// What one episode walked against what its commands asked for, summed per policy step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EpisodeDistance {
    /// Distance walked along the commanded direction (m): the integral of the base's velocity
    /// projected on the unit command. Walking against the command counts negative.
    pub walked: f32,
    /// Distance the commands asked for (m): the integral of |commanded xy velocity|.
    pub commanded: f32,
    /// The part of `commanded` asked for in biped mode (m).
    pub commanded_biped: f32,
    /// The part of `walked` walked in biped mode (m).
    pub walked_biped: f32,
    /// How far from the spawn point the base got, against how far the commands would have
    /// taken it (decision record 0038).
    pub reach: Reach,
}

/// The farthest an episode's base got from its spawn point, and the farthest its commanded path
/// did, per mode (quad, biped). The commanded path starts at the spawn point and heading and
/// follows the commands (its heading turns at the commanded yaw rate, never at the robot's); at
/// a mode switch it restarts from where the base is, so one mode's shortfall is not charged to
/// the other. A robot that turns at a riser and walks along it tracks its command in its own
/// frame but gets no farther from the spawn point, while its commanded path climbs on.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Reach {
    /// Farthest distance from the spawn point (m) the base reached, per mode.
    pub walked: [f32; 2],
    /// Farthest distance from the spawn point (m) the commanded path reached, per mode.
    pub commanded: [f32; 2],
    /// The commanded path's point (m, from the spawn point, world frame), heading (rad) and
    /// mode (biped or not); `None` before the episode's first step.
    path: Option<([f32; 2], f32, bool)>,
    /// The base's offset from the spawn point after the last step (m).
    last: [f32; 2],
}

impl Reach {
    /// One step of `dt` seconds: the base is at `offset` from the spawn point (m, world frame)
    /// with heading `yaw` (rad), under `command` (vx, vy in the heading frame, m/s; yaw rate,
    /// rad/s), in biped mode or not.
    pub fn add_step(
        &mut self,
        offset: [f32; 2],
        yaw: f32,
        command: [f32; 3],
        dt: f32,
        biped: bool,
    ) {
        if !(offset.iter().chain(&command).all(|v| v.is_finite()) && yaw.is_finite()) {
            return;
        }
        let (mut point, mut heading) = match self.path {
            // A mode switch restarts the path where the base was, keeping the commanded heading.
            Some((point, heading, mode)) if mode == biped => (point, heading),
            Some((_, heading, _)) => (self.last, heading),
            None => ([0.0, 0.0], yaw),
        };
        self.last = offset;
        let (sin, cos) = heading.sin_cos();
        point[0] += (cos * command[0] - sin * command[1]) * dt;
        point[1] += (sin * command[0] + cos * command[1]) * dt;
        heading += command[2] * dt;
        self.path = Some((point, heading, biped));
        let m = usize::from(biped);
        self.walked[m] = self.walked[m].max(offset[0].hypot(offset[1]));
        self.commanded[m] = self.commanded[m].max(point[0].hypot(point[1]));
    }

    /// The base's reach as a share of the commanded path's, the farthest of either mode; 1 when
    /// the commands asked for less than 1 cm.
    pub fn share(&self) -> f32 {
        let commanded = self.commanded[0].max(self.commanded[1]);
        if commanded < 0.01 {
            1.0
        } else {
            self.farthest() / commanded
        }
    }

    /// The farthest the base got from its spawn point in either mode (m).
    pub fn farthest(&self) -> f32 {
        self.walked[0].max(self.walked[1])
    }

    /// One mode's part, the other's emptied.
    fn in_mode(&self, biped: bool) -> Self {
        let keep = |r: [f32; 2]| if biped { [0.0, r[1]] } else { [r[0], 0.0] };
        Self {
            walked: keep(self.walked),
            commanded: keep(self.commanded),
            ..*self
        }
    }
}

impl EpisodeDistance {
    /// Add one step of `dt` seconds under the xy command `command` (m/s, heading frame) while
    /// the base moved at `velocity` (m/s, same frame), in biped mode or not. A zero command
    /// adds nothing.
    pub fn add_step(&mut self, command: [f32; 2], velocity: [f32; 2], dt: f32, biped: bool) {
        let speed = command[0].hypot(command[1]);
        if speed > 0.0 && speed.is_finite() && velocity.iter().all(|v| v.is_finite()) {
            self.add_commanded(speed * dt, biped);
            let walked = (velocity[0] * command[0] + velocity[1] * command[1]) / speed * dt;
            self.walked += walked;
            if biped {
                self.walked_biped += walked;
            }
        }
    }

    /// An episode that ended early (a fall) is judged on its full length, as legged_gym's
    /// |command| x episode length: the `seconds` it did not live count as commanded at the last
    /// command `command` (in the mode it fell in) and not walked.
    pub fn add_unlived(&mut self, command: [f32; 2], seconds: f32, biped: bool) {
        let speed = command[0].hypot(command[1]);
        if speed.is_finite() && seconds > 0.0 {
            self.add_commanded(speed * seconds, biped);
        }
    }

    fn add_commanded(&mut self, distance: f32, biped: bool) {
        self.commanded += distance;
        if biped {
            self.commanded_biped += distance;
        }
    }

    /// The part of the episode spent in one mode (biped or not), as if it were the whole.
    pub fn in_mode(&self, biped: bool) -> Self {
        if biped {
            Self {
                walked: self.walked_biped,
                commanded: self.commanded_biped,
                commanded_biped: self.commanded_biped,
                walked_biped: self.walked_biped,
                reach: self.reach.in_mode(true),
            }
        } else {
            Self {
                walked: self.walked - self.walked_biped,
                commanded: self.commanded - self.commanded_biped,
                commanded_biped: 0.0,
                walked_biped: 0.0,
                reach: self.reach.in_mode(false),
            }
        }
    }

    /// `quad_share` of the distance asked for on four legs plus `biped_share` of the distance
    /// asked for on two.
    pub fn line(&self, quad_share: f32, biped_share: f32) -> f32 {
        quad_share * (self.commanded - self.commanded_biped) + biped_share * self.commanded_biped
    }
}

/// When an episode moves its env up or down a level: the task config's `[terrain_curriculum]`
/// (decision records 0022 and 0027).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LevelRule {
    /// Up when walked > this x the distance commanded on four legs (plus the biped's share of
    /// the distance commanded on two) ...
    pub promote_share: f32,
    /// ... and walked >= this (m).
    pub promote_min_distance: f32,
    /// Down when walked < this x the distance commanded on four legs (plus the biped's share
    /// of the distance commanded on two), and not up.
    pub demote_share: f32,
    /// `promote_share` for the distance commanded in biped mode.
    pub promote_share_biped: f32,
    /// `demote_share` for the distance commanded in biped mode.
    pub demote_share_biped: f32,
    /// Each env keeps a level per mode: an episode starts on the tile of its first mode's
    /// level, and only what it walked in that mode moves that level (decision record 0036).
    /// Off: one level per env, judged on both modes together.
    pub per_mode_levels: bool,
    /// The walked distance counts only as far as the robot's reach from its spawn point bears
    /// it out: at most its commanded distance times its reach over its commanded path's
    /// ([`Reach`], decision record 0038). Off: the walked distance alone, which a robot that
    /// turns at a riser and walks along it makes in full.
    pub judge_reach: bool,
    /// Up only when the base also got this far from its spawn point (m), in the judged mode:
    /// legged_gym's own promotion, half a tile, which slow commands cannot lower
    /// (decision record 0038). 0: no such bound.
    pub promote_min_reach: f32,
}

impl Default for LevelRule {
    fn default() -> Self {
        Self {
            // 0.7: the shipped flat policy tracks a biped's 0.4 m/s command ~0.1 m/s short
            // (~75 %), so it promotes on terrain it walks as on flat ground; one that slows
            // below 70 % stays, below 50 % (demote_share) goes down.
            promote_share: 0.7,
            // 2 m: past the 1.5 m from the spawn to the platform's edge, i.e. onto the tile's
            // terrain; a biped at a typical 0.3 m/s covers it in 7 s of its 18 s episode.
            promote_min_distance: 2.0,
            // 0.5, as legged_gym.
            demote_share: 0.5,
            // The same lines on two legs unless a run says otherwise (decision record 0027).
            promote_share_biped: 0.7,
            demote_share_biped: 0.5,
            per_mode_levels: false,
            judge_reach: false,
            promote_min_reach: 0.0,
        }
    }
}

impl LevelRule {
    /// Shares in [0, 1], demotion below promotion in each mode, a distance in [0, 1000] m.
    pub fn validate(&self) -> Result<(), SimError> {
        let check = |field: &str, value: f32, hi: f32| {
            if value.is_finite() && (0.0..=hi).contains(&value) {
                Ok(())
            } else {
                Err(SimError::invalid(
                    format!("terrain_curriculum.{field}"),
                    value,
                    format!("allowed range [0, {hi}]"),
                ))
            }
        };
        check("promote_share", self.promote_share, 1.0)?;
        check("promote_share_biped", self.promote_share_biped, 1.0)?;
        // Demoting above the promotion share would move an env both ways.
        check("demote_share", self.demote_share, self.promote_share)?;
        check(
            "demote_share_biped",
            self.demote_share_biped,
            self.promote_share_biped,
        )?;
        check("promote_min_distance", self.promote_min_distance, 1000.0)?;
        check("promote_min_reach", self.promote_min_reach, 1000.0)
    }
}

/// The level after an episode: up one when the env walked more than its promotion line
/// (`promote_share` of the distance commanded on four legs plus `promote_share_biped` of the
/// distance commanded on two), at least `promote_min_distance` and, with `promote_min_reach`, got
/// that far from its spawn point; down one when it walked less
/// than its demotion line and is not moving up (legged_gym's demotion). Going down stops at level
/// 0; going past the top level sends the env to a level drawn uniformly from `0..num_levels`, so
/// solved envs keep visiting every level (legged_gym). Why relative to the commands:
/// docs/src/decisions/0022-command-relative-promotion.md.
pub fn next_level(
    current: u32,
    episode: EpisodeDistance,
    rule: &LevelRule,
    num_levels: u32,
    rng: &mut impl Rng,
) -> u32 {
    let walked = if rule.judge_reach {
        episode
            .walked
            .min(episode.commanded * episode.reach.share())
    } else {
        episode.walked
    };
    let up = walked > episode.line(rule.promote_share, rule.promote_share_biped)
        && walked >= rule.promote_min_distance
        && episode.reach.farthest() >= rule.promote_min_reach;
    let down = !up && walked < episode.line(rule.demote_share, rule.demote_share_biped);
    if up {
        let next = current.saturating_add(1);
        if next >= num_levels {
            return rng.random_range(0..num_levels.max(1));
        }
        next
    } else if down {
        current.saturating_sub(1)
    } else {
        current.min(num_levels.saturating_sub(1))
    }
}

#[cfg(test)]
#[path = "curriculum_test.rs"]
mod test;
