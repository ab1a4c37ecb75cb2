//! Where a batch's upright threshold stands (see [`UprightCurriculum`]): judged on counts of
//! biped-mode env-steps that the groups gather while they step.

use crate::task::{RewardParams, UprightCurriculum};

/// Biped-mode env-steps counted by a group since the batch last collected them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UprightCounts {
    /// Env-steps taken in biped mode.
    pub biped: u64,
    /// Of those, the ones ending above the threshold in force.
    pub above: u64,
}

impl UprightCounts {
    /// Count one biped-mode env-step.
    pub fn add(&mut self, above: bool) {
        self.biped += 1;
        self.above += u64::from(above);
    }
}

impl std::ops::AddAssign for UprightCounts {
    fn add_assign(&mut self, other: Self) {
        self.biped += other.biped;
        self.above += other.above;
    }
}

/// The threshold I_up uses now, and the counts of the window being judged.
#[derive(Clone, Debug, PartialEq)]
pub struct UprightThreshold {
    curriculum: UprightCurriculum,
    end: f32,
    current: f32,
    window: UprightCounts,
}

impl UprightThreshold {
    /// At the curriculum's start, or fixed at `upright_pitch` when it is off.
    pub fn new(rewards: &RewardParams) -> Self {
        let curriculum = rewards.upright_curriculum.clone();
        let end = rewards.upright_pitch;
        let current = if curriculum.enabled {
            curriculum.start.min(end)
        } else {
            end
        };
        Self {
            curriculum,
            end,
            current,
            window: UprightCounts::default(),
        }
    }

    /// The threshold in force (rad).
    pub fn current(&self) -> f32 {
        self.current
    }

    /// Add a step's counts; once the window holds `window_steps` biped env-steps, judge it
    /// (promote if at least `promote_share` were above) and start the next one.
    pub fn observe(&mut self, counts: UprightCounts) {
        if !self.curriculum.enabled || self.current >= self.end {
            return;
        }
        self.window += counts;
        if self.window.biped < u64::from(self.curriculum.window_steps) {
            return;
        }
        let share = self.window.above as f64 / self.window.biped as f64;
        if share >= f64::from(self.curriculum.promote_share) {
            self.current = (self.current + self.curriculum.step).min(self.end);
        }
        self.window = UprightCounts::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rewards(enabled: bool) -> RewardParams {
        RewardParams {
            upright_curriculum: UprightCurriculum {
                enabled,
                start: 1.2,
                step: 0.1,
                promote_share: 0.5,
                window_steps: 100,
            },
            ..RewardParams::default()
        }
    }

    fn counts(biped: u64, above: u64) -> UprightCounts {
        UprightCounts { biped, above }
    }

    #[test]
    fn off_means_the_fixed_threshold() {
        let mut t = UprightThreshold::new(&rewards(false));
        assert_eq!(t.current(), 1.4);
        t.observe(counts(1000, 1000));
        assert_eq!(t.current(), 1.4);
    }

    #[test]
    fn promotes_per_full_window_and_stops_at_the_paper_threshold() {
        let mut t = UprightThreshold::new(&rewards(true));
        assert_eq!(t.current(), 1.2);
        // 60 of 99: the window is not full yet.
        t.observe(counts(99, 60));
        assert_eq!(t.current(), 1.2);
        // 61 of 100 >= 0.5: up one step, the window starts afresh.
        t.observe(counts(1, 1));
        assert!((t.current() - 1.3).abs() < 1e-6);
        // 49 of 100 < 0.5: no change.
        t.observe(counts(100, 49));
        assert!((t.current() - 1.3).abs() < 1e-6);
        // Exactly half promotes; the next promotion is capped at upright_pitch (1.4).
        t.observe(counts(100, 50));
        assert!((t.current() - 1.4).abs() < 1e-6);
        t.observe(counts(100, 100));
        assert_eq!(t.current(), 1.4);
    }

    #[test]
    fn a_start_above_the_end_is_the_end() {
        let mut r = rewards(true);
        r.upright_pitch = 1.1;
        assert_eq!(UprightThreshold::new(&r).current(), 1.1);
    }
}
