//! The Henyey–Greenstein phase function: density, CDF and sampling.
//!
//! Convention: `cos` is the cosine between the arriving and the departing direction
//! (cos = 1: no deflection); g > 0 scatters forward.

use glam::DVec3;
use std::f64::consts::PI;

use crate::rng::WalkRng;

/// Below this |g| the sampling formula loses precision to cancellation; HG is then
/// isotropic to within 1e-8 relative, so sample it as isotropic.
const G_ISOTROPIC: f64 = 1e-8;

/// HG density per steradian: ρ_g(cos) = (1 − g²) / (4π (1 + g² − 2g·cos)^{3/2}).
#[inline]
pub fn hg_pdf(g: f64, cos: f64) -> f64 {
    let denom = 1.0 + g * g - 2.0 * g * cos;
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

/// HG per steradian from the arriving direction `w` to the departing `l`, both unit
/// vectors to f32 precision. 1 − cos θ (1 + cos θ for g < 0, the axis of its lobe) is half
/// the squared distance between them, which keeps its relative precision where 1 − w·l
/// is rounding: f32 directions hold w·l to ~1e-7, and the lobe of g = 0.999 is
/// 1 − cos θ ~ 5e-7 wide. The density is then written in non-negative terms of a = |g|,
/// as the WGSL kernels' `hg_pdf_between` computes it in f32.
#[inline]
pub fn hg_pdf_between(g: f64, w: DVec3, l: DVec3) -> f64 {
    let e = if g < 0.0 { w + l } else { w - l };
    let m = (0.5 * e.length_squared()).min(2.0);
    let a = g.abs();
    let d = (1.0 - a) * (1.0 - a) + 2.0 * a * m;
    (1.0 - a) * (1.0 + a) / (4.0 * PI * d * d.sqrt())
}

/// Density of cos θ on [−1, 1] (the per-steradian density times 2π).
#[inline]
pub fn hg_cos_pdf(g: f64, cos: f64) -> f64 {
    2.0 * PI * hg_pdf(g, cos)
}

/// CDF of cos θ: F(μ) = (1 − g²)/(2g) · [(1 + g² − 2gμ)^{−1/2} − (1 + g)^{−1}].
pub fn hg_cos_cdf(g: f64, cos: f64) -> f64 {
    let mu = cos.clamp(-1.0, 1.0);
    if g.abs() < G_ISOTROPIC {
        return 0.5 * (1.0 + mu);
    }
    let f =
        (1.0 - g * g) / (2.0 * g) * (1.0 / (1.0 + g * g - 2.0 * g * mu).sqrt() - 1.0 / (1.0 + g));
    f.clamp(0.0, 1.0)
}

/// Inverse CDF: the cos θ with F(cos θ) = ξ, for ξ ∈ [0, 1].
#[inline]
pub fn hg_sample_cos(g: f64, xi: f64) -> f64 {
    if g.abs() < G_ISOTROPIC {
        return 2.0 * xi - 1.0;
    }
    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * xi);
    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
}

/// Two unit vectors completing `n` to a right-handed orthonormal basis (t, b, n).
/// Branchless construction of Duff et al. (2017), exact for every unit `n`.
#[inline]
pub fn orthonormal_basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    (t, bt)
}

/// The direction at angle θ (given cos θ) from `dir` and azimuth (cos ψ, sin ψ) about it.
#[inline]
pub fn deflect(dir: DVec3, cos_theta: f64, (cos_psi, sin_psi): (f64, f64)) -> DVec3 {
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let (t, b) = orthonormal_basis(dir);
    dir * cos_theta + (t * cos_psi + b * sin_psi) * sin_theta
}

/// Draws a direction from HG around the arriving direction `dir`.
#[inline]
pub fn hg_sample_direction(g: f64, dir: DVec3, rng: &mut WalkRng) -> DVec3 {
    let cos_theta = hg_sample_cos(g, rng.uniform());
    deflect(dir, cos_theta, rng.unit_circle())
}
