//! The proxy that chooses an exact sphere step's NEE events (see
//! [`super::sphere_step`] and [`super::walk_lanes`], which offers each event of a walk
//! to the step's reservoirs with weight φ^k q_k): q_k, a cheap bound on event k's NEE.

use glam::Vec3;

/// Most lights the proxy weighs (beyond, events are chosen by φ^k alone), as in the
/// WGSL kernel (`ex_lights`).
pub(crate) const MAX_PROXY_LIGHTS: usize = 4;
/// Most events chosen per walk (the kernels keep one reservoir slot per event).
pub(crate) const MAX_EVENTS: usize = crate::scene::MAX_EXACT_NEE_SAMPLES as usize;

/// The proxy q(X, W) = Σ_l E_l · ρ_g(W·ω_l) · exp(−τ · chord of the free ball from X
/// along ω_l): the NEE of an event toward each light with the transmittance taken only
/// across the surface-free ball (in units of the walk's sphere), which bounds it. Any
/// positive proxy keeps the estimate unbiased as long as the same value selects and
/// weights an event, so it is evaluated in f32 with short polynomials for 2^x and
/// log₂ x (relative error ~10⁻⁵).
#[derive(Clone, Copy)]
pub(crate) struct Proxy {
    /// Light directions in the walk's frame and irradiances (this channel).
    pub(super) lights: [(Vec3, f32); MAX_PROXY_LIGHTS],
    /// q = 1 for every event (a light dark in this channel, or too many lights).
    pub(super) flat: bool,
    /// The free ball's radius² in units of the walk's sphere (≥ 1).
    pub(super) f2: f32,
    /// τ·log₂e: the transmittance as a power of two.
    pub(super) tau_log2e: f32,
    /// HG as c · d^(−3/2) with d = 1 + g² − 2g·cos (the lanes hold d's constants).
    pub(super) hg_c: f32,
}

impl Proxy {
    /// `lights`: (direction toward the light in the walk's frame, irradiance in this
    /// channel); `tau`: the walk's optical radius; `f2`: the free ball's radius² in units
    /// of the walk's sphere.
    #[inline]
    pub fn new(
        lights: impl ExactSizeIterator<Item = (Vec3, f32)>,
        tau: f32,
        f2: f32,
        g: f32,
    ) -> Self {
        let mut flat = lights.len() > MAX_PROXY_LIGHTS;
        let mut dirs = [(Vec3::Z, 0.0); MAX_PROXY_LIGHTS];
        for (slot, (dir, e)) in dirs.iter_mut().zip(lights) {
            // The proxy must be positive wherever the NEE can be.
            flat |= !(e > 0.0);
            *slot = (dir, e);
        }
        Self {
            lights: dirs,
            flat,
            f2: f2.max(1.0),
            tau_log2e: tau * std::f32::consts::LOG2_E,
            hg_c: (1.0 - g * g) / (4.0 * std::f32::consts::PI),
        }
    }
}

/// 2^x, clamped to the normal range [2^−126, 2^127]: the exponent bits from x rounded
/// to the nearest integer (by the 1.5·2^23 trick, which vectorises where `floor` needs
/// SSE4.1), 2^f for f ∈ [−0.5, 0.5] from a degree-4 least-squares polynomial (relative
/// error < 4·10⁻⁶).
#[inline]
pub(super) fn exp2(x: f32) -> f32 {
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-126.0, 127.0);
    let r = (x + ROUND) - ROUND;
    let f = x - r;
    let p = 1.0 + f * (0.693_122 + f * (0.240_237_2 + f * (0.055_916_89 + f * 0.009_600_396)));
    p * f32::from_bits((((r as i32) + 127) as u32) << 23)
}

/// log₂ x for positive normal x: the exponent bits plus a degree-5 least-squares
/// polynomial in the mantissa m ∈ [1, 2) (absolute error < 2·10⁻⁵).
#[inline]
pub(super) fn log2(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000) - 1.0;
    let p = m
        * (1.441_88
            + m * (-0.708_865_2 + m * (0.415_245_6 + m * (-0.193_516_5 + m * 0.045_268_29))));
    e as f32 + p
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fast 2^x and log₂ x against the standard library over their ranges. Bounds: the
    /// polynomials' own errors (fitted: < 4·10⁻⁶ relative, < 2·10⁻⁵ absolute) plus f32
    /// rounding of the few operations around them, with ~1.5–2.5× to spare; a wrong
    /// coefficient or exponent shift gives errors of 10⁻³ and more.
    #[test]
    fn fast_exp2_and_log2_are_accurate() {
        for i in 0..=20_000 {
            let x = -126.0 + 253.0 * i as f32 / 20_000.0;
            let rel = exp2(x) / x.exp2() - 1.0;
            assert!(rel.abs() < 1e-5, "exp2({x}): relative error {rel}");
        }
        for i in 1..=20_000 {
            let x = 1e-6 * (1e12f32).powf(i as f32 / 20_000.0);
            let err = log2(x) - x.log2();
            assert!(err.abs() < 3e-5, "log2({x}): error {err}");
        }
    }

    /// The proxy weighs each of up to [`MAX_PROXY_LIGHTS`] lit lights (kept in order) and
    /// turns flat (q = 1 for every event) only beyond them or where a light is dark in the
    /// channel, as the WGSL kernel's `ex_lights` does. Flat where it need not be (a scene
    /// of exactly four lights), an exact step's NEE events are chosen by φ^k alone, blind
    /// to the side of the ball the lights are on: still unbiased, as any positive proxy
    /// is, so no image test sees it, only more variance; and no scene in the tests has
    /// four lights (they have one, two or six; 65 in the CLI's test of the GPU's light
    /// limit, with PT).
    #[test]
    fn the_proxy_is_flat_only_beyond_its_lights_or_for_a_dark_one() {
        let lit = |n: usize| {
            (0..n).map(|i| {
                let d = Vec3::new(0.2 * i as f32 - 0.3, 0.6, 0.7).normalize();
                (d, 1.0 + i as f32)
            })
        };
        for n in 1..=MAX_PROXY_LIGHTS {
            let p = Proxy::new(lit(n), 2.0, 1.5, 0.5);
            assert!(!p.flat, "{n} lit lights: a flat proxy");
            for (i, light) in lit(n).enumerate() {
                assert_eq!(p.lights[i], light, "light {i} of {n}");
            }
        }
        assert!(
            Proxy::new(lit(MAX_PROXY_LIGHTS + 1), 2.0, 1.5, 0.5).flat,
            "more lights than the proxy weighs"
        );
        let dark = [(Vec3::Y, 1.0f32), (Vec3::X, 0.0)];
        assert!(
            Proxy::new(dark.into_iter(), 2.0, 1.5, 0.5).flat,
            "a light dark in the channel"
        );
    }
}
