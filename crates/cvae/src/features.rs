//! Input and output transforms of the three models (feature version 1).
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
//!
//! After these transforms every input and output is standardised with the shift and
//! scale stored in the model file.

/// Version of the transforms below; stored in the model file and checked on load.
pub const FEATURE_VERSION: u32 = 1;

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

/// ln of the diffusion-limit event count, made finite and ≥ ln 1 for small τ.
#[inline]
pub fn log_n_prior(tau: f64, g: f64) -> f64 {
    (1.0 + 0.5 * (1.0 - g) * tau * tau + 0.71 * tau).ln()
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

/// Inverse of [`length_target`]: N = ⌊exp(y + prior)⌋, at least `n_min`.
#[inline]
pub fn length_from_target(y: f64, tau: f64, g: f64, n_min: u64) -> u64 {
    let v = (y + log_n_prior(tau, g)).exp().floor();
    if v.is_finite() && v < 1e15 {
        (v as u64).max(n_min)
    } else if v.is_nan() {
        n_min
    } else {
        1_000_000_000_000_000
    }
}

/// Relative log N, the conditioning input of PathGen and EventGen.
#[inline]
pub fn relative_log_n(n: u64, tau: f64, g: f64) -> f64 {
    (n as f64).ln() - log_n_prior(tau, g)
}

pub fn length_cond(tau: f64, g: f64) -> [f64; LENGTH_COND] {
    [tau_feature(tau), g]
}

pub fn path_cond(tau: f64, g: f64, n: u64) -> [f64; PATH_COND] {
    [tau_feature(tau), g, relative_log_n(n, tau, g)]
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
    [
        tau_feature(tau),
        g,
        albedo_feature(albedo),
        relative_log_n(n, tau, g),
        cos_theta,
        beta,
        alpha,
    ]
}
