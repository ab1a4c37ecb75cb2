//! How likely a policy is to meet a milestone on one draw it has not seen, estimated from
//! evaluations with many trials (the Python learner's `unigait.pass_chance`, the same rules):
//! a success rate (a metric named `…success_rate`, its trial count beside it as `…trials`) is
//! pooled over the seeds under a Jeffreys prior, and its chance is the beta-binomial
//! probability that a draw of the milestone's size meets the bound; any other check counts the
//! seeds on which it was met; a group needs `at_least` of its checks (taken as independent);
//! the milestone multiplies its criteria. Why: docs/src/decisions/0043-rank-checkpoints-by-pass-chance.md.

use crate::milestone::{Check, Evals, Milestone};

/// The trial count's metric beside a success rate (`a/success_rate` -> `a/trials`).
fn trials_metric(metric: &str) -> Option<String> {
    let (head, last) = metric.rsplit_once('/').unwrap_or(("", metric));
    if !last.ends_with("success_rate") {
        return None;
    }
    Some(if head.is_empty() {
        "trials".to_string()
    } else {
        format!("{head}/trials")
    })
}

/// The chance that `n` new trials meet `check`, having seen `successes` of `trials`: the rate's
/// posterior is Beta(successes + 1/2, failures + 1/2) and a draw's count beta-binomial. Its
/// probabilities follow from P(0) by their ratio, in logs so that long draws do not underflow.
fn draw_chance(check: &Check, successes: f64, trials: f64, n: u32) -> f64 {
    let (a, b) = (successes + 0.5, trials - successes + 0.5);
    let nf = f64::from(n);
    let mut log_p: f64 = (0..n)
        .map(|i| ((b + f64::from(i)) / (a + b + f64::from(i))).ln())
        .sum();
    let mut total = 0.0;
    for x in 0..=n {
        let xf = f64::from(x);
        if check.passes(Some(xf / nf)) {
            total += log_p.exp();
        }
        if x < n {
            log_p += ((nf - xf) / (xf + 1.0)).ln() + ((a + xf) / (b + nf - xf - 1.0)).ln();
        }
    }
    total.min(1.0)
}

/// The chance that one draw of `n` trials meets `check`, judged on every seed's evaluations.
fn check_chance(check: &Check, per_seed: &[Evals], n: u32) -> f64 {
    if let Some(counts) = trials_metric(&check.metric) {
        let pooled: Option<(f64, f64)> = per_seed.iter().try_fold((0.0, 0.0), |(s, t), e| {
            let rate = check.value(e)?;
            let trials = *e.get(&check.scenario)?.get(&counts)?;
            Some((s + (rate * trials).round(), t + trials))
        });
        if let Some((successes, trials)) = pooled.filter(|p| p.1 > 0.0) {
            return draw_chance(check, successes, trials, n);
        }
    }
    if per_seed.is_empty() {
        return 0.0;
    }
    let met = per_seed
        .iter()
        .filter(|e| check.passes(check.value(e)))
        .count();
    met as f64 / per_seed.len() as f64
}

/// The chance that at least `k` of independent events with `chances` happen.
fn at_least(chances: &[f64], k: usize) -> f64 {
    let mut exactly = vec![1.0];
    for &p in chances {
        let mut next = vec![0.0; exactly.len() + 1];
        for (j, &q) in exactly.iter().enumerate() {
            next[j] += q * (1.0 - p);
            next[j + 1] += q * p;
        }
        exactly = next;
    }
    exactly.iter().skip(k).sum()
}

impl Milestone {
    /// The chance that one draw meets the milestone: each scenario's draw has the milestone's
    /// size for it (Table VI: 20 trials a column), else `draw_envs`.
    pub fn pass_chance(&self, per_seed: &[Evals], draw_envs: u32) -> f64 {
        let mut chance = 1.0;
        let mut grouped: std::collections::BTreeMap<&str, Vec<f64>> = self
            .groups
            .keys()
            .map(|g| (g.as_str(), Vec::new()))
            .collect();
        for c in &self.checks {
            let p = check_chance(c, per_seed, self.envs_for(&c.scenario, draw_envs));
            match &c.group {
                None => chance *= p,
                Some(g) => grouped.entry(g.as_str()).or_default().push(p),
            }
        }
        for (group, need) in &self.groups {
            chance *= at_least(
                grouped.get(group.as_str()).map_or(&[][..], Vec::as_slice),
                *need,
            );
        }
        chance
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::milestone::{load_milestone, milestones_file};

    fn check(metric: &str, op: &str, bound: f64) -> Check {
        Check {
            scenario: "s".into(),
            metric: metric.into(),
            op: op.into(),
            bound,
            label: "l".into(),
            group: None,
        }
    }

    /// P(n of n) under Beta(s + 1/2, f + 1/2): the product of the posterior's successive means.
    fn every_one_of(n: u32, successes: f64, trials: f64) -> f64 {
        let (a, b) = (successes + 0.5, trials - successes + 0.5);
        (0..n)
            .map(|i| (a + f64::from(i)) / (a + b + f64::from(i)))
            .product()
    }

    fn close(a: f64, b: f64, tol: f64) {
        assert!((a - b).abs() <= tol, "{a} != {b}");
    }

    #[test]
    fn trials_sit_beside_each_success_rate() {
        assert_eq!(
            trials_metric("stairs_up_quad/success_rate").as_deref(),
            Some("stairs_up_quad/trials")
        );
        assert_eq!(
            trials_metric("strict_success_rate").as_deref(),
            Some("trials")
        );
        assert_eq!(trials_metric("tracking/quad/lin_vel_error_mps"), None);
    }

    #[test]
    fn draws_match_hand_computed_cases() {
        let all = check("success_rate", ">=", 1.0);
        close(draw_chance(&all, 3.0, 4.0, 1), 0.7, 1e-12);
        close(draw_chance(&all, 3.0, 4.0, 2), 3.5 * 4.5 / 30.0, 1e-12);
        close(
            draw_chance(&all, 128.0, 128.0, 20),
            every_one_of(20, 128.0, 128.0),
            1e-12,
        );
        close(
            draw_chance(&all, 125.0, 128.0, 20),
            every_one_of(20, 125.0, 128.0),
            1e-12,
        );
        // Many trials at 0.5: the binomial tail of 12 or more of 20.
        let most = check("success_rate", ">=", 0.6);
        let tail: f64 = (12..=20u64)
            .map(|x| (0..x).fold(1.0, |c, i| c * (20 - i) as f64 / (i + 1) as f64))
            .sum::<f64>()
            / 2f64.powi(20);
        close(draw_chance(&most, 5e5, 1e6, 20), tail, 1e-3);
        // At most one fall in 20 at 0.05; a 512-trial draw does not underflow.
        let falls = check("fall_rate", "<=", 0.05);
        let one = 0.95f64.powi(20) + 20.0 * 0.05 * 0.95f64.powi(19);
        close(draw_chance(&falls, 5e4, 1e6, 20), one, 1e-3);
        close(
            draw_chance(&all, 5000.0, 5000.0, 512),
            every_one_of(512, 5000.0, 5000.0),
            1e-9,
        );
    }

    #[test]
    fn at_least_k_of_independent_events() {
        close(at_least(&[0.5, 0.5], 1), 0.75, 1e-12);
        close(at_least(&[1.0, 1.0, 0.9, 0.5], 3), 0.95, 1e-12);
        close(at_least(&[0.3, 0.4], 3), 0.0, 1e-12);
    }

    #[test]
    fn m3_multiplies_its_checks_and_takes_4_of_6_as_the_python_learner() {
        let m3 = load_milestone("M3", &milestones_file()).unwrap();
        let mut seed = Evals::new();
        let flat = [
            ("tracking_quad", "tracking/quad/lin_vel_error_mps", 0.1),
            ("tracking_quad", "tracking/quad/ang_vel_error_radps", 0.1),
            ("tracking_quad", "tracking/quad/termination_rate", 0.0),
            ("tracking_biped", "tracking/biped/upright_share", 1.0),
            ("tracking_biped", "tracking/biped/lin_vel_error_mps", 0.1),
            ("transition_biped_to_quad", "success_rate", 1.0),
            ("transition_biped_to_quad", "trials", 64.0),
            ("transition_quad_to_biped", "success_rate", 1.0),
            ("transition_quad_to_biped", "trials", 64.0),
        ];
        for (s, m, v) in flat {
            seed.entry(s.into()).or_default().insert(m.into(), v);
        }
        let crossed = [
            ("stairs_up_quad", 128.0),
            ("stairs_down_quad", 128.0),
            ("slope_quad", 128.0),
            ("slope_biped", 100.0),
            ("stairs_up_biped", 40.0),
            ("stairs_down_biped", 127.0),
        ];
        for (column, n) in crossed {
            let t = seed.entry("table_vi".into()).or_default();
            t.insert(format!("{column}/success_rate"), n / 128.0);
            t.insert(format!("{column}/trials"), 128.0);
        }
        let switch = draw_chance(&check("success_rate", ">=", 0.9), 128.0, 128.0, 64);
        let most = check("success_rate", ">=", 0.6);
        let columns = [
            every_one_of(20, 256.0, 256.0),
            every_one_of(20, 256.0, 256.0),
            every_one_of(20, 256.0, 256.0),
            every_one_of(20, 200.0, 256.0),
            draw_chance(&most, 80.0, 256.0, 20),
            every_one_of(20, 254.0, 256.0),
        ];
        let expected = switch * switch * at_least(&columns, 4);
        let two = [seed.clone(), seed.clone()];
        close(m3.pass_chance(&two, 64), expected, 1e-12);
        // One seed's quad yaw-rate error over its bound halves it.
        let mut worse = seed.clone();
        if let Some(t) = worse.get_mut("tracking_quad") {
            t.insert("tracking/quad/ang_vel_error_radps".into(), 0.3);
        }
        close(m3.pass_chance(&[seed, worse], 64), expected / 2.0, 1e-12);
    }
}
