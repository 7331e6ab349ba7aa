//! Input and output transforms of the three models (feature version 3; version 2 files
//! are still read).
//!
//! Small decoders learn faster and better when the physics they would otherwise have to
//! discover is built into their inputs and targets:
//! - τ spans 0–300 with most mass near 0: the network sees ln(1 + τ).
//! - N spans 1–10⁵ and grows like (1 − g)τ²/2 (diffusion): LengthGen predicts log N
//!   *relative to* that scale, `ln N − prior(τ, g)`, and PathGen/EventGen are conditioned
//!   on the same relative log N, which says how diffusive the walk was.
//! - N is an integer: training on ln(N + u), u ~ U(0, 1) (dequantisation) gives the
//!   Gaussian decoder a density to fit rather than spikes; N = ⌊e^y⌋ inverts it exactly.
//! - φ enters EventGen as (1 − φ)^{1/6}, the authors' choice, which spreads the albedos
//!   near 1 that matter most.
//! - Bounded outputs are mapped onto the whole real line, so a Gaussian decoder can fit
//!   them without mass piling up at clamps, and every decoded value is valid by
//!   construction: cos θ ∈ (−1, 1) through a logit (a uniform cos θ becomes a logistic,
//!   near-Gaussian variable); the exit direction's (β, α) in the unit disk through the
//!   radial map r² ↦ −ln(1 − r²) (a uniform disk — a cosine-lobe exit — becomes an
//!   exact 2-D Gaussian); the representative event X in the unit ball through a radial
//!   map that sends the sphere's surface to infinity ([`EventRadial`]).
//!
//! After these transforms every input and output is standardised with the shift and
//! scale stored in the model file.

/// Version of the transforms below; stored in the model file and checked on load.
/// Version 3 differs from 2 only in EventGen's radial map ([`EventRadial`]), so a file's
/// version says how to read its EventGen; LengthGen and PathGen read the same in both.
pub const FEATURE_VERSION: u32 = 3;
/// The oldest version this build reads.
pub const OLDEST_FEATURE_VERSION: u32 = 2;

/// Number of conditioning inputs of each model.
pub const LENGTH_COND: usize = 2;
pub const PATH_COND: usize = 3;
pub const EVENT_COND: usize = 7;
/// Number of outputs of each model.
pub const LENGTH_OUT: usize = 1;
pub const PATH_OUT: usize = 3;
pub const EVENT_OUT: usize = 6;

#[inline]
pub fn tau_feature(tau: f64) -> f64 {
    tau.max(0.0).ln_1p()
}

/// The diffusion-limit event count's coefficients, N ≈ ½(1 − g)τ² + 0.71τ: the τ² term is
/// diffusion's, the linear one comes from the extrapolated boundary z_b ≈ 0.71 transport
/// lengths (Milne problem). The GPU kernels take both from here (shaders/decoder.wgsl's
/// `log_n_prior`); a copy in WGSL that drifted would feed LengthGen other inputs than it
/// was trained on.
pub const PRIOR_QUADRATIC: f64 = 0.5;
pub const PRIOR_LINEAR: f64 = 0.71;

/// ln of the diffusion-limit event count, made finite and ≥ ln 1 for small τ.
#[inline]
pub fn log_n_prior(tau: f64, g: f64) -> f64 {
    (1.0 + PRIOR_QUADRATIC * (1.0 - g) * tau * tau + PRIOR_LINEAR * tau).ln()
}

#[inline]
pub fn albedo_feature(albedo: f64) -> f64 {
    (1.0 - albedo).max(0.0).powf(1.0 / 6.0)
}

/// LengthGen's target: the dequantised relative log N (`u` ∈ [0, 1)).
#[inline]
pub fn length_target(n: u64, u: f64, tau: f64, g: f64) -> f64 {
    (n as f64 + u).ln() - log_n_prior(tau, g)
}

pub fn length_cond(tau: f64, g: f64) -> [f64; LENGTH_COND] {
    WalkFeatures::new(tau, g, 1.0).length_cond()
}

pub fn path_cond(tau: f64, g: f64, n: u64) -> [f64; PATH_COND] {
    let f = WalkFeatures::new(tau, g, 1.0);
    f.path_cond(f.relative_log_n(n))
}

/// Exit order as in the dataset columns: cos θ, β, α.
pub fn event_cond(
    tau: f64,
    g: f64,
    albedo: f64,
    n: u64,
    cos_theta: f64,
    beta: f64,
    alpha: f64,
) -> [f64; EVENT_COND] {
    let f = WalkFeatures::new(tau, g, albedo);
    f.event_cond(f.relative_log_n(n), cos_theta, beta, alpha)
}

/// The largest N LengthGen's read-out gives, 10^15 (shaders/decoder.wgsl caps at the same
/// value, which the GPU kernels take from here): only a damaged or absurd draw gets there,
/// and with NEE's weight Λ(N) = N at φ = 1 the cap bounds that outlier alike on both
/// devices.
pub const MAX_DECODED_N: u64 = 1_000_000_000_000_000;

/// The features of one walk's (τ, g, φ), which all three models' conditions share. A
/// renderer draws N, the exit and two events for every sphere step: computing these once
/// per step, not once per model, saves eight of its ~17 f64 logarithms and powers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkFeatures {
    /// ln(1 + τ).
    pub tau: f64,
    pub g: f64,
    /// (1 − φ)^{1/6}.
    pub albedo: f64,
    /// ln of the diffusion-limit event count ([`log_n_prior`]).
    pub log_prior: f64,
}

impl WalkFeatures {
    pub fn new(tau: f64, g: f64, albedo: f64) -> Self {
        Self {
            tau: tau_feature(tau),
            g,
            albedo: albedo_feature(albedo),
            log_prior: log_n_prior(tau, g),
        }
    }

    pub fn length_cond(&self) -> [f64; LENGTH_COND] {
        [self.tau, self.g]
    }

    /// Relative log N, the conditioning input of PathGen and EventGen.
    pub fn relative_log_n(&self, n: u64) -> f64 {
        (n as f64).ln() - self.log_prior
    }

    /// Inverse of [`length_target`]: N = ⌊exp(y + prior)⌋, at least `n_min` and at most
    /// [`MAX_DECODED_N`].
    pub fn n_from_target(&self, y: f64, n_min: u64) -> u64 {
        let v = (y + self.log_prior).exp().floor();
        if v.is_nan() {
            n_min
        } else {
            (v.min(MAX_DECODED_N as f64) as u64).max(n_min)
        }
    }

    pub fn path_cond(&self, relative_log_n: f64) -> [f64; PATH_COND] {
        [self.tau, self.g, relative_log_n]
    }

    /// Exit order as in the dataset columns: cos θ, β, α.
    pub fn event_cond(
        &self,
        relative_log_n: f64,
        cos_theta: f64,
        beta: f64,
        alpha: f64,
    ) -> [f64; EVENT_COND] {
        [
            self.tau,
            self.g,
            self.albedo,
            relative_log_n,
            cos_theta,
            beta,
            alpha,
        ]
    }
}

/// Keeps logit/atanh/ln(1 − ρ²) arguments away from ±1 (f32 data holds values within
/// 6e-8 of 1).
const EDGE: f64 = 1e-7;

/// PathGen's target from (cos θ, β, α), the dataset's column order.
pub fn path_target(cos_theta: f64, beta: f64, alpha: f64) -> [f64; 3] {
    let u = (0.5 * (cos_theta + 1.0)).clamp(EDGE, 1.0 - EDGE);
    let r2 = (beta * beta + alpha * alpha).min(1.0 - EDGE);
    // Radial map of the disk onto the plane: R² = −ln(1 − r²); R/r → 1 as r → 0.
    let f = if r2 > 1e-12 {
        ((-(-r2).ln_1p()) / r2).sqrt()
    } else {
        1.0
    };
    [(u / (1.0 - u)).ln(), beta * f, alpha * f]
}

/// Inverse of [`path_target`]: (cos θ, β, α), always a valid exit (|cos θ| < 1, r < 1).
pub fn path_from_target(v: [f64; 3]) -> (f64, f64, f64) {
    let y = if v[0].is_finite() { v[0] } else { 0.0 };
    let cos_theta = (2.0 / (1.0 + (-y).exp()) - 1.0).clamp(-1.0, 1.0);
    let (b, a) = if v[1].is_finite() && v[2].is_finite() {
        (v[1], v[2])
    } else {
        (0.0, 0.0)
    };
    let big_r2 = b * b + a * a;
    let f = if big_r2 > 1e-12 {
        ((-(-big_r2).exp_m1()) / big_r2).sqrt()
    } else {
        1.0
    };
    (cos_theta, b * f, a * f)
}

/// How EventGen's target holds the distance |X| = ρ of the representative event from the
/// centre: ρ is mapped onto [0, ∞) and X scaled to that length.
///
/// Why version 3 changed it: near the sphere's surface the simulator's events have a
/// density in ρ that stays finite up to ρ = 1 (a random walk scatters right up to the
/// surface it escapes through). Under atanh that edge becomes an exponential tail,
/// 1 − ρ ≈ 2e^(−2u), which a Gaussian decoder cannot follow: the shipped version-2
/// EventGen puts 1.3–1.9× too many events 0.5–10 % of the radius from the surface and up
/// to 2.5× too few in the last 0.1 % (docs/BENCHMARKS.md, thirteenth session), where
/// the NEE of a step that touches the object's surface is collected. With
/// u = √(−2 ln(1 − ρ²)) the edge becomes 1 − ρ² = e^(−u²/2), a Gaussian tail (a flat density near ρ = 1 gives a
/// Rayleigh-like u·e^(−u²/2)); on the simulator's walks at g = 0.875 the radial feature's
/// kurtosis drops from ~7 to ~3.7 (3 for a Gaussian). Near the centre u ≈ √2·ρ, smooth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EventRadial {
    /// u = atanh ρ (feature version 2).
    Atanh,
    /// u = √(−2 ln(1 − ρ²)) (feature version 3).
    GaussianEdge,
}

impl EventRadial {
    /// The map of [`FEATURE_VERSION`], the one training uses.
    pub const CURRENT: Self = Self::GaussianEdge;

    /// The map a file of this feature version uses (None: a version this build cannot read).
    pub fn of_version(version: u32) -> Option<Self> {
        match version {
            2 => Some(Self::Atanh),
            3 => Some(Self::GaussianEdge),
            _ => None,
        }
    }

    /// u/ρ for ρ ∈ [0, 1): the factor that scales X to its feature.
    fn scale_to(self, rho: f64) -> f64 {
        if rho <= 1e-12 {
            return match self {
                Self::Atanh => 1.0,
                Self::GaussianEdge => std::f64::consts::SQRT_2,
            };
        }
        let rho = rho.min(1.0 - EDGE);
        match self {
            Self::Atanh => rho.atanh() / rho,
            Self::GaussianEdge => (-2.0 * (-rho * rho).ln_1p()).sqrt() / rho,
        }
    }

    /// ρ/u for u ≥ 0: the inverse's factor; ρ < 1 for every finite u (up to rounding).
    fn scale_from(self, u: f64) -> f64 {
        if u <= 1e-12 {
            return match self {
                Self::Atanh => 1.0,
                Self::GaussianEdge => std::f64::consts::FRAC_1_SQRT_2,
            };
        }
        match self {
            Self::Atanh => u.tanh() / u,
            Self::GaussianEdge => (-(-0.5 * u * u).exp_m1()).sqrt() / u,
        }
    }
}

/// EventGen's target from the representative event X (|X| ≤ 1) and W (|W| = 1).
pub fn event_target(radial: EventRadial, x: [f64; 3], w: [f64; 3]) -> [f64; 6] {
    let rho = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    let f = radial.scale_to(rho);
    [x[0] * f, x[1] * f, x[2] * f, w[0], w[1], w[2]]
}

/// Inverse of [`event_target`]: X strictly inside the unit ball (W is normalised by the
/// caller).
pub fn event_from_target(radial: EventRadial, v: [f64; 6]) -> ([f64; 3], [f64; 3]) {
    let big = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !big.is_finite() {
        return ([0.0; 3], [v[3], v[4], v[5]]);
    }
    let f = radial.scale_from(big);
    ([v[0] * f, v[1] * f, v[2] * f], [v[3], v[4], v[5]])
}

/// Whether a recorded representative event is event 1 (the centre, arriving along +z):
/// the simulator puts it at exactly (0, 0, 0).
pub fn is_centre_event(x: [f32; 3]) -> bool {
    x == [0.0; 3]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn current_radial_map_is_the_current_version() {
        assert_eq!(
            EventRadial::of_version(FEATURE_VERSION),
            Some(EventRadial::CURRENT)
        );
        assert_eq!(
            EventRadial::of_version(OLDEST_FEATURE_VERSION),
            Some(EventRadial::Atanh)
        );
        assert_eq!(EventRadial::of_version(FEATURE_VERSION + 1), None);
    }

    /// The version-3 map's defining property: 1 − ρ² = e^(−u²/2), so events within a
    /// band of the surface land in a Gaussian tail of u. Checked where that tail lies
    /// (u = 3–4.5: the last 1 % to 0.004 % of ρ²).
    #[test]
    fn gaussian_edge_puts_the_surface_in_a_gaussian_tail() {
        for t in [3.0f64, 3.5, 4.0, 4.5] {
            let rho = (-(-0.5 * t * t).exp_m1()).sqrt();
            let u = EventRadial::GaussianEdge.scale_to(rho) * rho;
            assert!((u - t).abs() < 1e-9, "u({rho}) = {u}, expected {t}");
        }
    }

    /// The output transforms are bijections on the valid set: round trips agree to
    /// within f64 rounding amplified by the logit/atanh slopes near the edges.
    #[test]
    fn output_transforms_round_trip() {
        let mut rng = scatter_sim::WalkRng::for_walk(5, 0);
        for _ in 0..10_000 {
            let c = 2.0 * rng.uniform() - 1.0;
            let (b, a) = rng.unit_circle();
            let r = rng.uniform().sqrt() * 0.999;
            let (c2, b2, a2) = path_from_target(path_target(c, b * r, a * r));
            assert!(
                (c - c2).abs() < 1e-9 && (b * r - b2).abs() < 1e-9 && (a * r - a2).abs() < 1e-9
            );
            // Events anywhere in the ball, up to 1e-5 of its surface.
            let len = (1.0 - 1e-5) * rng.uniform().cbrt();
            let (u, v) = (
                2.0 * rng.uniform() - 1.0,
                rng.uniform() * std::f64::consts::TAU,
            );
            let s = (1.0 - u * u).sqrt();
            let x = [len * s * v.cos(), len * s * v.sin(), len * u];
            for radial in [EventRadial::Atanh, EventRadial::GaussianEdge] {
                let (x2, _) = event_from_target(radial, event_target(radial, x, [0.0, 0.0, 1.0]));
                for k in 0..3 {
                    assert!((x[k] - x2[k]).abs() < 1e-9, "{radial:?}: {x:?} -> {x2:?}");
                }
            }
        }
        // Anything a decoder returns maps to a valid exit and event.
        for v in [-1e9, -30.0, 0.0, 30.0, 1e9, f64::NAN] {
            let (c, b, a) = path_from_target([v, v, -v]);
            assert!(c.abs() <= 1.0 && b * b + a * a <= 1.0 + 1e-12);
            for radial in [EventRadial::Atanh, EventRadial::GaussianEdge] {
                let (x, _) = event_from_target(radial, [v, v, v, 0.0, 0.0, 1.0]);
                assert!(x.iter().map(|q| q * q).sum::<f64>() <= 1.0 + 1e-12);
            }
        }
    }

    /// Exits on the edge of their domain give finite targets that map back onto it: a
    /// tangent exit direction (β, α) = (0.6, 0.8) as the f32 dataset holds it has β² + α²
    /// = 1 + 4.8e-8 in f64, and (0, 1) exactly 1; the poles cos θ = ±1 are what f32 makes
    /// of HG directions within 3e-8 of them (a few in 10⁴ single-scattering exits at
    /// |g| → 1). Clamped 1e-7 inside, each maps to a finite target (|logit| ≤ 16.12,
    /// radius √16.12) and back to within 2e-7 of itself; at r² = 1 the radial map's
    /// −ln(1 − r²) is infinite, and at cos θ = 1 the logit. The round trip test draws
    /// r ≤ 0.999 and |cos θ| < 1, where no clamp acts.
    #[test]
    fn exits_on_the_edge_give_finite_targets() {
        let (b, a) = (0.6f32 as f64, 0.8f32 as f64);
        assert!(b * b + a * a > 1.0);
        for (c, b, a) in [
            (0.0, b, a),
            (0.2, 0.0, 1.0),
            (-0.3, -1.0, 0.0),
            (1.0, 0.0, 0.0),
            (-1.0, 0.0, 0.0),
        ] {
            let t = path_target(c, b, a);
            assert!(t.iter().all(|v| v.is_finite()), "({c}, {b}, {a}) -> {t:?}");
            let (c2, b2, a2) = path_from_target(t);
            assert!(
                (c2 - c).abs() < 1e-6 && (b2 - b).abs() < 1e-6 && (a2 - a).abs() < 1e-6,
                "({c}, {b}, {a}) -> {t:?} -> ({c2}, {b2}, {a2})"
            );
        }
    }

    /// Events on the sphere's surface, |X| = 1 (and 1 + 2.4e-8, as f32 holds (0.6, 0, 0.8)),
    /// give finite targets under both radial maps, which map back to within 1e-6 of the
    /// surface and inside it: ρ is clamped 1e-7 inside, where atanh ρ and
    /// √(−2 ln(1 − ρ²)) are 8.4 and 5.6; at ρ = 1 both are infinite. The round trip test
    /// draws events at most 1 − 1e-5 from the centre, where no clamp acts.
    #[test]
    fn events_on_the_surface_give_finite_targets() {
        let edge = [0.6f32 as f64, 0.0, 0.8f32 as f64];
        for x in [[0.0, 0.0, 1.0], [0.6, 0.0, -0.8], [0.0, -1.0, 0.0], edge] {
            for radial in [EventRadial::Atanh, EventRadial::GaussianEdge] {
                let t = event_target(radial, x, [0.0, 0.0, 1.0]);
                assert!(
                    t.iter().all(|v| v.is_finite()),
                    "{radial:?}: {x:?} -> {t:?}"
                );
                let (x2, _) = event_from_target(radial, t);
                let r = x2.iter().map(|q| q * q).sum::<f64>().sqrt();
                assert!(r < 1.0 && r > 1.0 - 1e-6, "{radial:?}: {x:?} -> {x2:?}");
            }
        }
    }
}
