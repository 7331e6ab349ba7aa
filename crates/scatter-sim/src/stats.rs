//! Goodness-of-fit statistics shared by the tests and by `stcvae eval`.

use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Two-sample Kolmogorov–Smirnov statistic sup |F_a − F_b| (sorts its inputs).
pub fn ks_two_sample(a: &mut [f64], b: &mut [f64]) -> f64 {
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
pub fn ks_one_sample(samples: &mut [f64], cdf: impl Fn(f64) -> f64) -> f64 {
    samples.sort_by(f64::total_cmp);
    let n = samples.len() as f64;
    samples
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            let f = cdf(x);
            (f - i as f64 / n).max((i + 1) as f64 / n - f)
        })
        .fold(0.0, f64::max)
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
/// (sorts its inputs).
pub fn wasserstein1(a: &mut [f64], b: &mut [f64]) -> f64 {
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
