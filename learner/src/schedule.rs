//! The adaptive learning rate and the KL it follows.

/// rsl_rl's adaptive rule: shrink by 1.5 when KL > 2 kl*, grow by 1.5 when 0 < KL < kl*/2,
/// kept within `[min_lr, max_lr]` (1e-5 and 1e-2 in the Python learner).
pub fn adaptive_learning_rate(lr: f64, kl: f64, desired_kl: f64, min_lr: f64, max_lr: f64) -> f64 {
    if kl > 2.0 * desired_kl {
        (lr / 1.5).max(min_lr)
    } else if kl > 0.0 && kl < desired_kl / 2.0 {
        (lr * 1.5).min(max_lr)
    } else {
        lr
    }
}

/// KL(old || new) of one diagonal Gaussian pair, summed over the action dims, as rsl_rl computes
/// it: `sum_i ln(s_new / s_old + 1e-5) + (s_old^2 + (mu_old - mu_new)^2) / (2 s_new^2) - 0.5`.
pub fn gaussian_kl(mu_old: &[f32], sigma_old: &[f32], mu_new: &[f32], sigma_new: &[f32]) -> f64 {
    let mut kl = 0.0f64;
    for i in 0..mu_old.len() {
        let (mo, so) = (f64::from(mu_old[i]), f64::from(sigma_old[i]));
        let (mn, sn) = (f64::from(mu_new[i]), f64::from(sigma_new[i]));
        kl += (sn / so + 1e-5).ln() + (so * so + (mo - mn).powi(2)) / (2.0 * sn * sn) - 0.5;
    }
    kl
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn learning_rate_follows_the_kl() {
        let lr = 1e-3;
        assert!((adaptive_learning_rate(lr, 0.03, 0.01, 1e-5, 1e-2) - 1e-3 / 1.5).abs() < 1e-15);
        assert!((adaptive_learning_rate(lr, 0.004, 0.01, 1e-5, 1e-2) - 1.5e-3).abs() < 1e-15);
        // Inside [kl*/2, 2 kl*], and a KL of exactly 0: unchanged.
        assert_eq!(adaptive_learning_rate(lr, 0.01, 0.01, 1e-5, 1e-2), lr);
        assert_eq!(adaptive_learning_rate(lr, 0.0, 0.01, 1e-5, 1e-2), lr);
        // Clamped at both ends.
        assert_eq!(adaptive_learning_rate(1.2e-5, 1.0, 0.01, 1e-5, 1e-2), 1e-5);
        assert_eq!(adaptive_learning_rate(9e-3, 1e-4, 0.01, 1e-5, 1e-2), 1e-2);
    }

    /// Two dims: (mu 0 -> 1, sigma 1 -> 1) and (mu 0 -> 0, sigma 1 -> 2).
    /// dim 0: ln(1 + 1e-5) + (1 + 1) / 2 - 0.5 = 0.5 + 1e-5 (to first order).
    /// dim 1: ln(2 + 1e-5) + 1 / 8 - 0.5 = 0.693147 + 5e-6 - 0.375 = 0.318152.
    #[test]
    fn kl_of_two_diagonal_gaussians() {
        let kl = gaussian_kl(&[0.0, 0.0], &[1.0, 1.0], &[1.0, 0.0], &[1.0, 2.0]);
        let expected = (1.0f64 + 1e-5).ln() + 0.5 + (2.0f64 + 1e-5).ln() - 0.375;
        assert!((kl - expected).abs() < 1e-9, "{kl} vs {expected}");
        assert!((kl - 0.818162).abs() < 1e-5);
        // Identical distributions: only the 1e-5 guard remains.
        let same = gaussian_kl(&[0.3], &[0.7], &[0.3], &[0.7]);
        assert!((same - (1.0f64 + 1e-5).ln()).abs() < 1e-12);
    }
}
