//! The canonical frame of a sphere walk and its mapping to the world (design §2).
//!
//! A walk enters along ω_in = +z at the centre. Rotating the whole path about z so that
//! the exit point is x = (0, sin θ, cos θ) with sin θ ≥ 0 removes the azimuth, which is
//! uniform by symmetry. The exit direction is written in the exit frame
//! e_n = x, e_b = normalize(ω_in × x), e_t = e_b × e_n as ω = α e_b + β e_t + √(1−α²−β²) e_n.
//! In the canonical frame e_b = (−1, 0, 0) and e_t = (0, cos θ, −sin θ); at the poles
//! (sin θ = 0) the same e_b = (−1, 0, 0) is used, the limit sin θ → 0⁺.
//!
//! The renderers map canonical quantities to the world with [`WalkFrame`], whose third
//! axis is the world ω_in and whose first two axes carry the random azimuth ψ.

use glam::{DMat3, DVec3};

use crate::phase::orthonormal_basis;

/// The exit of a walk in the canonical frame: position and direction as (cos θ, α, β).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CanonicalExit {
    pub cos_theta: f64,
    pub alpha: f64,
    pub beta: f64,
}

/// A rotation about z, R = [[c, −s], [s, c]] on (x, y).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AzimuthRotation {
    pub cos: f64,
    pub sin: f64,
}

impl AzimuthRotation {
    /// The rotation that takes `x` into the half-plane x = 0, y ≥ 0 (identity on the z axis).
    pub fn aligning(x: DVec3) -> Self {
        let rho = (x.x * x.x + x.y * x.y).sqrt();
        if rho > 0.0 {
            Self {
                cos: x.y / rho,
                sin: x.x / rho,
            }
        } else {
            Self { cos: 1.0, sin: 0.0 }
        }
    }

    #[inline]
    pub fn apply(&self, v: DVec3) -> DVec3 {
        DVec3::new(
            self.cos * v.x - self.sin * v.y,
            self.sin * v.x + self.cos * v.y,
            v.z,
        )
    }

    #[inline]
    pub fn inverse(&self) -> Self {
        Self {
            cos: self.cos,
            sin: -self.sin,
        }
    }
}

/// The exit frame (e_n, e_b, e_t) at the canonical exit point with polar cosine `cos_theta`.
#[inline]
pub fn exit_frame(cos_theta: f64) -> (DVec3, DVec3, DVec3) {
    let c = cos_theta.clamp(-1.0, 1.0);
    let s = (1.0 - c * c).max(0.0).sqrt();
    (
        DVec3::new(0.0, s, c),
        DVec3::new(-1.0, 0.0, 0.0),
        DVec3::new(0.0, c, -s),
    )
}

/// Canonicalises a walk's exit point `x` (|x| = 1) and exit direction `omega` (ω_in = +z).
/// Returns the canonical exit and the rotation that was applied; apply the same rotation
/// to any other point of the path (e.g. the representative event) to keep it consistent.
pub fn to_canonical(x: DVec3, omega: DVec3) -> (CanonicalExit, AzimuthRotation) {
    let rot = AzimuthRotation::aligning(x);
    let xc = rot.apply(x);
    let wc = rot.apply(omega);
    let cos_theta = xc.z.clamp(-1.0, 1.0);
    let (_, e_b, e_t) = exit_frame(cos_theta);
    (
        CanonicalExit {
            cos_theta,
            alpha: wc.dot(e_b),
            beta: wc.dot(e_t),
        },
        rot,
    )
}

/// The exit point and direction in the canonical frame for a (possibly model-made)
/// exit. Out-of-range values are repaired rather than propagated: cos θ is clamped to
/// [−1, 1] and (α, β) rescaled onto the unit disk, so no NaN can follow.
pub fn from_canonical(exit: CanonicalExit) -> (DVec3, DVec3) {
    let (e_n, e_b, e_t) = exit_frame(if exit.cos_theta.is_finite() {
        exit.cos_theta
    } else {
        1.0
    });
    let (mut a, mut b) = (exit.alpha, exit.beta);
    if !(a.is_finite() && b.is_finite()) {
        a = 0.0;
        b = 0.0;
    }
    let r2 = a * a + b * b;
    if r2 > 1.0 {
        let r = r2.sqrt();
        a /= r;
        b /= r;
    }
    let n = (1.0 - a * a - b * b).max(0.0).sqrt();
    (e_n, (a * e_b + b * e_t + n * e_n).normalize())
}

/// Maps canonical coordinates to the world: +z goes to the world's arriving direction
/// ω_in, and the canonical x/y axes are turned by the azimuth ψ about it.
#[derive(Clone, Copy, Debug)]
pub struct WalkFrame {
    /// Columns: images of the canonical x, y, z axes.
    pub basis: DMat3,
}

impl WalkFrame {
    /// `omega_in` must be a unit vector; `(cos ψ, sin ψ)` is the random azimuth.
    pub fn new(omega_in: DVec3, (cos_psi, sin_psi): (f64, f64)) -> Self {
        let (t, b) = orthonormal_basis(omega_in);
        let u = t * cos_psi + b * sin_psi;
        let v = b * cos_psi - t * sin_psi;
        Self {
            basis: DMat3::from_cols(u, v, omega_in),
        }
    }

    #[inline]
    pub fn to_world(&self, v: DVec3) -> DVec3 {
        self.basis * v
    }

    #[inline]
    pub fn to_canonical(&self, v: DVec3) -> DVec3 {
        self.basis.transpose() * v
    }
}
