//! The periodic gait reward's expected phase indicators (Siekmann et al. 2021): phase boundaries
//! are von Mises random variables, so each foot's swing/stance indicator becomes a smooth
//! expectation. The von Mises CDF has no closed form; it is integrated once (Simpson) into a table
//! for the config's kappa and interpolated, which is exact to ~1e-6.

use std::f32::consts::{PI, TAU};

/// Expected force and speed cost coefficients of one foot: both in [0, 1], summing to 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaitCoefficients {
    /// Weight on the foot's contact force (high in swing).
    pub force: f32,
    /// Weight on the foot's speed (high in stance).
    pub speed: f32,
}

/// Tabulated CDF of a zero-centred von Mises distribution on [-pi, pi].
#[derive(Clone, Debug, PartialEq)]
pub struct VonMisesCdf {
    table: Vec<f32>,
}

const TABLE_SIZE: usize = 4097;

impl VonMisesCdf {
    /// Tabulate the CDF for concentration `kappa`.
    pub fn new(kappa: f32) -> Self {
        // Integrate exp(kappa (cos t - 1)) (the unnormalised density, kept <= 1 to avoid overflow)
        // with Simpson's rule on a fine grid, in f64.
        let k = kappa as f64;
        let n = (TABLE_SIZE - 1) * 8;
        let h = std::f64::consts::TAU / n as f64;
        let f = |t: f64| (k * (t.cos() - 1.0)).exp();
        let mut cumulative = vec![0.0f64; TABLE_SIZE];
        let mut acc = 0.0;
        for i in 0..(TABLE_SIZE - 1) {
            // Each table interval spans 8 fine steps: Simpson over 4 pairs.
            for p in 0..4 {
                let a = -std::f64::consts::PI + ((i * 8 + p * 2) as f64) * h;
                acc += h / 3.0 * (f(a) + 4.0 * f(a + h) + f(a + 2.0 * h));
            }
            cumulative[i + 1] = acc;
        }
        let table = cumulative.iter().map(|c| (c / acc) as f32).collect();
        Self { table }
    }

    /// P(X <= d) for d in [-pi, pi]; 0 below, 1 above (no wrapping: SciPy's convention, clipped).
    pub fn cdf(&self, d: f32) -> f32 {
        if d <= -PI {
            return 0.0;
        }
        if d >= PI {
            return 1.0;
        }
        let x = (d + PI) / TAU * (TABLE_SIZE - 1) as f32;
        let i = (x as usize).min(TABLE_SIZE - 2);
        let t = x - i as f32;
        self.table[i] * (1.0 - t) + self.table[i + 1] * t
    }
}

/// Expected swing and stance indicators of a foot at local phase `phase` in [0, 1) for swing
/// ratio `swing_ratio`: swing is [0, r), stance [r, 1).
pub fn expected_indicators(cdf: &VonMisesCdf, phase: f32, swing_ratio: f32) -> (f32, f32) {
    let phi = TAU * phase.rem_euclid(1.0);
    let b_swing = TAU * swing_ratio;
    let swing = cdf.cdf(phi) * (1.0 - cdf.cdf(phi - b_swing));
    let stance = cdf.cdf(phi - b_swing) * (1.0 - cdf.cdf(phi - TAU));
    (swing, stance)
}

/// Force and speed cost weights of a foot at local phase `phase`, with the complement fix
/// (weights sum to 1 and stay continuous across the cycle wrap): in the nominal swing window the
/// force weight is E[I_swing], in the stance window the speed weight is E[I_stance].
pub fn gait_coefficients(cdf: &VonMisesCdf, phase: f32, swing_ratio: f32) -> GaitCoefficients {
    if swing_ratio <= 0.0 {
        return GaitCoefficients {
            force: 0.0,
            speed: 1.0,
        };
    }
    let (swing, stance) = expected_indicators(cdf, phase, swing_ratio);
    if phase.rem_euclid(1.0) < swing_ratio {
        GaitCoefficients {
            force: swing,
            speed: 1.0 - swing,
        }
    } else {
        GaitCoefficients {
            force: 1.0 - stance,
            speed: stance,
        }
    }
}

#[cfg(test)]
mod test {
    use super::*;

    /// Reference values of periodic_reward.md (kappa 20, r 0.4): phase, E[I_sw], E[I_st],
    /// |E[C_frc]|, |E[C_spd]|.
    const REFERENCE: [(f32, f32, f32, f32, f32); 15] = [
        (0.000, 0.5000, 0.0000, 0.5000, 0.5000),
        (0.025, 0.7572, 0.0000, 0.7572, 0.2428),
        (0.050, 0.9178, 0.0000, 0.9178, 0.0822),
        (0.100, 0.9970, 0.0000, 0.9970, 0.0030),
        (0.200, 1.0000, 0.0000, 1.0000, 0.0000),
        (0.350, 0.9178, 0.0822, 0.9178, 0.0822),
        (0.375, 0.7572, 0.2428, 0.7572, 0.2428),
        (0.400, 0.5000, 0.5000, 0.5000, 0.5000),
        (0.425, 0.2428, 0.7572, 0.2428, 0.7572),
        (0.450, 0.0822, 0.9178, 0.0822, 0.9178),
        (0.500, 0.0030, 0.9970, 0.0030, 0.9970),
        (0.700, 0.0000, 1.0000, 0.0000, 1.0000),
        (0.900, 0.0000, 0.9970, 0.0030, 0.9970),
        (0.950, 0.0000, 0.9178, 0.0822, 0.9178),
        (0.975, 0.0000, 0.7572, 0.2428, 0.7572),
    ];

    #[test]
    fn expected_indicators_match_the_reference_table() {
        let cdf = VonMisesCdf::new(20.0);
        for (phase, sw, st, frc, spd) in REFERENCE {
            let (s, t) = expected_indicators(&cdf, phase, 0.4);
            assert!((s - sw).abs() < 1e-4, "phase {phase}: E[I_sw] {s} vs {sw}");
            assert!((t - st).abs() < 1e-4, "phase {phase}: E[I_st] {t} vs {st}");
            let c = gait_coefficients(&cdf, phase, 0.4);
            assert!(
                (c.force - frc).abs() < 1e-4,
                "phase {phase}: force {} vs {frc}",
                c.force
            );
            assert!(
                (c.speed - spd).abs() < 1e-4,
                "phase {phase}: speed {} vs {spd}",
                c.speed
            );
        }
    }

    #[test]
    fn cdf_is_a_cdf() {
        let cdf = VonMisesCdf::new(20.0);
        assert_eq!(cdf.cdf(-4.0), 0.0);
        assert_eq!(cdf.cdf(4.0), 1.0);
        assert!((cdf.cdf(0.0) - 0.5).abs() < 1e-6);
        // For large kappa the von Mises is close to a normal with variance 1/kappa.
        assert!((cdf.cdf(1.0 / 20f32.sqrt()) - 0.8413).abs() < 0.01);
    }
}
