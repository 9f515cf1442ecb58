//! Small statistics: Student's t, F and normal tail probabilities (t and F through the
//! regularized incomplete beta function), a one-sample t test, RMS, median, the χ² quantile, and
//! the χ² upper tail as a standard normal deviate, exact far into the tail (log space).

/// ln Γ(x) for x > 0 (Lanczos, g = 7, 9 terms; relative error below 1e-13).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let sum = C.iter().enumerate().skip(1).fold(C[0], |s, (k, c)| s + c / (x + k as f64));
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + sum.ln()
}

/// Continued fraction of the incomplete beta function (modified Lentz).
fn beta_fraction(a: f64, b: f64, x: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    if d.abs() < TINY {
        d = TINY;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..300 {
        let m = m as f64;
        let m2 = 2.0 * m;
        for aa in
            [m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))]
        {
            d = 1.0 + aa * d;
            if d.abs() < TINY {
                d = TINY;
            }
            c = 1.0 + aa / c;
            if c.abs() < TINY {
                c = TINY;
            }
            d = 1.0 / d;
            h *= d * c;
        }
        if (d * c - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

/// Regularized incomplete beta function I_x(a, b).
pub fn incomplete_beta(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let front = (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln()).exp();
    if x < (a + 1.0) / (a + b + 2.0) {
        front * beta_fraction(a, b, x) / a
    } else {
        1.0 - front * beta_fraction(b, a, 1.0 - x) / b
    }
}

/// P(T ≥ t) for Student's t with `dof` degrees of freedom.
pub fn t_upper_tail(t: f64, dof: f64) -> f64 {
    let tail = 0.5 * incomplete_beta(dof / 2.0, 0.5, dof / (dof + t * t));
    if t >= 0.0 {
        tail
    } else {
        1.0 - tail
    }
}

/// One-sided one-sample t test of mean > 0: (t statistic, p-value). With fewer than two
/// values, or none varying, the p-value is 1 unless every value is positive and equal.
pub fn one_sided_t(values: &[f64]) -> (f64, f64) {
    let n = values.len();
    if n < 2 {
        return (0.0, 1.0);
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    if var <= 0.0 {
        return if mean > 0.0 { (f64::INFINITY, 0.0) } else { (0.0, 1.0) };
    }
    let t = mean / (var / n as f64).sqrt();
    (t, t_upper_tail(t, (n - 1) as f64))
}

/// Root mean square of `values` (0 for none).
pub fn rms(values: &[f64]) -> f64 {
    (values.iter().map(|v| v * v).sum::<f64>() / values.len().max(1) as f64).sqrt()
}

/// Median of `values`: the mean of the middle two for an even count, NaN for none.
pub fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// P(F ≥ f) for Fisher's F with `d1` and `d2` degrees of freedom.
pub fn f_upper_tail(f: f64, d1: f64, d2: f64) -> f64 {
    if f <= 0.0 {
        return 1.0;
    }
    incomplete_beta(d2 / 2.0, d1 / 2.0, d2 / (d2 + d1 * f))
}

/// P(Z ≥ z) for a standard normal Z.
pub fn normal_upper_tail(z: f64) -> f64 {
    if z >= 0.0 {
        ln_upper_tail_of_positive(z).exp()
    } else {
        1.0 - ln_upper_tail_of_positive(-z).exp()
    }
}

/// ln P(Z ≥ z) for z ≥ 0: erfc by the Chebyshev fit of Numerical Recipes (erfcc), kept in log
/// space so it does not underflow far in the tail; relative error below 1.2e-7.
fn ln_upper_tail_of_positive(z: f64) -> f64 {
    let x = z / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * x);
    let poly = -1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    0.5f64.ln() + t.ln() - x * x + poly
}

/// Wilson–Hilferty approximation of the χ² quantile with `nu` degrees of freedom at standard
/// normal deviate `z`.
pub fn chi2_quantile(nu: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * nu);
    nu * (1.0 - a + z * a.sqrt()).powi(3)
}

/// ln Q(a, x), the regularized upper incomplete gamma function, without underflow far in the
/// tail: the series for P below x = a + 1, the continued fraction (modified Lentz) above.
fn ln_gamma_upper(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let front = -x + a * x.ln() - ln_gamma(a);
    if x < a + 1.0 {
        let (mut term, mut sum, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..1000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        return (-(front + sum.ln()).exp()).ln_1p();
    }
    const TINY: f64 = 1e-300;
    let mut b = x + 1.0 - a;
    let mut c = 1.0 / TINY;
    let mut d = 1.0 / b;
    let mut h = d;
    for i in 1..1000 {
        let an = -(i as f64) * (i as f64 - a);
        b += 2.0;
        d = an * d + b;
        if d.abs() < TINY {
            d = TINY;
        }
        c = b + an / c;
        if c.abs() < TINY {
            c = TINY;
        }
        d = 1.0 / d;
        let step = d * c;
        h *= step;
        if (step - 1.0).abs() < 1e-16 {
            break;
        }
    }
    front + h.ln()
}

/// ln P(Z ≥ z) for a standard normal Z, without underflow for large z.
fn ln_normal_upper_tail(z: f64) -> f64 {
    if z >= 0.0 {
        ln_upper_tail_of_positive(z)
    } else {
        (-normal_upper_tail(-z)).ln_1p()
    }
}

/// The standard normal deviate with the same upper tail as χ²_k at `x`: z with
/// P(Z ≥ z) = P(χ²_k ≥ x), exact (to the erfc fit's 1.2e-7 relative error) far into the tail,
/// where the Wilson–Hilferty cube root favours larger k (at z ≈ 15 it puts a 2-parameter drop
/// above a larger 1-parameter one). Between −40 and 80.
pub fn chi2_normal_deviate(x: f64, k: usize) -> f64 {
    let target = ln_gamma_upper(0.5 * k.max(1) as f64, 0.5 * x.max(0.0));
    let (mut lo, mut hi) = (-40.0, 80.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if ln_normal_upper_tail(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 {
            break;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f_and_normal_tails_match_tables() {
        // F(6, 30) upper 1 %: 3.47; F(6, 33) upper 5 %: 2.39.
        assert!((f_upper_tail(3.473, 6.0, 30.0) - 0.01).abs() < 2e-4, "{}", f_upper_tail(3.473, 6.0, 30.0));
        assert!((f_upper_tail(2.389, 6.0, 33.0) - 0.05).abs() < 1e-3);
        assert!((normal_upper_tail(1.644_854) - 0.05).abs() < 1e-7);
        assert!((normal_upper_tail(4.5) - 3.398e-6).abs() < 1e-8);
        assert!((normal_upper_tail(-1.959_964) - 0.975).abs() < 1e-7);
    }

    #[test]
    fn t_tail_matches_tables() {
        // Two-sided 5 % critical values: t(8) = 2.306, t(14) = 2.145; 0.1 %: t(8) = 5.041.
        assert!((t_upper_tail(2.306_004, 8.0) - 0.025).abs() < 1e-6);
        assert!((t_upper_tail(2.144_787, 14.0) - 0.025).abs() < 1e-6);
        assert!((t_upper_tail(5.041_305, 8.0) - 0.0005).abs() < 1e-7);
        assert!((t_upper_tail(0.0, 5.0) - 0.5).abs() < 1e-12);
        assert!((t_upper_tail(-2.306_004, 8.0) - 0.975).abs() < 1e-6);
        // One degree of freedom is the Cauchy distribution: P(T ≥ 1) = 1/4.
        assert!((t_upper_tail(1.0, 1.0) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn t_test_of_a_clear_shift_and_of_noise() {
        let (t, p) = one_sided_t(&[1.0, 1.2, 0.8, 1.1, 0.9]);
        assert!(t > 10.0 && p < 1e-4, "{t} {p}");
        let (_, p) = one_sided_t(&[0.1, -0.2, 0.05, -0.1, 0.15, -0.05]);
        assert!(p > 0.3, "{p}");
    }

    #[test]
    fn chi2_deviate_is_exact_in_the_far_tail() {
        // χ²₁ = Z²: P(χ²₁ ≥ z²) = 2 P(Z ≥ z), so z' solves P(Z ≥ z') = 2 P(Z ≥ z).
        assert!((chi2_normal_deviate(1.959_964f64.powi(2), 1) - 1.644_854).abs() < 1e-5);
        // At z = 15: ln 2 P(Z ≥ 15) → z' ≈ 14.954 (Wilson–Hilferty says 11.3).
        let far = chi2_normal_deviate(225.0, 1);
        assert!((far - 14.954).abs() < 0.01, "{far}");
        // χ²₂ is exponential: P(χ²₂ ≥ x) = e^(−x/2); e^(−3) = 0.0498 → z = 1.647.
        assert!((chi2_normal_deviate(6.0, 2) - 1.6476).abs() < 1e-3, "{}", chi2_normal_deviate(6.0, 2));
        // The same large drop is stronger evidence with fewer parameters.
        assert!(chi2_normal_deviate(350.0, 1) > chi2_normal_deviate(350.0, 2));
        assert!(chi2_normal_deviate(0.0, 3) < -30.0);
        // Below the mean: the series branch, χ²₆ median 5.348.
        assert!(chi2_normal_deviate(5.348, 6).abs() < 1e-3, "{}", chi2_normal_deviate(5.348, 6));
    }

    #[test]
    fn rms_median_and_chi2_of_known_values() {
        assert!((super::rms(&[3.0, 4.0]) - 12.5f64.sqrt()).abs() < 1e-12);
        assert_eq!(super::median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(super::median(vec![4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(super::median(Vec::new()).is_nan());
        // χ²₆ at 0.999 is 22.458, χ²₃ at 0.999 is 16.266 (z = 3.0902).
        assert!((super::chi2_quantile(6.0, 3.0902) - 22.458).abs() < 0.3);
        assert!((super::chi2_quantile(3.0, 3.0902) - 16.266).abs() < 0.4);
    }
}
