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

/// Two-dimensional two-sample KS statistic (Peacock's idea, evaluated at the data points
/// as Fasano and Franceschini do): the largest difference between the two samples'
/// shares in any of the four quadrants {x ≤ x₀ or > x₀} × {y ≤ y₀ or > y₀} about any
/// point (x₀, y₀) of either sample. The larger of the two samples' maxima, where
/// Fasano–Franceschini (and Numerical Recipes' ks2d2s) average them: never below theirs,
/// so their critical values do not apply (the docs compare it with its own null level,
/// simulator against simulator). Unlike the marginals' statistics it sees a wrong
/// dependence between the coordinates (a model whose exit direction is right on average
/// but paired with the wrong exit points). Unchanged by increasing maps of either axis (it
/// depends on ranks only; a decreasing map swaps closed and open quadrant sides), and NaN
/// for an empty sample or a NaN. (It need not reach a coordinate's 1-D statistic: the
/// origins are data points, so the half-plane at the 1-D maximum may not be a quadrant.)
///
/// All quadrant counts come from one sweep in x with a Fenwick tree over y's ranks per
/// sample: O((n + m) log(n + m)), where the direct count is O((n + m)²) (4·10⁸ for the
/// 10⁴ + 10⁴ samples of `stcvae eval`).
pub fn ks_two_sample_2d(a: &[(f64, f64)], b: &[(f64, f64)]) -> f64 {
    let undefined =
        a.is_empty() || b.is_empty() || a.iter().chain(b).any(|&(x, y)| x.is_nan() || y.is_nan());
    if undefined {
        return f64::NAN;
    }
    // Every point, tagged with its sample; y replaced by its rank among distinct values.
    let mut pts: Vec<(f64, f64, bool)> = a
        .iter()
        .map(|&(x, y)| (x, y, true))
        .chain(b.iter().map(|&(x, y)| (x, y, false)))
        .collect();
    let mut ys: Vec<f64> = pts.iter().map(|p| p.1).collect();
    ys.sort_by(f64::total_cmp);
    ys.dedup();
    let rank = |y: f64| ys.partition_point(|&v| v < y);
    // Totals below or at each y rank, per sample (for the half-planes {y ≤ y₀}).
    let (mut ya, mut yb) = (vec![0u64; ys.len()], vec![0u64; ys.len()]);
    for p in &pts {
        let r = rank(p.1);
        if p.2 { ya[r] += 1 } else { yb[r] += 1 }
    }
    for r in 1..ys.len() {
        ya[r] += ya[r - 1];
        yb[r] += yb[r - 1];
    }
    pts.sort_by(|p, q| p.0.total_cmp(&q.0));
    let (n, m) = (a.len() as f64, b.len() as f64);
    let (mut fa, mut fb) = (Fenwick::new(ys.len()), Fenwick::new(ys.len()));
    let (mut xa, mut xb) = (0u64, 0u64); // points with x ≤ x₀ so far
    let mut d = 0f64;
    let mut start = 0;
    while start < pts.len() {
        // Every point of this x value is counted before any of them is an origin.
        let x = pts[start].0;
        let mut end = start;
        while end < pts.len() && pts[end].0 == x {
            let r = rank(pts[end].1);
            if pts[end].2 {
                fa.add(r);
                xa += 1;
            } else {
                fb.add(r);
                xb += 1;
            }
            end += 1;
        }
        for p in &pts[start..end] {
            let r = rank(p.1);
            let quadrants = |ll: u64, x_le: u64, y_le: u64, total: u64| {
                let lu = x_le - ll;
                let rl = y_le - ll;
                [ll, lu, rl, total - ll - lu - rl]
            };
            let qa = quadrants(fa.prefix(r), xa, ya[r], a.len() as u64);
            let qb = quadrants(fb.prefix(r), xb, yb[r], b.len() as u64);
            for (ca, cb) in qa.into_iter().zip(qb) {
                d = d.max((ca as f64 / n - cb as f64 / m).abs());
            }
        }
        start = end;
    }
    d
}

/// Counts by rank with prefix sums in O(log n) (a binary indexed tree).
struct Fenwick(Vec<u64>);

impl Fenwick {
    fn new(n: usize) -> Self {
        Fenwick(vec![0; n + 1])
    }

    fn add(&mut self, rank: usize) {
        let mut i = rank + 1;
        while i < self.0.len() {
            self.0[i] += 1;
            i += i & i.wrapping_neg();
        }
    }

    /// How many added ranks are ≤ `rank`.
    fn prefix(&self, rank: usize) -> u64 {
        let (mut i, mut s) = (rank + 1, 0);
        while i > 0 {
            s += self.0[i];
            i -= i & i.wrapping_neg();
        }
        s
    }
}

/// Sliced Wasserstein-1 distance of two 2-D samples: the mean over `directions` evenly
/// spaced directions u (angles kπ/K) of the 1-D W1 of the projections u·p. A true metric
/// on distributions, like W1, but without 2-D optimal transport (O((n + m)² ·…) for the
/// exact one); it is in the units of the coordinates, so it mixes them as they are given.
/// NaN for an empty sample or a NaN.
pub fn sliced_wasserstein1(a: &[(f64, f64)], b: &[(f64, f64)], directions: usize) -> f64 {
    let project = |s: &[(f64, f64)], (c, sn): (f64, f64)| -> Vec<f64> {
        s.iter().map(|&(x, y)| c * x + sn * y).collect()
    };
    let k = directions.max(1);
    (0..k)
        .map(|i| {
            let t = std::f64::consts::PI * i as f64 / k as f64;
            let u = (t.cos(), t.sin());
            wasserstein1(&mut project(a, u), &mut project(b, u))
        })
        .sum::<f64>()
        / k as f64
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

/// Welch's statistic for the difference of two means, mean(b) − mean(a) over its standard
/// error √(s_a²/n_a + s_b²/n_b): N(0, 1) for samples of a few dozen or more from
/// distributions with the same mean (unequal variances allowed). NaN if either sample has
/// fewer than two values or holds a NaN; ±∞ or NaN when both are constant.
pub fn welch_z(a: &[f64], b: &[f64]) -> f64 {
    if undefined(a, b) || a.len() < 2 || b.len() < 2 {
        return f64::NAN;
    }
    let (ma, sa) = mean_and_sem(a);
    let (mb, sb) = mean_and_sem(b);
    (mb - ma) / (sa * sa + sb * sb).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand-worked: a = {1, 2, 3} (mean 2, variance 1), b = {4, 6} (mean 5, variance 2):
    /// z = 3/√(1/3 + 2/2). Swapped samples negate z; a NaN, or a sample of one, gives NaN.
    #[test]
    fn welch_of_a_worked_case() {
        let z = welch_z(&[1.0, 2.0, 3.0], &[6.0, 4.0]);
        assert!((z - 3.0 / (4.0f64 / 3.0).sqrt()).abs() < 1e-12, "{z}");
        assert_eq!(welch_z(&[6.0, 4.0], &[1.0, 2.0, 3.0]), -z);
        assert!(welch_z(&[1.0, f64::NAN], &[2.0, 3.0]).is_nan());
        assert!(welch_z(&[1.0], &[2.0, 3.0]).is_nan());
    }

    /// Under equal means z is N(0, 1), unequal spreads and sizes allowed: 400 pairs (200
    /// uniform draws on [0, 1] against 100 on [0.25, 0.75]) give a mean within 4 standard
    /// errors (4/√400 = 0.2) of 0 and a variance within 0.25 of 1 (the sample variance of
    /// 400 normals has a standard deviation of √(2/399) = 0.071: 3.5 of them).
    #[test]
    fn welch_is_standard_normal_under_the_null() {
        let mut rng = crate::WalkRng::from_seed(11);
        let zs: Vec<f64> = (0..400)
            .map(|_| {
                let a: Vec<f64> = (0..200).map(|_| rng.uniform()).collect();
                let b: Vec<f64> = (0..100).map(|_| 0.25 + 0.5 * rng.uniform()).collect();
                welch_z(&a, &b)
            })
            .collect();
        let (mean, _) = mean_and_sem(&zs);
        let var = zs.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / 399.0;
        assert!(mean.abs() < 0.2, "mean {mean}");
        assert!((var - 1.0).abs() < 0.25, "variance {var}");
    }

    /// Hand-worked: a = {1, 2, 3}, b = {2.5, 4}. At x = 2 F_a = 2/3 and F_b = 0; the
    /// other points differ less (1/3, 1/6, 1/2, 0).
    #[test]
    fn two_sample_ks_of_a_worked_case() {
        let d = ks_two_sample(&mut [3.0, 1.0, 2.0], &mut [4.0, 2.5]);
        assert!((d - 2.0 / 3.0).abs() < 1e-15, "{d}");
        // Identical samples: 0; disjoint samples: 1.
        assert_eq!(ks_two_sample(&mut [1.0, 2.0], &mut [2.0, 1.0]), 0.0);
        assert_eq!(ks_two_sample(&mut [1.0, 2.0], &mut [3.0, 4.0, 5.0]), 1.0);
        // The same with the samples swapped: D is two-sided, whichever sample runs ahead.
        let d = ks_two_sample(&mut [4.0, 2.5], &mut [3.0, 1.0, 2.0]);
        assert!((d - 2.0 / 3.0).abs() < 1e-15, "{d}");
        assert_eq!(ks_two_sample(&mut [3.0, 4.0, 5.0], &mut [1.0, 2.0]), 1.0);
    }

    /// Hand-worked against U(0, 1): samples {0.1, 0.2, 0.9}; the empirical CDF steps to
    /// 2/3 at 0.2 where F = 0.2, so D = 2/3 − 0.2. A NaN sample gives NaN, not a pass.
    #[test]
    fn one_sample_ks_of_a_worked_case_and_nan() {
        let d = ks_one_sample(&mut [0.9, 0.1, 0.2], |x| x.clamp(0.0, 1.0));
        assert!((d - (2.0 / 3.0 - 0.2)).abs() < 1e-15, "{d}");
        // A sample above F: {0.5, 0.6, 0.9}, whose empirical CDF is still 0 where F
        // reaches 0.5 just below the first point, so D = 0.5 (from below: D⁻); above, the
        // steps exceed F by at most 0.1 (D⁺).
        let d = ks_one_sample(&mut [0.6, 0.9, 0.5], |x| x.clamp(0.0, 1.0));
        assert!((d - 0.5).abs() < 1e-15, "{d}");
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
        // Small n, where Stephens' correction √n + 0.12 + 0.11/√n matters: the exact
        // two-sided 5 % critical values (Massey 1951, Table 1) are D = 0.294 at n = 20 and
        // 0.409 at n = 10; the correction is good to a few thousandths of p there (0.0502
        // and 0.0504 measured). Without it p reads 0.063 and 0.070.
        for (d, n, tol) in [(0.294, 20.0, 0.003), (0.409, 10.0, 0.004)] {
            let p = ks_p_value(d, n);
            assert!((p - 0.05).abs() < tol, "n = {n}, D = {d}: p = {p}");
        }
    }

    /// The 2-D statistic by its definition, counted directly: every point of either
    /// sample as origin, the four closed/open quadrants, the largest share difference.
    fn ks_2d_direct(a: &[(f64, f64)], b: &[(f64, f64)]) -> f64 {
        let share = |s: &[(f64, f64)], o: (f64, f64), q: usize| {
            let inside = |&(x, y): &(f64, f64)| {
                let (left, low) = (x <= o.0, y <= o.1);
                match q {
                    0 => left && low,
                    1 => left && !low,
                    2 => !left && low,
                    _ => !left && !low,
                }
            };
            s.iter().filter(|p| inside(p)).count() as f64 / s.len() as f64
        };
        a.iter()
            .chain(b)
            .flat_map(|&o| (0..4).map(move |q| (o, q)))
            .map(|(o, q)| (share(a, o, q) - share(b, o, q)).abs())
            .fold(0.0, f64::max)
    }

    /// The sweep equals the direct count on random samples with ties in both axes (values
    /// on a coarse grid), of unequal sizes; and it sees what the marginals cannot: y = x
    /// against y independent of x, both with uniform marginals, differ by 1/4 in the
    /// quadrant below (½, ½).
    #[test]
    fn two_dimensional_ks_by_sweep_equals_the_direct_count() {
        let mut rng = crate::WalkRng::from_seed(11);
        for (n, m, grid) in [(50, 70, 8.0), (200, 150, 1e6), (1, 3, 4.0)] {
            let mut draw = |k: usize| -> Vec<(f64, f64)> {
                (0..k)
                    .map(|_| {
                        let x = (rng.uniform() * grid).floor();
                        let y = (rng.uniform() * grid).floor() + 0.3 * x;
                        (x, y)
                    })
                    .collect()
            };
            let (a, b) = (draw(n), draw(m));
            let fast = ks_two_sample_2d(&a, &b);
            let direct = ks_2d_direct(&a, &b);
            assert!(
                (fast - direct).abs() < 1e-12,
                "{n}, {m}: {fast} vs {direct}"
            );
        }
        let k = 4000;
        let u: Vec<f64> = (0..k).map(|_| rng.uniform()).collect();
        let v: Vec<f64> = (0..k).map(|_| rng.uniform()).collect();
        let same: Vec<(f64, f64)> = u.iter().map(|&x| (x, x)).collect();
        let indep: Vec<(f64, f64)> = u.iter().zip(&v).map(|(&x, &y)| (x, y)).collect();
        // Marginals equal in law (x: the same draws; y: two uniform samples): 1-D KS of y
        // at the noise level, ~1/√(k/2) = 0.022; the 2-D statistic near its 1/4.
        let d = ks_two_sample_2d(&same, &indep);
        assert!(d > 0.22, "{d}");
        assert!(ks_two_sample_2d(&[], &same).is_nan());
        assert!(ks_two_sample_2d(&[(0.0, f64::NAN)], &same).is_nan());
    }

    /// Sliced W1 of point masses at distance r apart along x: the projections are r·|cos t|
    /// apart, whose mean over t ∈ [0, π) is 2r/π (to the K-point rule's error).
    #[test]
    fn sliced_wasserstein_of_two_points() {
        let w = sliced_wasserstein1(&[(0.0, 0.0)], &[(3.0, 0.0)], 720);
        assert!((w - 6.0 / std::f64::consts::PI).abs() < 1e-4, "{w}");
        // Apart along (3, 4): projections 5·|cos(t − t₀)| apart, mean 10/π (3.1831014 with
        // K = 720, off by 2.5e-6). y read as x would give 2.7009.
        let w = sliced_wasserstein1(&[(0.0, 0.0)], &[(3.0, 4.0)], 720);
        assert!((w - 10.0 / std::f64::consts::PI).abs() < 1e-4, "{w}");
        assert!(sliced_wasserstein1(&[], &[(3.0, 0.0)], 8).is_nan());
    }

    /// W1 of point masses is the distance between them; of {0, 1} against {0, 3} it is
    /// ∫|F_a − F_b| = 1/2 · 2 = 1.
    #[test]
    fn wasserstein_of_worked_cases() {
        assert!((wasserstein1(&mut [2.0], &mut [5.5]) - 3.5).abs() < 1e-15);
        assert!((wasserstein1(&mut [0.0, 1.0], &mut [3.0, 0.0]) - 1.0).abs() < 1e-15);
    }

    /// Samples of unequal sizes, where each empirical CDF steps by its own 1/size (the
    /// cases above, the sliced W1's and every caller in `stcvae eval` have equal sizes,
    /// where the two sizes could be taken for each other unseen). {0} against {1, 2}:
    /// F_a = 1 from 0 on, F_b = ½ on [1, 2), so W1 = 1·1 + ½·1 = 1.5 (the quantile
    /// coupling's mean distance, (1 + 2)/2), in either order. {0, 1, 2} against
    /// {0.5, 1.5}: |F_a − F_b| is 1/3, 1/6, 1/6, 1/3 on the four half-unit pieces of
    /// [0, 2], so W1 = ½·(1/3 + 1/6 + 1/6 + 1/3) = 0.5. With the sizes swapped in the
    /// CDFs these read 1.0, 1.0 and 0.833.
    #[test]
    fn wasserstein_of_samples_of_unequal_sizes() {
        for (a, b, want) in [
            (vec![0.0], vec![2.0, 1.0], 1.5),
            (vec![1.0, 2.0], vec![0.0], 1.5),
            (vec![0.0, 1.0, 2.0], vec![1.5, 0.5], 0.5),
        ] {
            let (mut a, mut b) = (a, b);
            let w = wasserstein1(&mut a, &mut b);
            assert!(
                (w - want).abs() < 1e-12,
                "{a:?} vs {b:?}: {w}, expected {want}"
            );
        }
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

    /// An empty second sample gives the 2-D statistic NaN as an empty first one does (only
    /// the first was tried): otherwise every share difference is x/0 = NaN, which
    /// `f64::max` drops, and the statistic came out 0, a perfect fit that passes every
    /// `d < bound` (an `eval` whose model draws were all filtered out).
    #[test]
    fn two_dimensional_ks_of_an_empty_sample_on_either_side_is_nan() {
        let a = [(0.25, 0.5), (0.75, 0.125)];
        assert!(ks_two_sample_2d(&a, &[]).is_nan());
        assert!(ks_two_sample_2d(&[], &a).is_nan());
        // Non-empty on both sides: a number.
        assert!(ks_two_sample_2d(&a, &a[..1]).is_finite());
    }

    /// A proportion's z where p ≠ ½. The worked case above has p = ½, where p(1 − p) = p²
    /// = ¼, so a variance of n·p², or the bound n/4, gave the same 2; away from ½ those
    /// shrink or swell z (n/4 at p = e^(−5) divides it by 6), and every |z| < 4 check of
    /// the simulator and the models then tests nothing. Hand-worked: 30 of 100 at p = 0.1
    /// is (30 − 10)/√(100·0.1·0.9) = 20/3; 50 of 100 at p = 0.8 is (50 − 80)/√16 = −7.5.
    /// 1e-12: a few f64 roundings of numbers of order 10 are ~1e-15; the wrong variances
    /// are off by more than 1.
    #[test]
    fn proportion_z_away_from_one_half() {
        let z = proportion_z(30, 100, 0.1);
        assert!((z - 20.0 / 3.0).abs() < 1e-12, "{z}");
        let z = proportion_z(50, 100, 0.8);
        assert!((z + 7.5).abs() < 1e-12, "{z}");
    }

    /// A NaN x (a model whose exit point is NaN, in `stcvae eval`) makes the 2-D statistic
    /// NaN at once, as a NaN y does (only y was tried): the sweep groups the points by equal
    /// x, and NaN equals no x, so a NaN x that reached it looped for ever. The call runs on
    /// a thread so that a hang fails the test rather than stalling the suite; it takes
    /// microseconds, and 30 s only tells an endless loop from a loaded machine (this is
    /// not a timing check: the correct code never comes near it).
    #[test]
    fn two_dimensional_ks_of_a_nan_x_is_nan() {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let b = [(0.25, 0.25), (0.75, 0.5)];
            // A NaN sorts last (total_cmp), a negative NaN first: both are refused.
            let first = ks_two_sample_2d(&[(f64::NAN, 0.5)], &b);
            let second = ks_two_sample_2d(&b, &[(0.5, 0.5), (-f64::NAN, 0.25)]);
            let _ = tx.send((first, second));
        });
        let (first, second) = rx
            .recv_timeout(std::time::Duration::from_secs(30))
            .expect("ks_two_sample_2d did not return on a NaN x");
        assert!(first.is_nan() && second.is_nan(), "{first} {second}");
    }
}
