//! The held-out test's p value: one number per test unit (a validation placement, a block of
//! poses of a held-out session), ln(MSE_before / MSE_after), positive where the change helps.
//! Under "no effect" the units are independent and symmetric about zero, so an exact sign-flip
//! (randomisation) test of their sum is valid whatever their distribution; it cannot go below
//! 2⁻ᵁ with U units, so a one-sided t test on the same numbers, which uses their sizes, is
//! combined with it by a weighted Bonferroni: p = min(p_flip/0.64, p_t/0.36).

use crate::numerics::stats::one_sided_t;

/// Share of the held-out level given to the sign-flip test (the rest to the t test): a weighted
/// Bonferroni over the pair. 0.64 lets five units all improved (p = 2⁻⁵) pass at 0.05.
pub const SIGN_FLIP_WEIGHT: f64 = 0.64;
/// Units up to which the sign-flip test enumerates every sign pattern; beyond, a seeded random
/// sample of [`SIGN_FLIP_DRAWS`] patterns.
pub const SIGN_FLIP_EXACT: usize = 20;
/// Random sign patterns beyond [`SIGN_FLIP_EXACT`] units.
pub const SIGN_FLIP_DRAWS: usize = 200_000;

/// Held-out p of the units' values: a weighted Bonferroni over the exact sign-flip p and a
/// one-sided t test on the same numbers, at most 1.
pub fn held_out_p(units: &[f64]) -> f64 {
    (sign_flip_p(units) / SIGN_FLIP_WEIGHT).min(one_sided_t(units).1 / (1.0 - SIGN_FLIP_WEIGHT)).min(1.0)
}

/// Exact one-sided sign-flip (randomisation) p of Σ units > 0: the share of sign patterns
/// whose sum is at least the observed one. Symmetric about zero under "no effect".
pub fn sign_flip_p(units: &[f64]) -> f64 {
    if units.is_empty() {
        return 1.0;
    }
    let observed: f64 = units.iter().sum();
    let tolerance = 1e-12 * units.iter().map(|u| u.abs()).sum::<f64>();
    let at_least = |signs: u64| {
        let sum: f64 =
            units.iter().enumerate().map(|(k, u)| if signs >> k & 1 == 1 { -u.abs() } else { u.abs() }).sum();
        sum >= observed - tolerance
    };
    if units.len() <= SIGN_FLIP_EXACT {
        let patterns = 1u64 << units.len();
        (0..patterns).filter(|&s| at_least(s)).count() as f64 / patterns as f64
    } else {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        let hits = (0..SIGN_FLIP_DRAWS).filter(|_| at_least(rng.random::<u64>())).count();
        (1 + hits) as f64 / (1 + SIGN_FLIP_DRAWS) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_out_test_carries_a_large_gain_with_one_unit_slightly_worse() {
        // Sign-flip alone: 2/32. The t test on the sizes carries it; noise passes neither; five
        // units all improved pass through the sign-flip part.
        let units = [0.9, 1.1, 0.8, -0.05, 1.0];
        assert!((sign_flip_p(&units) - 2.0 / 32.0).abs() < 1e-15);
        assert!(held_out_p(&units) < 0.05, "{}", held_out_p(&units));
        assert!(held_out_p(&[0.01, -0.02, 0.015, -0.01, 0.005]) > 0.3);
        assert!(held_out_p(&[0.1, 2.0, 0.05, 1.5, 0.3]) <= 0.05);
    }

    #[test]
    fn sign_flip_test_is_exact() {
        // Five units all improved: one pattern of 32 is as extreme.
        assert!((sign_flip_p(&[0.3, 0.2, 0.5, 0.1, 0.4]) - 1.0 / 32.0).abs() < 1e-15);
        // The smallest one negative: that pattern and the all-positive one.
        assert!((sign_flip_p(&[0.3, 0.2, 0.5, -0.1, 0.4]) - 2.0 / 32.0).abs() < 1e-15);
        // Noise: small changes either way.
        assert!(sign_flip_p(&[0.01, -0.02, 0.015, -0.01, 0.005]) > 0.3);
        assert!((sign_flip_p(&[0.1, 0.1, 0.1]) - 0.125).abs() < 1e-15);
    }
}
