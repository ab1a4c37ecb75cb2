//! The measures, as small pure functions over per-step traces (unit-tested on hand-made traces).

use serde::Serialize;

/// Pitch above which the robot stands on its front legs: the paper's upright indicator (rad).
pub const UPRIGHT_PITCH: f32 = 1.4;
/// |pitch| below which the robot is back on four legs (rad).
pub const QUAD_PITCH: f32 = 0.35;
/// A posture counts as reached once it has held this long (s).
pub const HOLD_S: f32 = 0.3;
/// Steps after a reset or a mode change left out of the tracking error (s).
pub const TRACKING_SETTLE_S: f32 = 1.0;
/// Biped time this soon after a reset or a mode change is left out of the upright share (s):
/// the robot is still getting up.
pub const UPRIGHT_SETTLE_S: f32 = 2.0;

/// How one traversal trial ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TraversalEnd {
    /// Got the whole distance.
    Crossed,
    /// The base touched the terrain (or the physics blew up) first.
    Terminated,
    /// Ran out of time.
    TimedOut,
}

/// Decide one step of a traversal trial: `progress` (m along the commanded direction),
/// whether the env terminated or was truncated in this step. Returns the end, if it ended.
///
/// A termination ends the trial as a failure whatever the progress: a robot that falls past
/// the line did not cross the obstacle.
pub fn traversal_step(
    progress: f32,
    distance: f32,
    terminated: bool,
    truncated: bool,
) -> Option<TraversalEnd> {
    if terminated {
        Some(TraversalEnd::Terminated)
    } else if progress >= distance {
        Some(TraversalEnd::Crossed)
    } else if truncated {
        Some(TraversalEnd::TimedOut)
    } else {
        None
    }
}

/// First index `i >= start` from which `holds(trace[j])` is true for every j in
/// `i .. i + hold` (and the trace is long enough to tell).
pub fn first_sustained(
    trace: &[f32],
    start: usize,
    hold: usize,
    holds: impl Fn(f32) -> bool,
) -> Option<usize> {
    let hold = hold.max(1);
    let mut run = 0usize;
    for (i, &v) in trace.iter().enumerate().skip(start) {
        if holds(v) {
            run += 1;
            if run >= hold {
                return Some(i + 1 - hold);
            }
        } else {
            run = 0;
        }
    }
    None
}

/// Mean, standard deviation, min and max of `values` (all 0 when empty).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    /// Samples.
    pub count: usize,
    /// Mean.
    pub mean: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
}

impl Summary {
    /// Summarise `values`.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let (mut n, mut sum, mut sq) = (0usize, 0.0, 0.0);
        let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values {
            n += 1;
            sum += v;
            sq += v * v;
            min = min.min(v);
            max = max.max(v);
        }
        if n == 0 {
            return Self::default();
        }
        let mean = sum / n as f64;
        Self {
            count: n,
            mean,
            std: (sq / n as f64 - mean * mean).max(0.0).sqrt(),
            min,
            max,
        }
    }

    /// Max minus min.
    pub fn range(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.max - self.min
        }
    }
}

/// Running sums of the velocity tracking error in one mode.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrackingAccumulator {
    samples: u64,
    lin: f64,
    lin_sq: f64,
    forward: f64,
    lateral: f64,
    ang: f64,
    /// The same four sums for a policy that does nothing (zero velocity and yaw rate) under
    /// the same commands: what the figures above must beat to mean anything.
    idle: [f64; 4],
}

/// The tracking error a policy that does nothing (base velocity and yaw rate 0) would have on
/// the same samples: computed from the commands alone, nothing simulated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DoNothingStats {
    /// Mean |v*_xy| (m/s).
    pub lin_vel_error_mps: f64,
    /// Mean |v*_x| (m/s).
    pub forward_error_mps: f64,
    /// Mean |v*_y| (m/s).
    pub lateral_error_mps: f64,
    /// Mean |w*_z| (rad/s).
    pub ang_vel_error_radps: f64,
}

/// Velocity tracking error of one mode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TrackingStats {
    /// Env steps counted.
    pub samples: u64,
    /// Mean |v*_xy - v_xy| in the heading frame (m/s).
    pub lin_vel_error_mps: f64,
    /// Root mean square of the same (m/s).
    pub lin_vel_rmse_mps: f64,
    /// Mean |v*_x - v_x|, along the heading (m/s): how well the walk follows forward commands.
    pub forward_error_mps: f64,
    /// Mean |v*_y - v_y|, across the heading (m/s): a gait that only walks forward and back
    /// shows up here, however well it does that.
    pub lateral_error_mps: f64,
    /// Mean |w*_z - w_z| (rad/s).
    pub ang_vel_error_radps: f64,
    /// The same figures for a policy that does nothing, over the same samples.
    pub do_nothing: DoNothingStats,
}

impl TrackingAccumulator {
    /// Add one env step: command (vx, vy, wz), measured heading-frame (vx, vy) and yaw rate.
    pub fn add(&mut self, command: [f32; 3], velocity_xy: [f32; 2], yaw_rate: f32) {
        let (dx, dy) = (command[0] - velocity_xy[0], command[1] - velocity_xy[1]);
        let e = f64::from((dx * dx + dy * dy).sqrt());
        self.samples += 1;
        self.lin += e;
        self.lin_sq += e * e;
        self.forward += f64::from(dx.abs());
        self.lateral += f64::from(dy.abs());
        self.ang += f64::from((command[2] - yaw_rate).abs());
        let idle = [
            command[0].hypot(command[1]),
            command[0].abs(),
            command[1].abs(),
            command[2].abs(),
        ];
        for (sum, e) in self.idle.iter_mut().zip(idle) {
            *sum += f64::from(e);
        }
    }

    /// Add another accumulator's samples.
    pub fn merge(&mut self, other: &TrackingAccumulator) {
        self.samples += other.samples;
        self.lin += other.lin;
        self.lin_sq += other.lin_sq;
        self.forward += other.forward;
        self.lateral += other.lateral;
        self.ang += other.ang;
        for (sum, e) in self.idle.iter_mut().zip(other.idle) {
            *sum += e;
        }
    }

    /// The means (None without samples).
    pub fn stats(&self) -> Option<TrackingStats> {
        (self.samples > 0).then(|| {
            let n = self.samples as f64;
            TrackingStats {
                samples: self.samples,
                lin_vel_error_mps: self.lin / n,
                lin_vel_rmse_mps: (self.lin_sq / n).sqrt(),
                forward_error_mps: self.forward / n,
                lateral_error_mps: self.lateral / n,
                ang_vel_error_radps: self.ang / n,
                do_nothing: DoNothingStats {
                    lin_vel_error_mps: self.idle[0] / n,
                    forward_error_mps: self.idle[1] / n,
                    lateral_error_mps: self.idle[2] / n,
                    ang_vel_error_radps: self.idle[3] / n,
                },
            }
        })
    }
}

/// Head contacts over a rollout: the head is not the trunk, so touching the terrain with it
/// neither ends an episode nor costs reward, and is counted here instead.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct HeadHits {
    /// Times a head came down on the terrain (steps with contact after a step without, per env).
    pub hits: u64,
    /// Env steps with the head on the terrain.
    pub contact_steps: u64,
    /// Env steps counted.
    pub env_steps: u64,
}

impl HeadHits {
    /// Count one step of every env: `contact` now and `before` (the last step's flags, updated).
    pub fn add_step(&mut self, contact: &[u8], before: &mut [bool]) {
        for (c, b) in contact.iter().zip(before.iter_mut()) {
            let now = *c != 0;
            self.hits += u64::from(now && !*b);
            self.contact_steps += u64::from(now);
            *b = now;
        }
        self.env_steps += contact.len() as u64;
    }

    /// Add another count.
    pub fn merge(&mut self, other: &HeadHits) {
        self.hits += other.hits;
        self.contact_steps += other.contact_steps;
        self.env_steps += other.env_steps;
    }

    /// Share of env steps with the head on the terrain (0 without steps).
    pub fn contact_share(&self) -> f64 {
        if self.env_steps == 0 {
            0.0
        } else {
            self.contact_steps as f64 / self.env_steps as f64
        }
    }
}

/// How the episodes of a rollout ended, and how long biped mode stood upright.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EpisodeOutcomes {
    /// Episodes ended by a termination, by the mode in force when they ended (biped, quad).
    pub terminated: [u64; 2],
    /// Episodes counted (ended, or still running at the end), by the same mode.
    pub episodes: [u64; 2],
    /// Biped-mode env steps at least [`UPRIGHT_SETTLE_S`] into their episode and mode.
    pub biped_steps: u64,
    /// Of those, the steps with pitch > [`UPRIGHT_PITCH`].
    pub upright_steps: u64,
    /// Sum of the pitch over the same steps (rad): how far up a policy that is not upright yet
    /// gets (one resting on its head sits well below the upright threshold).
    pub pitch_sum: f64,
}

impl EpisodeOutcomes {
    /// Add another count.
    pub fn merge(&mut self, other: &EpisodeOutcomes) {
        for m in 0..2 {
            self.terminated[m] += other.terminated[m];
            self.episodes[m] += other.episodes[m];
        }
        self.biped_steps += other.biped_steps;
        self.upright_steps += other.upright_steps;
        self.pitch_sum += other.pitch_sum;
    }

    /// Share of the episodes of mode index `m` (0 biped, 1 quad) ended by a termination.
    pub fn termination_rate(&self, m: usize) -> Option<f64> {
        rate(self.terminated[m] as usize, self.episodes[m] as usize)
    }

    /// Share of the counted biped steps spent upright.
    pub fn upright_share(&self) -> Option<f64> {
        rate(self.upright_steps as usize, self.biped_steps as usize)
    }

    /// Mean pitch over the counted biped steps (rad).
    pub fn mean_biped_pitch(&self) -> Option<f64> {
        (self.biped_steps > 0).then(|| self.pitch_sum / self.biped_steps as f64)
    }
}

/// The median of `values` (None when empty).
pub fn median(values: &[f64]) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

/// A rate that is None when there were no trials.
pub fn rate(hits: usize, trials: usize) -> Option<f64> {
    (trials > 0).then(|| hits as f64 / trials as f64)
}

/// The normal quantile of a two-sided 95% interval.
pub const Z95: f64 = 1.959964;

/// Wilson score 95% interval [low, high] of `hits` in `trials` (None without trials): unlike
/// p +- z sqrt(p (1 - p) / n) it stays inside [0, 1] and does not shrink to a point at 0 or n
/// hits, which is where small evaluations sit.
pub fn wilson_interval(hits: usize, trials: usize) -> Option<[f64; 2]> {
    if trials == 0 {
        return None;
    }
    let n = trials as f64;
    let p = hits.min(trials) as f64 / n;
    let z2 = Z95 * Z95;
    let d = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / d;
    let half = Z95 / d * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    // At 0 or n hits a bound is exactly 0 or 1; rounding would leave it a hair inside.
    let low = if hits == 0 { 0.0 } else { centre - half };
    let high = if hits >= trials { 1.0 } else { centre + half };
    Some([low.max(0.0), high.min(1.0)])
}

/// Insert the rate `name` = hits / trials with `name_ci95_low` and `name_ci95_high` (its
/// Wilson interval); nothing without trials.
pub fn insert_rate(
    metrics: &mut std::collections::BTreeMap<String, f64>,
    name: &str,
    hits: usize,
    trials: usize,
) {
    if let (Some(r), Some([low, high])) = (rate(hits, trials), wilson_interval(hits, trials)) {
        metrics.insert(name.to_string(), r);
        metrics.insert(format!("{name}_ci95_low"), low);
        metrics.insert(format!("{name}_ci95_high"), high);
    }
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn a_fall_is_a_failure_even_past_the_line() {
        assert_eq!(
            traversal_step(5.0, 4.5, true, false),
            Some(TraversalEnd::Terminated)
        );
        assert_eq!(
            traversal_step(4.6, 4.5, false, false),
            Some(TraversalEnd::Crossed)
        );
        assert_eq!(
            traversal_step(1.0, 4.5, false, true),
            Some(TraversalEnd::TimedOut)
        );
        assert_eq!(traversal_step(1.0, 4.5, false, false), None);
    }

    #[test]
    fn sustained_posture_needs_the_whole_hold() {
        let pitch = [0.0, 1.5, 1.3, 1.5, 1.5, 1.5, 1.2];
        let up = |p: f32| p > UPRIGHT_PITCH;
        assert_eq!(first_sustained(&pitch, 0, 3, up), Some(3));
        assert_eq!(first_sustained(&pitch, 0, 1, up), Some(1));
        assert_eq!(first_sustained(&pitch, 0, 4, up), None);
        assert_eq!(first_sustained(&pitch, 4, 2, up), Some(4));
    }

    #[test]
    fn summary_and_tracking_by_hand() {
        let s = Summary::of([1.0, 3.0]);
        assert_eq!((s.count, s.mean, s.std, s.range()), (2, 2.0, 1.0, 2.0));
        assert_eq!(Summary::of([]).count, 0);
        let mut t = TrackingAccumulator::default();
        t.add([1.0, 0.0, 0.5], [0.0, 0.0], 0.0);
        t.add([0.0, 0.0, 0.0], [0.0, 0.0], 0.5);
        let s = t.stats().unwrap();
        assert_eq!(s.samples, 2);
        assert!((s.lin_vel_error_mps - 0.5).abs() < 1e-12);
        assert!((s.lin_vel_rmse_mps - 0.5f64.sqrt()).abs() < 1e-12);
        assert!((s.ang_vel_error_radps - 0.5).abs() < 1e-12);
        // A (0.3, -0.4) miss is 0.5 in all: 0.3 along the heading and 0.4 across it.
        let mut other = TrackingAccumulator::default();
        other.add([0.3, 0.0, 0.0], [0.0, 0.4], 0.0);
        t.merge(&other);
        let s = t.stats().unwrap();
        assert_eq!(s.samples, 3);
        assert!((s.lin_vel_error_mps - 0.5).abs() < 1e-6);
        assert!((s.forward_error_mps - 1.3 / 3.0).abs() < 1e-6);
        assert!((s.lateral_error_mps - 0.4 / 3.0).abs() < 1e-6);
        assert_eq!(TrackingAccumulator::default().stats(), None);
        assert_eq!(rate(0, 0), None);
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[1.0, 2.0]), Some(1.5));
        assert_eq!(median(&[]), None);
        assert_eq!(rate(1, 4), Some(0.25));
    }

    #[test]
    fn doing_nothing_costs_the_size_of_the_command() {
        let mut t = TrackingAccumulator::default();
        // Tracked exactly: no error of its own, while standing still would miss by the
        // command: |(0.3, -0.4)| = 0.5 and |(1, 0)| = 1.
        t.add([0.3, -0.4, 0.5], [0.3, -0.4], 0.5);
        t.add([1.0, 0.0, -0.2], [1.0, 0.0], -0.2);
        let s = t.stats().unwrap();
        assert!(s.lin_vel_error_mps.abs() < 1e-12 && s.ang_vel_error_radps.abs() < 1e-12);
        let d = s.do_nothing;
        assert!((d.lin_vel_error_mps - 0.75).abs() < 1e-6, "{d:?}");
        assert!((d.forward_error_mps - 0.65).abs() < 1e-6, "{d:?}");
        assert!((d.lateral_error_mps - 0.2).abs() < 1e-6, "{d:?}");
        assert!((d.ang_vel_error_radps - 0.35).abs() < 1e-6, "{d:?}");
        // A robot that stands still scores exactly the do-nothing figures, merged or not.
        let mut still = TrackingAccumulator::default();
        still.add([0.3, -0.4, 0.5], [0.0, 0.0], 0.0);
        let mut other = TrackingAccumulator::default();
        other.add([1.0, 0.0, -0.2], [0.0, 0.0], 0.0);
        still.merge(&other);
        let s = still.stats().unwrap();
        assert!((s.lin_vel_error_mps - s.do_nothing.lin_vel_error_mps).abs() < 1e-12);
        assert!((s.forward_error_mps - s.do_nothing.forward_error_mps).abs() < 1e-12);
        assert!((s.lateral_error_mps - s.do_nothing.lateral_error_mps).abs() < 1e-12);
        assert!((s.ang_vel_error_radps - s.do_nothing.ang_vel_error_radps).abs() < 1e-12);
        assert_eq!(s.do_nothing, d);
    }

    #[test]
    fn wilson_intervals_by_hand() {
        // (p + z^2/2n) / (1 + z^2/n) -+ z / (1 + z^2/n) sqrt(p (1 - p) / n + z^2 / 4n^2).
        let close = |got: [f64; 2], want: [f64; 2]| {
            assert!(
                (got[0] - want[0]).abs() < 1e-9 && (got[1] - want[1]).abs() < 1e-9,
                "{got:?} != {want:?}"
            );
        };
        close(
            wilson_interval(61, 64).unwrap(),
            [0.8710034617, 0.9839309833],
        );
        close(
            wilson_interval(17, 20).unwrap(),
            [0.6395811334, 0.9476312545],
        );
        close(wilson_interval(1, 2).unwrap(), [0.0945312046, 0.9054687954]);
        // No successes (or no failures) still leaves room on one side.
        close(wilson_interval(0, 20).unwrap(), [0.0, 0.1611251602]);
        close(wilson_interval(20, 20).unwrap(), [0.8388748398, 1.0]);
        assert_eq!(wilson_interval(0, 20).unwrap()[0], 0.0);
        assert_eq!(wilson_interval(20, 20).unwrap()[1], 1.0);
        assert_eq!(wilson_interval(0, 0), None);
        let mut m = std::collections::BTreeMap::new();
        insert_rate(&mut m, "success_rate", 61, 64);
        assert_eq!(m["success_rate"], 61.0 / 64.0);
        assert!((m["success_rate_ci95_low"] - 0.8710034617).abs() < 1e-9);
        assert!((m["success_rate_ci95_high"] - 0.9839309833).abs() < 1e-9);
        insert_rate(&mut m, "fall_rate", 0, 0);
        assert_eq!(m.len(), 3, "no trials, no rate: {m:?}");
    }

    #[test]
    fn episode_outcomes_by_hand() {
        let mut a = EpisodeOutcomes {
            terminated: [1, 0],
            episodes: [4, 2],
            biped_steps: 10,
            upright_steps: 9,
            pitch_sum: 15.0,
        };
        a.merge(&EpisodeOutcomes {
            terminated: [0, 1],
            episodes: [0, 2],
            biped_steps: 10,
            upright_steps: 8,
            pitch_sum: 14.0,
        });
        assert_eq!(a.termination_rate(0), Some(0.25));
        assert_eq!(a.termination_rate(1), Some(0.25));
        assert_eq!(a.upright_share(), Some(17.0 / 20.0));
        assert_eq!(a.mean_biped_pitch(), Some(29.0 / 20.0));
        assert_eq!(EpisodeOutcomes::default().termination_rate(0), None);
        assert_eq!(EpisodeOutcomes::default().mean_biped_pitch(), None);
    }

    #[test]
    fn a_head_hit_is_counted_once_per_landing() {
        let mut h = HeadHits::default();
        let mut before = [false, false];
        for step in [[1u8, 0], [1, 0], [0, 1], [1, 1]] {
            h.add_step(&step, &mut before);
        }
        // env 0 lands twice (steps 1 and 4), env 1 once (step 3).
        assert_eq!((h.hits, h.contact_steps, h.env_steps), (3, 5, 8));
        assert!((h.contact_share() - 5.0 / 8.0).abs() < 1e-12);
        assert_eq!(HeadHits::default().contact_share(), 0.0);
    }
}
