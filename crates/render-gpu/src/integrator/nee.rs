//! Next-event estimation to the directional lights from a point inside the medium.
//!
//! The phase function is evaluated toward the light: cos = W·ω_light with ω_light =
//! −(the direction the light travels). Transmittance sums every inside segment of the
//! straight shadow ray (non-convex meshes re-enter). With a dielectric boundary the ray
//! is not refracted (the paper's straight shadow ray) but multiplied by the Fresnel
//! transmittance at each crossing: a documented bias, excluded from equality tests.

use glam::Vec3;
use scatter_sim::phase::hg_pdf;
use scatter_sim::rng::WalkRng;

use super::uniform;
use crate::optics::fresnel;
use crate::setup::{Boundary, SceneData};

/// Beyond this optical depth the transmittance (< 2e-22) is taken as 0.
const MAX_OPTICAL_DEPTH: f32 = 50.0;
/// Most surface crossings followed along one shadow ray.
const MAX_CROSSINGS: usize = 64;

/// Shadow-ray roulette on a bound of the NEE term: with T ≤ exp(−σ_t·free(ω_l)) (the
/// shadow ray along ω_l crosses at least free(ω_l) of medium, [`direct`]),
/// c = ρ_g(cos)·exp(−σ_t·free(ω_l)) bounds ρ_g·T.
/// Below ROULETTE_BOUND·ρ_iso (ρ_iso = 1/4π, the phase function's mean) the ray is cast
/// only with probability c / (ROULETTE_BOUND·ρ_iso) and its result divided by that
/// probability: unbiased, and a surviving ray adds at most ROULETTE_BOUND·ρ_iso·E — a
/// fiftieth of an average unshadowed event — so the added variance is small next to what
/// events near the surface contribute. Including the phase value matters for forward
/// scattering: with g = 0.875 nine in ten directions toward the light have less than the
/// mean phase, and their rays are skipped from shallower depths than the transmittance
/// bound alone would allow. PT (no distance bound, free = 0) skips a ray only when the
/// phase value alone is below the threshold: never for |g| ≤ 0.9, whose smallest HG value
/// (1−|g|)/(4π(1+|g|)²) is above ρ_iso/50.
pub const ROULETTE_BOUND: f32 = 0.02;
/// ROULETTE_BOUND times the isotropic phase function 1/4π (the mean of every phase
/// function over directions): the bound on ρ_g·T below which shadow rays are rouletted.
const ROULETTE_THRESHOLD: f32 = ROULETTE_BOUND / (4.0 * std::f32::consts::PI);

/// Σ over lights of ρ_g(W·ω_l) · T(x → light) · (E, or L/pdf for a sun disk).
///
/// `free(ω_l)` is a lower bound on the length of medium the shadow ray from `x` along
/// ω_l crosses before it can meet the surface (0 if unknown), so T ≤ exp(−σ_t·free),
/// which decides the shadow-ray roulette. Any value keeps the estimate unbiased; a larger
/// true bound skips more rays whose contribution is negligible.
pub fn direct(
    scene: &SceneData,
    x: Vec3,
    w: Vec3,
    free: impl Fn(Vec3) -> f32,
    channel: usize,
    rng: &mut WalkRng,
) -> f32 {
    let sigma = scene.sigma_t[channel];
    let mut sum = 0.0;
    for light in &scene.lights {
        let (wl, factor) = light.sample(uniform(rng), uniform(rng), channel);
        if factor <= 0.0 {
            continue;
        }
        let phase = hg_pdf(scene.g as f64, w.dot(wl).clamp(-1.0, 1.0) as f64) as f32;
        let mut weight = factor * phase;
        let bound = phase * (-sigma * free(wl)).exp();
        if bound < ROULETTE_THRESHOLD {
            if uniform(rng) * ROULETTE_THRESHOLD >= bound {
                continue;
            }
            weight *= ROULETTE_THRESHOLD / bound;
        }
        sum += transmittance(scene, x, wl, channel) * weight;
    }
    sum
}

/// Transmittance from `x` (inside) along `dir` to infinity.
pub fn transmittance(scene: &SceneData, x: Vec3, dir: Vec3, channel: usize) -> f32 {
    let sigma = scene.sigma_t[channel];
    let crossed = scene.geo.inside_length(x, dir, |c, exiting| {
        crossing_transmittance(scene, c, exiting)
    });
    match crossed {
        Some((length, fresnel_t)) => (-sigma * length).exp() * fresnel_t,
        None => transmittance_ordered(scene, x, dir, channel),
    }
}

/// Fresnel transmittance of one boundary crossing of the straight shadow ray (1 for an
/// index-matched boundary); `exiting`: from the medium to the outside.
fn crossing_transmittance(scene: &SceneData, cos: f32, exiting: bool) -> f32 {
    match scene.boundary {
        Boundary::IndexMatched => 1.0,
        Boundary::Dielectric(ior) if exiting => 1.0 - fresnel(cos, ior, 1.0),
        Boundary::Dielectric(ior) => 1.0 - fresnel(cos, 1.0, ior),
    }
}

/// Transmittance by walking the crossings in order (one closest-hit query each): the
/// fallback for rays whose crossings do not pair up, and the reference in tests.
pub fn transmittance_ordered(scene: &SceneData, x: Vec3, dir: Vec3, channel: usize) -> f32 {
    let geo = &scene.geo;
    let sigma = scene.sigma_t[channel];
    let mut o = x;
    let mut inside = true;
    let mut depth = 0.0f32;
    let mut fresnel_t = 1.0f32;
    for _ in 0..MAX_CROSSINGS {
        let Some(h) = geo.intersect(o, dir, f32::INFINITY) else {
            return (-depth).exp() * fresnel_t;
        };
        if inside {
            depth += sigma * h.t;
            if depth > MAX_OPTICAL_DEPTH {
                return 0.0;
            }
        }
        fresnel_t *= crossing_transmittance(scene, dir.dot(h.normal).abs(), inside);
        inside = !inside;
        o = geo.spawn(o + dir * h.t, h.normal, dir);
    }
    0.0
}
