//! Generalised advantage estimation over a rollout, and the time-out bootstrap.
//!
//! Rollout arrays are step-major: element `t * num_envs + e` is env `e` at step `t`.

/// Advantages and returns of a `[T, N]` rollout (GAE), as the Python learner's `compute_gae`.
///
/// `dones[t * n + e]` means env `e`'s episode ended after step `t`: no value flows back across it.
/// A time-out is handled by the caller, who adds `gamma * V(final state)` to the reward (see
/// [`bootstrap_time_outs`]) and sets the done; a termination only sets the done.
///
/// Returns `(advantages, returns)`, both `[T, N]`, with `returns = advantages + values`.
pub fn compute_gae(
    rewards: &[f32],
    values: &[f32],
    dones: &[bool],
    last_values: &[f32],
    gamma: f32,
    lam: f32,
) -> (Vec<f32>, Vec<f32>) {
    let n = last_values.len();
    let steps = rewards.len().checked_div(n).unwrap_or(0);
    let mut advantages = vec![0.0f32; steps * n];
    let mut gae = vec![0.0f32; n];
    for t in (0..steps).rev() {
        for e in 0..n {
            let i = t * n + e;
            let next_value = if t + 1 == steps {
                last_values[e]
            } else {
                values[i + n]
            };
            let not_done = if dones[i] { 0.0 } else { 1.0 };
            let delta = rewards[i] + not_done * gamma * next_value - values[i];
            gae[e] = delta + not_done * gamma * lam * gae[e];
            advantages[i] = gae[e];
        }
    }
    let returns = advantages.iter().zip(values).map(|(a, v)| a + v).collect();
    (advantages, returns)
}

/// Add `gamma * V(final state)` to the reward of every env that timed out without terminating.
///
/// `final_env_ids[k]` ended in this step and `final_values[k]` is the critic's value of its final
/// (pre-reset) input. Envs that terminated keep their reward: the end was real.
pub fn bootstrap_time_outs(
    rewards: &mut [f32],
    terminated: &[bool],
    truncated: &[bool],
    final_env_ids: &[usize],
    final_values: &[f32],
    gamma: f32,
) {
    for (&e, &v) in final_env_ids.iter().zip(final_values) {
        if truncated[e] && !terminated[e] {
            rewards[e] += gamma * v;
        }
    }
}

/// `(x - mean) / (std + 1e-8)` in place, with torch's unbiased std (as `adv.std()`).
pub fn normalize(x: &mut [f32]) {
    let n = x.len();
    if n < 2 {
        return;
    }
    let mean = x.iter().map(|&v| f64::from(v)).sum::<f64>() / n as f64;
    let var = x
        .iter()
        .map(|&v| (f64::from(v) - mean).powi(2))
        .sum::<f64>()
        / (n - 1) as f64;
    let denom = var.sqrt() + 1e-8;
    for v in x {
        *v = ((f64::from(*v) - mean) / denom) as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &[f32], b: &[f32]) {
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() < 1e-5, "{a:?} != {b:?}");
        }
    }

    /// One env, 3 steps, a time-out after step 1 (V(final) = 2), gamma 0.9, lambda 0.5.
    ///
    /// Bootstrapped reward r1 = 0 + 0.9 * 2 = 1.8; values 1, 1, 1; last value 4.
    /// t2: delta = 1 + 0.9 * 4 - 1 = 3.6; A2 = 3.6.
    /// t1 (done): delta = 1.8 - 1 = 0.8; A1 = 0.8.
    /// t0: delta = 1 + 0.9 * 1 - 1 = 0.9; A0 = 0.9 + 0.9 * 0.5 * 0.8 = 1.26.
    #[test]
    fn gae_three_steps_with_a_time_out() {
        let mut r1 = [0.0f32];
        bootstrap_time_outs(&mut r1, &[false], &[true], &[0], &[2.0], 0.9);
        close(&r1, &[1.8]);
        let rewards = [1.0, r1[0], 1.0];
        let (adv, ret) = compute_gae(
            &rewards,
            &[1.0, 1.0, 1.0],
            &[false, true, false],
            &[4.0],
            0.9,
            0.5,
        );
        close(&adv, &[1.26, 0.8, 3.6]);
        close(&ret, &[2.26, 1.8, 4.6]);
    }

    /// Two envs interleaved step-major: env 1 never ends, so its advantages chain over all steps.
    /// gamma 1, lambda 1, values 0: A_t = sum of the rewards from t plus the last value.
    #[test]
    fn gae_two_envs_are_independent() {
        let rewards = [1.0, 1.0, 2.0, 2.0];
        let dones = [true, false, false, false];
        let (adv, _) = compute_gae(&rewards, &[0.0; 4], &dones, &[10.0, 10.0], 1.0, 1.0);
        // env 0: step 0 ends the episode (A = 1); step 1: 2 + 10 = 12.
        // env 1: step 1: 2 + 10 = 12; step 0: 1 + 12 = 13.
        close(&adv, &[1.0, 13.0, 12.0, 12.0]);
    }

    #[test]
    fn terminations_are_not_bootstrapped() {
        let mut r = [1.0f32, 1.0, 1.0];
        // env 0 terminated (and truncated in the same step), env 1 timed out, env 2 did not end.
        bootstrap_time_outs(
            &mut r,
            &[true, false, false],
            &[true, true, false],
            &[0, 1],
            &[5.0, 5.0],
            0.5,
        );
        close(&r, &[1.0, 3.5, 1.0]);
    }

    #[test]
    fn normalize_uses_the_unbiased_std() {
        let mut x = [1.0f32, 2.0, 3.0];
        normalize(&mut x);
        // mean 2, unbiased std 1.
        close(&x, &[-1.0, 0.0, 1.0]);
    }
}
