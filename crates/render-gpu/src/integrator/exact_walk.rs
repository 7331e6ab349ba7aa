//! The walk of an exact sphere step (see [`super::sphere_step`]) in f32: the same process
//! as the simulator's [`scatter_sim::walk_with`] (which stays in f64, as the ground truth
//! and the training data need), with two 32-bit variates taken from each 64-bit draw and
//! `logf` in place of `log`. A walk below `exact_tau` has a handful of events, and at
//! k = 8 on the bunny these walks were a quarter of ST-CVAE's time, most of it the
//! direction sampling and the random draws.

use glam::Vec3;
use scatter_sim::rng::WalkRng;

/// 2^−32: a 32-bit integer to [0, 1).
const INV_2_32: f32 = 1.0 / 4_294_967_296.0;

/// How an exact walk ended: its event count and where and how it crossed the unit sphere.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ExactEnd {
    /// Scattering events, the centre included (N ≥ 1).
    pub n: u32,
    /// Exit point, |x| = 1.
    pub exit_pos: Vec3,
    /// Exit direction (unit, pointing outward).
    pub exit_dir: Vec3,
}

/// HG's cos θ given ξ ∈ [0, 1). The inverse CDF cancels for small |g| (its numerator is
/// O(g) from O(1) terms), so it is evaluated in f64 and only its result rounded; below
/// |g| = 10⁻⁸ HG is isotropic to within 10⁻⁸ relative.
#[inline]
fn hg_cos(g: f64, xi: f32) -> f32 {
    scatter_sim::phase::hg_sample_cos(g, xi as f64) as f32
}

/// A direction at cos θ from unit `dir`, at a uniform azimuth about it (drawn by
/// rejection from the square, both coordinates from one 64-bit draw).
#[inline]
fn deflect(dir: Vec3, cos_theta: f32, rng: &mut WalkRng) -> Vec3 {
    let (cos_psi, sin_psi) = loop {
        let bits = rng.next_u64();
        let a = (bits >> 32) as u32 as f32 * (2.0 * INV_2_32) - 1.0;
        let b = bits as u32 as f32 * (2.0 * INV_2_32) - 1.0;
        let r2 = a * a + b * b;
        if r2 <= 1.0 && r2 > 1e-12 {
            let inv = 1.0 / r2;
            break ((a * a - b * b) * inv, 2.0 * a * b * inv);
        }
    };
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    // Duff et al. (2017)'s branchless orthonormal basis about `dir`. (glam's
    // `any_orthonormal_pair` is the same construction, but with it the k = 1 and k = 8
    // bunny rendered 3–4 % slower: its sign goes through `f32::signum`.)
    let sign = 1.0f32.copysign(dir.z);
    let a = -1.0 / (sign + dir.z);
    let b = dir.x * dir.y * a;
    let t = Vec3::new(1.0 + sign * dir.x * dir.x * a, sign * b, -sign * dir.x);
    let u = Vec3::new(b, sign + dir.y * dir.y * a, -dir.y);
    let d = dir * cos_theta + (t * cos_psi + u * sin_psi) * sin_theta;
    // One Newton step toward unit length (|d|² = 1 + δ → 1 + O(δ²)): the roundings of
    // each event would otherwise accumulate over a walk, and a normalisation's square
    // root and division sit on the walk's serial chain of directions.
    d * (1.5 - 0.5 * d.length_squared())
}

/// Simulates one walk in the unit sphere of optical radius `tau` (HG with `g`), from the
/// centre arriving along +z, calling `event(X_k, W_k, rng)` at each event after the first
/// (event 1 is the centre, X = 0, W = +z).
#[inline]
pub(crate) fn walk(
    tau: f32,
    g: f32,
    rng: &mut WalkRng,
    mut event: impl FnMut(Vec3, Vec3, &mut WalkRng),
) -> ExactEnd {
    let g = g as f64;
    let inv_tau = 1.0 / tau;
    let mut pos = Vec3::ZERO;
    let mut arriving = Vec3::Z;
    let mut n = 1u32;
    loop {
        let bits = rng.next_u64();
        // ξ for the deflection from the high half, the flight's uniform in (0, 1] (safe
        // to take the logarithm of) from the low half.
        let xi = (bits >> 40) as f32 * (1.0 / 16_777_216.0);
        let u = (bits as u32 as f32 + 1.0) * INV_2_32;
        let dir = deflect(arriving, hg_cos(g, xi), rng);
        let flight = -u.ln() * inv_tau;
        let next = pos + dir * flight;
        // A flight of 2 or more crosses the unit sphere from anywhere inside; testing it
        // first also catches τ = 0 (infinite flight) before it makes NaNs.
        if !(flight < 2.0) || next.length_squared() >= 1.0 {
            // Distance to the sphere along dir: t² + 2bt + c = 0 with c = |p|² − 1 ≤ 0.
            let b = pos.dot(dir);
            let c = pos.length_squared() - 1.0;
            let t = -b + (b * b - c).max(0.0).sqrt();
            return ExactEnd {
                n,
                exit_pos: (pos + dir * t).normalize(),
                exit_dir: dir,
            };
        }
        pos = next;
        arriving = dir;
        n = n.saturating_add(1);
        event(pos, dir, rng);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The f32 walk against the simulator's f64 walk, an independent implementation of
    /// the same process: the distribution of N (chi-square over N = 1..11 and a tail bin)
    /// and of the exit's cos θ to +z and of the exit direction's cos to the exit normal
    /// (two-sample Kolmogorov–Smirnov), for forward (g = 0.875) and isotropic scattering,
    /// 40,000 walks each. The chi-square with 11 degrees of freedom (two samples: the
    /// statistic Σ (a − b)²/(a + b)) exceeds 31.3 with probability 0.1 %; the KS distance
    /// of two samples of n exceeds 1.95·√(2/n) = 0.0138 with probability 0.1 %. Flights 5 % too long
    /// or azimuths over half a turn each fail the N test by far (χ² 187 and 432).
    #[test]
    fn f32_walk_matches_the_simulator() {
        let n = 40_000;
        for &(tau, g) in &[(4.0f32, 0.875f32), (3.0, 0.0), (7.5, 0.875)] {
            let mut rng = WalkRng::for_walk(5, tau.to_bits() as u64 ^ g.to_bits() as u64);
            let mut ours = (vec![0u64; 12], Vec::new(), Vec::new());
            let mut theirs = (vec![0u64; 12], Vec::new(), Vec::new());
            for _ in 0..n {
                let e = walk(tau, g, &mut rng, |_, _, _| {});
                ours.0[(e.n as usize - 1).min(11)] += 1;
                ours.1.push(e.exit_pos.z as f64);
                ours.2.push(e.exit_pos.dot(e.exit_dir) as f64);
                let e = scatter_sim::walk_with(tau as f64, g as f64, &mut rng, |_, _, _, _| {});
                theirs.0[(e.n as usize - 1).min(11)] += 1;
                theirs.1.push(e.exit_pos.z);
                theirs.2.push(e.exit_pos.dot(e.exit_dir));
            }
            let chi2: f64 = ours
                .0
                .iter()
                .zip(&theirs.0)
                .filter(|(a, b)| **a + **b > 0)
                .map(|(&a, &b)| (a as f64 - b as f64).powi(2) / (a + b) as f64)
                .sum();
            assert!(chi2 < 31.3, "τ {tau}, g {g}: N chi-square {chi2}");
            for (a, b, what) in [
                (&mut ours.1, &mut theirs.1, "exit cos θ"),
                (&mut ours.2, &mut theirs.2, "exit direction"),
            ] {
                let d = scatter_sim::stats::ks_two_sample(a, b);
                assert!(d < 0.0138, "τ {tau}, g {g}: {what} KS distance {d}");
            }
        }
    }

    /// Events stay inside the unit sphere and the exit on it, with unit directions.
    #[test]
    fn events_stay_inside_and_exit_on_the_sphere() {
        let mut rng = WalkRng::for_walk(9, 0);
        for _ in 0..20_000 {
            let end = walk(6.0, 0.9, &mut rng, |x, w, _| {
                assert!(x.length_squared() < 1.0, "event at {x}");
                assert!((w.length() - 1.0).abs() < 1e-5, "direction {w}");
            });
            assert!((end.exit_pos.length() - 1.0).abs() < 1e-5);
            assert!(end.exit_pos.dot(end.exit_dir) >= -1e-5);
        }
    }
}
