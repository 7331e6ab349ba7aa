//! Goodness-of-fit statistics shared by the tests and by `stcvae eval`.

use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Whether the statistic of these samples is undefined: a NaN sample (which no merge loop
/// can step past: `x <= NaN` is false) or an empty one. The statistic is then NaN, which
/// fails every `d < bound` check.
fn undefined(a: &[f64], b: &[f64]) -> bool {
    a.is_empty() || b.is_empty() || a.iter().chain(b).any(|x| x.is_nan())
}

/// Two-sample Kolmogorov–Smirnov statistic sup |F_a − F_b| (sorts its inputs); NaN if
/// either sample is empty or holds a NaN.
pub fn ks_two_sample(a: &mut [f64], b: &mut [f64]) -> f64 {
    if undefined(a, b) {
        return f64::NAN;
    }
    a.sort_by(f64::total_cmp);
    b.sort_by(f64::total_cmp);
    let (n, m) = (a.len() as f64, b.len() as f64);
    let (mut i, mut j, mut d) = (0usize, 0usize, 0.0f64);
    while i < a.len() && j < b.len() {
        let x = a[i].min(b[j]);
        while i < a.len() && a[i] <= x {
            i += 1;
        }
        while j < b.len() && b[j] <= x {
            j += 1;
        }
        d = d.max((i as f64 / n - j as f64 / m).abs());
    }
    d
}

/// One-sample KS statistic of `samples` against a continuous `cdf` (sorts its input).
/// No samples, a NaN sample or a NaN CDF value make the statistic NaN, which fails every `d < bound`
/// check: `f64::max` would silently drop it.
pub fn ks_one_sample(samples: &mut [f64], cdf: impl Fn(f64) -> f64) -> f64 {
    // No samples, no statistic: 0 would pass every `d < bound` check (the two-sample
    // forms give NaN too).
    if samples.is_empty() {
        return f64::NAN;
    }
    samples.sort_by(f64::total_cmp);
    let n = samples.len() as f64;
    samples
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            let f = cdf(x);
            if f.is_nan() {
                return f64::NAN;
            }
            (f - i as f64 / n).max((i + 1) as f64 / n - f)
        })
        .fold(0.0, |d, v| {
            if d.is_nan() || v.is_nan() {
                f64::NAN
            } else {
                d.max(v)
            }
        })
}

/// Asymptotic p-value of a KS statistic `d` with effective sample size `n_eff`
/// (n for one sample, nm/(n+m) for two): Kolmogorov's series with Stephens' correction.
pub fn ks_p_value(d: f64, n_eff: f64) -> f64 {
    let s = n_eff.sqrt();
    let lambda = (s + 0.12 + 0.11 / s) * d;
    if lambda < 0.2 {
        return 1.0;
    }
    let mut sum = 0.0;
    for k in 1..=100 {
        let k = k as f64;
        let term = 2.0 * (-1f64).powi(k as i32 - 1) * (-2.0 * k * k * lambda * lambda).exp();
        sum += term;
        if term.abs() < 1e-12 {
            break;
        }
    }
    sum.clamp(0.0, 1.0)
}

/// Wasserstein-1 distance between two empirical distributions: ∫ |F_a − F_b| dx
/// (sorts its inputs); NaN if either sample is empty or holds a NaN.
pub fn wasserstein1(a: &mut [f64], b: &mut [f64]) -> f64 {
    if undefined(a, b) {
        return f64::NAN;
    }
    a.sort_by(f64::total_cmp);
    b.sort_by(f64::total_cmp);
    let (n, m) = (a.len() as f64, b.len() as f64);
    let (mut i, mut j) = (0usize, 0usize);
    let mut x_prev = a[0].min(b[0]);
    let mut w = 0.0;
    while i < a.len() || j < b.len() {
        let x = match (a.get(i), b.get(j)) {
            (Some(&p), Some(&q)) => p.min(q),
            (Some(&p), None) => p,
            (None, Some(&q)) => q,
            (None, None) => break,
        };
        w += (i as f64 / n - j as f64 / m).abs() * (x - x_prev);
        x_prev = x;
        while i < a.len() && a[i] <= x {
            i += 1;
        }
        while j < b.len() && b[j] <= x {
            j += 1;
        }
    }
    w
}

/// Pearson's chi-square statistic of observed counts against expected counts.
pub fn chi_square(observed: &[u64], expected: &[f64]) -> f64 {
    observed
        .iter()
        .zip(expected)
        .map(|(&o, &e)| (o as f64 - e).powi(2) / e)
        .sum()
}

/// Upper-tail probability of the chi-square distribution with `dof` degrees of freedom.
pub fn chi_square_p_value(stat: f64, dof: usize) -> f64 {
    ChiSquared::new(dof as f64).expect("dof > 0").sf(stat)
}

/// z-score of `hits` successes in `n` Bernoulli(p) trials.
pub fn proportion_z(hits: u64, n: u64, p: f64) -> f64 {
    let n = n as f64;
    (hits as f64 - n * p) / (n * p * (1.0 - p)).sqrt()
}

/// Mean and standard error of the mean.
pub fn mean_and_sem(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand-worked: a = {1, 2, 3}, b = {2.5, 4}. At x = 2 F_a = 2/3 and F_b = 0; the
    /// other points differ less (1/3, 1/6, 1/2, 0).
    #[test]
    fn two_sample_ks_of_a_worked_case() {
        let d = ks_two_sample(&mut [3.0, 1.0, 2.0], &mut [4.0, 2.5]);
        assert!((d - 2.0 / 3.0).abs() < 1e-15, "{d}");
        // Identical samples: 0; disjoint samples: 1.
        assert_eq!(ks_two_sample(&mut [1.0, 2.0], &mut [2.0, 1.0]), 0.0);
        assert_eq!(ks_two_sample(&mut [1.0, 2.0], &mut [3.0, 4.0, 5.0]), 1.0);
    }

    /// Hand-worked against U(0, 1): samples {0.1, 0.2, 0.9}; the empirical CDF steps to
    /// 2/3 at 0.2 where F = 0.2, so D = 2/3 − 0.2. A NaN sample gives NaN, not a pass.
    #[test]
    fn one_sample_ks_of_a_worked_case_and_nan() {
        let d = ks_one_sample(&mut [0.9, 0.1, 0.2], |x| x.clamp(0.0, 1.0));
        assert!((d - (2.0 / 3.0 - 0.2)).abs() < 1e-15, "{d}");
        let d = ks_one_sample(&mut [0.5, f64::NAN, 0.25], |x| x.clamp(0.0, 1.0));
        assert!(d.is_nan(), "{d}");
        assert!(ks_one_sample(&mut [0.5], |_| f64::NAN).is_nan());
        // An empty sample has no statistic (0 passed every bound).
        assert!(ks_one_sample(&mut [], |x| x).is_nan());
    }

    /// Kolmogorov's distribution: P(√n·D > 1.358) = 0.05 and P(√n·D > 1.628) = 0.01
    /// (the classical critical values), and p(λ) falls with λ. For large n Stephens'
    /// correction vanishes, so n = 10⁸ reads the asymptotic values to ~1e-4.
    #[test]
    fn ks_p_values_match_the_critical_values() {
        let n = 1e8f64;
        let p05 = ks_p_value(1.358 / n.sqrt(), n);
        let p01 = ks_p_value(1.628 / n.sqrt(), n);
        assert!((p05 - 0.05).abs() < 5e-4, "{p05}");
        assert!((p01 - 0.01).abs() < 2e-4, "{p01}");
        assert_eq!(ks_p_value(0.0, 100.0), 1.0);
        assert!(ks_p_value(0.2, 100.0) > ks_p_value(0.3, 100.0));
    }

    /// W1 of point masses is the distance between them; of {0, 1} against {0, 3} it is
    /// ∫|F_a − F_b| = 1/2 · 2 = 1.
    #[test]
    fn wasserstein_of_worked_cases() {
        assert!((wasserstein1(&mut [2.0], &mut [5.5]) - 3.5).abs() < 1e-15);
        assert!((wasserstein1(&mut [0.0, 1.0], &mut [3.0, 0.0]) - 1.0).abs() < 1e-15);
    }

    /// A NaN (a model that outputs NaN, in `stcvae eval`) or an empty sample makes both
    /// two-sample statistics NaN; the merge loops used to spin forever on a NaN.
    #[test]
    fn two_sample_statistics_of_nan_and_empty_samples_are_nan() {
        let nan = || vec![0.1, f64::NAN, 0.3];
        let ok = || vec![0.2, 0.4];
        assert!(ks_two_sample(&mut nan(), &mut ok()).is_nan());
        assert!(ks_two_sample(&mut nan(), &mut nan()).is_nan());
        assert!(wasserstein1(&mut ok(), &mut nan()).is_nan());
        assert!(wasserstein1(&mut nan(), &mut nan()).is_nan());
        assert!(wasserstein1(&mut [], &mut ok()).is_nan());
        assert!(ks_two_sample(&mut ok(), &mut []).is_nan());
    }

    /// χ² of counts, its tail (χ²₁ > 3.841 has probability 0.05), a proportion's z and
    /// a mean's standard error, each against a value worked by hand.
    #[test]
    fn chi_square_z_and_sem_of_worked_cases() {
        // (12 − 10)²/10 + (8 − 10)²/10 = 0.8.
        assert!((chi_square(&[12, 8], &[10.0, 10.0]) - 0.8).abs() < 1e-12);
        assert!((chi_square_p_value(3.841, 1) - 0.05).abs() < 1e-4);
        // 60 of 100 at p = 1/2: (60 − 50)/√25 = 2.
        assert!((proportion_z(60, 100, 0.5) - 2.0).abs() < 1e-12);
        // {1, 2, 3, 4}: mean 2.5, sample variance 5/3, SEM √(5/12).
        let (m, se) = mean_and_sem(&[1.0, 2.0, 3.0, 4.0]);
        assert!((m - 2.5).abs() < 1e-15 && (se - (5.0f64 / 12.0).sqrt()).abs() < 1e-15);
    }
}
