//! Next-event estimation to the directional lights from a point inside the medium.
//!
//! The phase function is evaluated toward the light: cos = W·ω_light with ω_light =
//! −(the direction the light travels). Transmittance sums every inside segment of the
//! shadow ray (non-convex meshes re-enter). With a dielectric boundary the ray refracts
//! where it first leaves the medium (`shadow`) and is multiplied by the Fresnel
//! transmittance at each crossing. The term then takes the camera side's radiance factor
//! 1/ior² ([`crate::setup::Boundary::nee_scale`]).

use glam::Vec3;
use scatter_sim::phase::{hg_pdf, hg_pdf_between};
use scatter_sim::rng::WalkRng;

use super::uniform;
use crate::geometry::Crossed;
use crate::optics::fresnel;
use crate::setup::SceneData;

/// Beyond this optical depth the transmittance (< 2e-22) is taken as 0 (the WGSL kernels
/// get it from here, gpu/kernels.rs).
pub const MAX_OPTICAL_DEPTH: f32 = 50.0;
/// The deepest optical depth [`proxy`] weighs an event by: its exp(−σ_t·free) stays
/// ≥ e^−40 = 4e-18. Under a wide sun disk the disk's centre direction, along which the
/// proxy measures `free`, can cross far more medium than directions near the disk's edge
/// that still light the event; there exp(−σ_t·free) underflowed to 0 in f32 (from an
/// optical depth of ~104, ~87 where a GPU flushes denormals), the event was never offered
/// to the path's NEE reservoirs, and its light was lost. Capped, every event keeps a
/// positive proxy, which is all the reservoirs' unbiasedness needs; an event deeper than
/// this is still offered with ~1e-17 of a surface event's weight.
pub const PROXY_DEPTH_CAP: f32 = 40.0;
/// Most surface crossings followed along one shadow ray by the ordered walk (the WGSL
/// kernels get it from here, gpu/kernels.rs); a ray with more is taken as shadowed. The
/// walk serves the rays whose crossings exceed the sorted list where pieces overlap
/// ([`crate::geometry::MAX_UNION_CROSSINGS`]), so it must follow more than those: at 64,
/// the list's own size, every such ray came out black (two interleaved combs of 20 teeth,
/// `rays_through_more_crossings_than_the_list_holds`: 0 where 0.0745 was due). Walks end
/// sooner at [`MAX_OPTICAL_DEPTH`]; only thin parts in the hundreds reach this.
pub const MAX_CROSSINGS: u32 = 1024;
const _: () = assert!(MAX_CROSSINGS as usize > crate::geometry::MAX_UNION_CROSSINGS);

/// Shadow-ray roulette on a bound of the NEE term: with T ≤ exp(−σ_t·free(ω_l)) (the
/// shadow ray along ω_l crosses at least free(ω_l) of medium, [`direct`]),
/// c = ρ_g(cos)·exp(−σ_t·free(ω_l)) bounds ρ_g·T.
/// Below ROULETTE_BOUND·ρ_iso (ρ_iso = 1/4π, the phase function's mean) the ray is cast
/// only with probability c / (ROULETTE_BOUND·ρ_iso) and its result divided by that
/// probability: unbiased, and a surviving ray adds at most ROULETTE_BOUND·ρ_iso·E — a
/// fiftieth of an average unshadowed event — so the added variance is small next to what
/// events near the surface contribute. (Through a dielectric c is no strict bound: the
/// refracted ray's phase value and length can beat it, `phase_bound`; the roulette stays
/// unbiased.) Including the phase value matters for forward
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
        let Some((wl, factor, phase)) = light_sample(scene, light, w, channel, rng) else {
            continue;
        };
        let mut weight = factor * phase;
        let bound = phase_bound(scene, w, wl, phase) * (-sigma * free(wl)).exp();
        if bound < ROULETTE_THRESHOLD {
            if uniform(rng) * ROULETTE_THRESHOLD >= bound {
                continue;
            }
            weight *= ROULETTE_THRESHOLD / bound;
        }
        sum += shadow(scene, x, w, wl, phase, channel) * weight;
    }
    sum
}

/// The share of the largest turn refraction gives light (`refraction_turn`) over which
/// `phase_bound` takes the phase function's largest value (the WGSL kernels get it from
/// here, gpu/kernels.rs).
///
/// Measured (`stcvae render --variance`, 256 spp, RMS standard error of the image, two
/// seeds; 2026-12-04): the default bunny made dielectric (ior 1.5), ST-CVAE with
/// path-level NEE: 0.090–0.094 in R with no widening, 0.080–0.083 with half the turn,
/// 0.100–0.101 with all of it; a dielectric cube under a sun 60° off its top face's normal
/// (g 0.875): 0.051–0.059, 0.047, 0.056–0.057. All of the turn (48° at ior 1.5, for light
/// grazing the face) makes the path's choice among its events too blind; none lets events
/// whose refracted direction has a large phase value be chosen too rarely.
pub const PHASE_BOUND_TURN: f32 = 0.5;

/// The phase value toward `wl` (`phase`), or for a dielectric boundary the largest over
/// the directions within [`PHASE_BOUND_TURN`] of the turn refraction can give it (toward a
/// face's normal): the bound of the shadow-ray roulette and the path-level proxy, which
/// the refracted direction's phase value ([`shadow`]) should rarely exceed by much.
/// Any positive bound keeps both unbiased.
fn phase_bound(scene: &SceneData, w: Vec3, wl: Vec3, phase: f32) -> f32 {
    match scene.boundary.ior() {
        None => phase,
        Some(ior) => {
            let angle = w.dot(wl).clamp(-1.0, 1.0).acos();
            let turn = PHASE_BOUND_TURN * refraction_turn(ior);
            let nearest = if scene.g >= 0.0 {
                (angle - turn).max(0.0)
            } else {
                (angle + turn).min(std::f32::consts::PI)
            };
            phase.max(hg_pdf(scene.g as f64, nearest.cos() as f64) as f32)
        }
    }
}

/// The most that refraction into a medium of index `ior` turns light: 90° − the critical
/// angle, for light grazing the face (48.2° at ior 1.5).
fn refraction_turn(ior: f32) -> f32 {
    std::f32::consts::FRAC_PI_2 - (1.0 / ior).clamp(0.0, 1.0).asin()
}

/// The shadow ray's transmittance, times the ratio of the phase value toward the
/// direction the light arrives from to `phase` (its value toward `wl`, from an event
/// scattering along `w`).
///
/// Index-matched: the straight ray (ratio 1). Dielectric: light from `wl` refracts at the
/// face where the straight ray first leaves the medium and reaches `x` along the refracted
/// direction d (turned toward the face's normal n: cos θ_t = √(1 − sin²θ_i/ior²)), across
/// that face's plane: the first segment's length s becomes s·r with r = cos θ_i / cos θ_t
/// (the same depth below the plane), the beam's irradiance falls by r (power through an
/// area of the face spreads over cross-sections ∝ cos θ_i outside and cos θ_t inside), and
/// the phase function is read toward d. Exact where a single flat face (every face of a
/// triangle mesh is) admits the light that reaches `x`: near an edge between two lit faces
/// light also comes in through the other one, which this leaves out (as the straight ray
/// did); on a curved surface the face's plane stands for it, which leaves out how the
/// surface focuses the light (a sphere: −0.8 %, `a_sphere_matches_an_independent_walk`).
/// The straight ray (the paper's, until 2026-12-04) read a sun 60° off a flat face 7–12 %
/// too bright. Crossings after the first
/// (re-entries of non-convex meshes) stay straight, with their Fresnel factors; where
/// pieces overlap, the first crossing of the union's boundary refracts. nee.wgsl does the
/// same (`shadow_of`, `refracted_phase_ratio`).
fn shadow(scene: &SceneData, x: Vec3, w: Vec3, wl: Vec3, phase: f32, channel: usize) -> f32 {
    let Some(ior) = scene.boundary.ior() else {
        return transmittance(scene, x, wl, channel);
    };
    let (t, d) = refracted_transmittance(scene, ior, x, wl, channel);
    match d {
        Some(d) if phase > 0.0 => {
            t * hg_pdf_between(scene.g as f64, w.as_dvec3(), d.as_dvec3()) as f32 / phase
        }
        _ => t,
    }
}

/// [`shadow`]'s transmittance (the beam's factor r included) and the refracted
/// direction toward the light (None where the ray stays straight: its first crossing of
/// the boundary is no way out).
fn refracted_transmittance(
    scene: &SceneData,
    ior: f32,
    x: Vec3,
    wl: Vec3,
    channel: usize,
) -> (f32, Option<Vec3>) {
    let geo = &scene.geo;
    let sigma = scene.sigma_t[channel];
    let factor = |c, _| crossing_transmittance(scene, c);
    let crossed = match &geo.pieces {
        Some(pieces) => geo.union_crossed(pieces, x, wl, factor),
        None => Some(geo.crossed(x, wl, factor)).filter(|c| c.paired),
    };
    let Some(Crossed {
        length,
        product,
        first,
        ..
    }) = crossed
    else {
        return ordered(scene, Some(ior), x, wl, channel);
    };
    // The way out's outward normal: where pieces overlap it may cross a face of either
    // orientation (a piece nested in another is a hole).
    let first = first.map(|(t, prim)| {
        let n = geo.normals[prim];
        let flip = geo.pieces.is_some() && wl.dot(n) < 0.0;
        (t, if flip { -n } else { n })
    });
    match first.and_then(|(s, n)| Some((s, refraction(ior, wl, n)?))) {
        Some((s, (r, d))) => {
            let depth = sigma * (length - s * (1.0 - r));
            ((-depth.max(0.0)).exp() * product * r, Some(d))
        }
        None => ((-sigma * length).exp() * product, None),
    }
}

/// The beam's factor r = cos θ_i / cos θ_t and the refracted direction d toward the
/// light for a shadow ray along `wl` leaving through a face of outward normal `n`
/// ([`shadow`]); None where it does not leave through it (an entry: a point outside by
/// rounding).
fn refraction(ior: f32, wl: Vec3, n: Vec3) -> Option<(f32, Vec3)> {
    let cos_i = wl.dot(n);
    if !(cos_i > 0.0) {
        return None;
    }
    let cos_t = (1.0 - (1.0 - cos_i * cos_i).max(0.0) / (ior * ior)).sqrt();
    let d = ((wl - cos_i * n) / ior + cos_t * n).normalize();
    Some((cos_i / cos_t, d))
}

/// A positive proxy of [`direct`]'s value at an event (X, W) whose shadow ray along ω_l
/// crosses at least `free(ω_l)` of medium: Σ_l E_l · ρ_g(W·ω_l) · exp(−min(σ_t·free(ω_l),
/// [`PROXY_DEPTH_CAP`])), the bound its roulette uses up to the cap (with the light's
/// central direction for a sun disk; where
/// the phase lobe is narrower than the disk, with the phase function's largest value over
/// it, [`crate::light::DirectionalLight::extreme_cos`]).
pub fn proxy(scene: &SceneData, w: Vec3, free: impl Fn(Vec3) -> f32, channel: usize) -> f32 {
    let sigma = scene.sigma_t[channel];
    let mut q = 0.0;
    for light in &scene.lights {
        let wl = light.to_light;
        // Where the lobe is narrower than the disk, the phase function's largest value
        // over the disk: its centre's would nearly vanish for an event whose lobe points
        // at the disk's edge, and that event's NEE would come with a huge weight.
        let cos = if light.phase_share(scene.g) > 0.0 {
            light.extreme_cos(w, scene.g)
        } else {
            w.dot(wl).clamp(-1.0, 1.0)
        };
        let phase = phase_bound(scene, w, wl, hg_pdf(scene.g as f64, cos as f64) as f32);
        q += light.irradiance[channel] * phase * (-(sigma * free(wl)).min(PROXY_DEPTH_CAP)).exp();
    }
    q
}

/// [`direct`] without the shadow-ray roulette (the path-level choice has already spent
/// the ray on an event worth it).
fn direct_unrouletted(
    scene: &SceneData,
    x: Vec3,
    w: Vec3,
    channel: usize,
    rng: &mut WalkRng,
) -> f32 {
    let mut sum = 0.0;
    for light in &scene.lights {
        if let Some((wl, factor, phase)) = light_sample(scene, light, w, channel, rng) {
            sum += shadow(scene, x, w, wl, phase, channel) * factor * phase;
        }
    }
    sum
}

/// A direction toward `light`, its factor (see `DirectionalLight::sample`) and the phase
/// value toward it from an event scattering along `w`; None when the light is dark here.
#[inline]
fn light_sample(
    scene: &SceneData,
    light: &crate::light::DirectionalLight,
    w: Vec3,
    channel: usize,
    rng: &mut WalkRng,
) -> Option<(Vec3, f32, f32)> {
    let (u1, u2) = (uniform(rng), uniform(rng));
    let (wl, factor) = light.sample_from(w, scene.g, (u1, u2), || uniform(rng), channel);
    let factor = factor * scene.boundary.nee_scale();
    (factor > 0.0).then(|| {
        let phase = hg_pdf_between(scene.g as f64, w.as_dvec3(), wl.as_dvec3()) as f32;
        (wl, factor, phase)
    })
}

/// Most shadow rays per path with path-level NEE (the scene's limit on
/// `render.path_nee_rays`).
pub const MAX_PATH_NEE_RAYS: usize = crate::scene::MAX_PATH_NEE_RAYS as usize;

/// Path-level NEE (ST-CVAE): instead of a shadow ray at every NEE event (each PT
/// fallback event, each sphere step's representative events), the path offers every
/// event to M weighted reservoirs and casts M shadow rays when it ends.
///
/// An event i whose NEE term is c_i·f_i (c_i: throughput × albedo or Λ(N)/M weights, f_i:
/// [`direct`]'s value) is offered with weight a_i = c_i·q_i, q_i its [`proxy`]; a
/// reservoir holds event K with probability a_K/A (A = Σ a_i) and A·f_K/q_K estimates
/// Σ c_i f_i without bias for any positive proxy. f ≤ q for a delta light where the
/// boundary is index-matched (the proxy's transmittance is a bound), so a chosen event
/// adds at most A; through a dielectric the refracted shadow ray's phase value and length
/// can exceed what the proxy assumed ([`phase_bound`]), so f/q is not bounded there.
///
/// Why it pays for ST-CVAE and not for PT: the proxy's transmittance comes from the
/// free distance an event knows. ST-CVAE's events lie in free balls whose chords bound
/// the way out, so deep events get small proxies and the choice lands near the lit side,
/// where the NEE is; a path of ~10 events casts one ray instead of ~5 at ~9 % more
/// variance. PT's events know no free distance, the proxy is the phase value alone, and
/// one ray chosen among ~100 events multiplied PT's variance by 2.4 (k = 1) to 11 (k = 8)
/// (docs/BENCHMARKS.md, twentieth session).
#[derive(Clone, Copy)]
pub(crate) struct PathNee {
    /// A so far (0: nothing offered).
    total: f32,
    /// (X, W, q) of each reservoir's event.
    slots: [(Vec3, Vec3, f32); MAX_PATH_NEE_RAYS],
}

impl PathNee {
    pub fn new() -> Self {
        Self {
            total: 0.0,
            slots: [(Vec3::ZERO, Vec3::Z, 0.0); MAX_PATH_NEE_RAYS],
        }
    }

    /// Offers event (x, w) with NEE coefficient `c` and proxy `q` to `m` reservoirs.
    #[inline]
    pub fn offer(&mut self, m: usize, (x, w): (Vec3, Vec3), c: f32, q: f32, rng: &mut WalkRng) {
        let a = c * q;
        if !(a > 0.0) {
            return;
        }
        self.total += a;
        for slot in &mut self.slots[..m] {
            if uniform(rng) * self.total < a {
                *slot = (x, w, q);
            }
        }
    }

    /// Casts the `m` reservoirs' shadow rays: the path's NEE.
    pub fn finish(&self, scene: &SceneData, m: usize, channel: usize, rng: &mut WalkRng) -> f32 {
        if !(self.total > 0.0) {
            return 0.0;
        }
        let mut sum = 0.0;
        for &(x, w, q) in &self.slots[..m] {
            sum += direct_unrouletted(scene, x, w, channel, rng) / q;
        }
        sum * self.total / m as f32
    }
}

/// Transmittance from `x` (inside) along `dir` to infinity.
pub fn transmittance(scene: &SceneData, x: Vec3, dir: Vec3, channel: usize) -> f32 {
    let sigma = scene.sigma_t[channel];
    let geo = &scene.geo;
    let factor = |c, _| crossing_transmittance(scene, c);
    let crossed = if let Some(pieces) = &geo.pieces {
        geo.union_inside_length(pieces, x, dir, factor)
    } else {
        geo.inside_length(x, dir, factor)
    };
    match crossed {
        Some((length, fresnel_t)) => (-sigma * length).exp() * fresnel_t,
        None => transmittance_ordered(scene, x, dir, channel),
    }
}

/// Fresnel transmittance of one boundary crossing of the shadow ray (1 for an
/// index-matched boundary). The ray is cast along the light's direction in air, so
/// `cos` is the air-side angle at either crossing, and the transmittance is that of light
/// from air into the medium at it (the same both ways by reciprocity, for the pair of
/// angles refraction joins). Read as the medium-side angle of an exit, as it was until
/// 2026-11-28, it put every light beyond the critical angle (41.8° from the normal at
/// ior 1.5) in total internal reflection: no NEE at all there.
fn crossing_transmittance(scene: &SceneData, cos: f32) -> f32 {
    match scene.boundary.ior() {
        None => 1.0,
        Some(ior) => 1.0 - fresnel(cos, 1.0, ior),
    }
}

/// The transmittance `shadow` reads toward `dir` (refracted where it leaves a dielectric, the
/// beam's factor r included), from the sorted crossings or, with `ordered_walk`, by the
/// ordered walk: the references for nee.wgsl's `shadow` in the kernels' tests.
pub fn transmittance_refracted(
    scene: &SceneData,
    x: Vec3,
    dir: Vec3,
    channel: usize,
    ordered_walk: bool,
) -> f32 {
    match (scene.boundary.ior(), ordered_walk) {
        (ior, true) => ordered(scene, ior, x, dir, channel).0,
        (Some(ior), false) => refracted_transmittance(scene, ior, x, dir, channel).0,
        (None, false) => transmittance(scene, x, dir, channel),
    }
}

/// Transmittance by walking the crossings in order (one closest-hit query each): the
/// fallback for rays whose crossings do not pair up (or, where pieces overlap, that
/// cross more than [`crate::geometry::MAX_UNION_CROSSINGS`] faces), and the reference in
/// tests.
pub fn transmittance_ordered(scene: &SceneData, x: Vec3, dir: Vec3, channel: usize) -> f32 {
    ordered(scene, None, x, dir, channel).0
}

/// The ordered walk, refracted at the first crossing of the boundary if `ior` is given
/// and that crossing is a way out: the optical depth up to it is then multiplied by r
/// and the result by r, and the refracted direction returned ([`shadow`]). Until that
/// crossing the depth is not cut off at
/// [`MAX_OPTICAL_DEPTH`]: refraction can shorten it below.
fn ordered(
    scene: &SceneData,
    ior: Option<f32>,
    x: Vec3,
    dir: Vec3,
    channel: usize,
) -> (f32, Option<Vec3>) {
    let geo = &scene.geo;
    let sigma = scene.sigma_t[channel];
    let mut o = x;
    // Past each crossing the ray is in the medium by turns or, where pieces overlap, as
    // Geometry::in_union says (a closest-hit walk steps past the second of two faces in
    // one plane); Fresnel's factor applies where that changes.
    let in_medium = |o: Vec3, was: bool| match &geo.pieces {
        Some(pieces) => geo.in_union(pieces, o, dir),
        None => !was,
    };
    let mut inside = geo.pieces.is_none() || in_medium(x, false);
    let mut depth = 0.0f32;
    let mut fresnel_t = 1.0f32;
    let mut refracted: Option<Vec3> = None;
    // Whether the boundary has been crossed (refraction happens at the first crossing).
    let mut crossed = ior.is_none();
    for _ in 0..MAX_CROSSINGS {
        let Some(h) = geo.intersect(o, dir, f32::INFINITY) else {
            return ((-depth).exp() * fresnel_t, refracted);
        };
        if inside {
            depth += sigma * h.t;
            if crossed && depth > MAX_OPTICAL_DEPTH {
                return (0.0, refracted);
            }
        }
        o = geo.spawn(o + dir * h.t, h.normal, dir);
        let now = in_medium(o, inside);
        if now != inside {
            fresnel_t *= crossing_transmittance(scene, dir.dot(h.normal).abs());
            if !crossed {
                crossed = true;
                // Where pieces overlap, a way out may cross a face of either orientation
                // (a piece nested in another is a hole).
                let flip = geo.pieces.is_some() && dir.dot(h.normal) < 0.0;
                let n = if flip { -h.normal } else { h.normal };
                if let (true, Some(ior)) = (inside, ior)
                    && let Some((r, d)) = refraction(ior, dir, n)
                {
                    // Everything so far was inside: the first segment's depth.
                    depth *= r;
                    fresnel_t *= r;
                    refracted = Some(d);
                }
                if depth > MAX_OPTICAL_DEPTH {
                    return (0.0, refracted);
                }
            }
            inside = now;
        }
    }
    (0.0, refracted)
}

#[cfg(test)]
mod tests {
    use super::*;
    use scatter_sim::stats::{chi_square, chi_square_p_value};

    /// Each reservoir must hold event i with probability c_i·q_i / Σ c_j·q_j, whatever
    /// the order of the offers, and the two reservoirs independently. For each of three
    /// orders (as listed, reversed, shuffled), 200,000 paths of seven events (one with
    /// weight 0, never to be held) give a chi-square over the six others per reservoir
    /// (5 dof) and over the pairs the two hold (35 dof); p > 10⁻⁴ each (a false alarm
    /// ~9·10⁻⁴ over the nine). Taking an event with probability c/A instead of c·q/A gives
    /// χ² ≈ 10⁴; one that favoured the first or last offer would show in one order.
    #[test]
    fn path_reservoirs_hold_events_in_proportion_to_c_times_q() {
        let cq = [
            (0.5f32, 2.0f32),
            (1.0, 0.1),
            (0.0, 3.0),
            (2.0, 0.4),
            (0.3, 0.3),
            (1.0, 1.0),
            (0.05, 4.0),
        ];
        let a: Vec<f64> = cq.iter().map(|&(c, q)| (c * q) as f64).collect();
        let total: f64 = a.iter().sum();
        let live: Vec<usize> = (0..cq.len()).filter(|&i| a[i] > 0.0).collect();
        for order in [
            [0, 1, 2, 3, 4, 5, 6],
            [6, 5, 4, 3, 2, 1, 0],
            [3, 6, 0, 5, 1, 4, 2],
        ] {
            reservoirs_fit(&cq, &a, total, &live, &order);
        }
    }

    /// One order of offers of [`path_reservoirs_hold_events_in_proportion_to_c_times_q`].
    fn reservoirs_fit(
        cq: &[(f32, f32); 7],
        a: &[f64],
        total: f64,
        live: &[usize],
        order: &[usize; 7],
    ) {
        let mut single = [[0u64; 7]; 2];
        let mut pairs = vec![0u64; 49];
        let n = 200_000u64;
        let mut rng = WalkRng::for_walk(17, order[0] as u64);
        for _ in 0..n {
            let mut r = PathNee::new();
            for &i in order {
                let (c, q) = cq[i];
                r.offer(2, (Vec3::splat(i as f32), Vec3::Z), c, q, &mut rng);
            }
            assert!((r.total as f64 / total - 1.0).abs() < 1e-5);
            let held = r.slots.map(|(x, _, _)| x.x as usize);
            single[0][held[0]] += 1;
            single[1][held[1]] += 1;
            pairs[held[0] * 7 + held[1]] += 1;
        }
        let fits = |what: &str, obs: &[u64], exp: &[f64]| {
            let (chi2, dof) = (chi_square(obs, exp), obs.len() - 1);
            let p = chi_square_p_value(chi2, dof);
            assert!(
                p > 1e-4,
                "{what}, offers in order {order:?}: chi2 {chi2:.1} over {dof} dof (p = {p:.1e})"
            );
        };
        for (k, counts) in single.iter().enumerate() {
            assert_eq!(counts[2], 0, "an event of weight 0 was held");
            let obs: Vec<u64> = live.iter().map(|&i| counts[i]).collect();
            let exp: Vec<f64> = live.iter().map(|&i| n as f64 * a[i] / total).collect();
            fits(&format!("reservoir {k}"), &obs, &exp);
        }
        let (mut obs, mut exp) = (Vec::new(), Vec::new());
        for &i in live {
            for &j in live {
                obs.push(pairs[i * 7 + j]);
                exp.push(n as f64 * a[i] * a[j] / (total * total));
            }
        }
        fits("pairs", &obs, &exp);
    }

    /// The path-level reservoirs are unbiased only where every event that some light can
    /// reach has a positive proxy. Under an 80° disk the proxy's chord is the disk
    /// centre's, which may cross 300 optical depths where the disk's edge crosses almost
    /// none: exp(−300) is 0 in f32, and such events were never offered. Capped at
    /// [`PROXY_DEPTH_CAP`], the proxy stays positive (≥ E·ρ·e^−40) and is unchanged at
    /// depths below the cap.
    #[test]
    fn the_proxy_is_positive_at_any_depth_and_exact_below_the_cap() {
        let f = crate::scene::SceneFile::parse(
            std::path::Path::new("t.toml"),
            "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
             width = 8\nheight = 8\n[object]\nshape = \"sphere\"\nradius = 0.5\n\
             [medium]\nsigma_t = [600.0, 600.0, 600.0]\nalbedo = [0.99, 0.99, 0.99]\ng = 0.5\n\
             [[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\n\
             irradiance = [3.0, 3.0, 3.0]\nangular_diameter_deg = 80.0\n",
        )
        .unwrap();
        let scene = SceneData::build(&f, std::path::Path::new("."), false, &[]).unwrap();
        let w = Vec3::new(1.0, 0.0, 0.0);
        let deep = proxy(&scene, w, |_| 0.5, 0);
        let floor = 3.0 * hg_pdf(0.5, -1.0) as f32 * (-PROXY_DEPTH_CAP).exp();
        assert!(
            deep >= 0.999 * floor && deep > 0.0,
            "σ·free = 300: proxy {deep}"
        );
        // 6 optical depths: the plain bound, E·ρ·e^−6, as before the cap.
        let shallow = proxy(&scene, w, |_| 0.01, 0);
        let plain = proxy(&scene, w, |_| 0.0, 0) * (-6.0f32).exp();
        assert!(
            (shallow / plain - 1.0).abs() < 1e-5,
            "σ·free = 6: {shallow} vs {plain}"
        );
    }

    /// `shadow` through a dielectric against the refraction worked out by hand (angles, not
    /// the vector form `refraction` uses): a point 0.2 under the top face (z = 1) of a glass
    /// cube (ior 1.5, σ_t 1, g 0.5), a sun 60° off the face's normal. Light enters at
    /// θ_i = 60° and runs inside at sin θ_t = sin 60°/1.5 (θ_t = 35.3°), so the value is
    /// the Fresnel transmittance at 60° (s and p written out) · e^(−σ_t·0.2/cos θ_t) · the
    /// beam's cos θ_i/cos θ_t · the phase ratio ρ(W·d)/ρ(W·ω_l), for an event travelling
    /// up (W·ω_l = cos 60°, W·d = cos θ_t). Reading the phase function toward the sun's
    /// direction in air (ratio 1) gives 0.44 for 0.99 here (measured); the paper's straight
    /// ray, e^(−0.4) with neither factor, 0.61 of it. `shadow` works in f32: 1e-4
    /// relative.
    #[test]
    fn a_shadow_ray_through_a_dielectric_refracts_at_the_face() {
        let f = crate::scene::SceneFile::parse(
            std::path::Path::new("t.toml"),
            "[camera]\norigin = [0.0, 0.0, 5.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
             width = 8\nheight = 8\n[object]\nshape = \"cube\"\nsize = 2.0\n\
             [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [0.9, 0.9, 0.9]\ng = 0.5\n\
             [boundary]\nkind = \"dielectric\"\nior = 1.5\n\
             [[light]]\nkind = \"directional\"\ndirection = [0.0, -0.8660254, -0.5]\n\
             irradiance = [1.0, 1.0, 1.0]\n",
        )
        .unwrap();
        let scene = SceneData::build(&f, std::path::Path::new("."), false, &[]).unwrap();
        let (x, w) = (Vec3::new(0.0, 0.0, 0.8), Vec3::Z);
        let wl = Vec3::new(0.0, 0.8660254, 0.5);
        let hg = |c: f64| (1.0 - 0.25) / (4.0 * std::f64::consts::PI * (1.25 - c).powf(1.5));
        let (theta_i, n) = (60f64.to_radians(), 1.5f64);
        let theta_t = (theta_i.sin() / n).asin();
        let (ci, ct) = (theta_i.cos(), theta_t.cos());
        let rs = (ci - n * ct) / (ci + n * ct);
        let rp = (n * ci - ct) / (n * ci + ct);
        let transmitted = 1.0 - 0.5 * (rs * rs + rp * rp);
        let want = transmitted * (-0.2 / ct).exp() * (ci / ct) * hg(ct) / hg(ci);
        let got = f64::from(shadow(&scene, x, w, wl, hg(ci) as f32, 0));
        assert!(
            (got / want - 1.0).abs() < 1e-4,
            "shadow {got}, by hand {want}"
        );
    }

    /// The shadow-ray roulette keeps NEE unbiased where it fires. At the centre of a sphere
    /// (radius 0.5, σ_t 2) with g = 0.97 and a delta light straight behind the direction of
    /// travel, HG's value (1 − g)/(4π(1 + g)²) = 6.15e-4 is below the threshold ρ_iso/50 =
    /// 1.59e-3 (PT passes free = 0, so the phase value alone decides), so each ray is cast
    /// with probability p = 0.387 and weighted 1/p. The mean over 10⁵ draws must be
    /// E·ρ·e^(−σ_t·r) (written out, not through `hg_pdf`); its relative standard error is
    /// √((1 − p)/(p·10⁵)) = 0.40 %, and |z| < 4 is asked. A roulette that dropped its 1/p
    /// would give 0.387 of it (150 SE off); no image test can see this, as the rouletted
    /// rays carry little light in any scene.
    #[test]
    fn the_shadow_ray_roulette_is_unbiased_where_it_fires() {
        let f = crate::scene::SceneFile::parse(
            std::path::Path::new("t.toml"),
            "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
             width = 8\nheight = 8\n[object]\nshape = \"sphere\"\nradius = 0.5\n\
             [medium]\nsigma_t = [2.0, 2.0, 2.0]\nalbedo = [0.5, 0.5, 0.5]\ng = 0.97\n\
             [[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\n\
             irradiance = [3.0, 3.0, 3.0]\n",
        )
        .unwrap();
        let scene = SceneData::build(&f, std::path::Path::new("."), false, &[]).unwrap();
        let g = 0.97f64;
        let rho = (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g).powi(3));
        let p = rho / f64::from(ROULETTE_THRESHOLD);
        assert!((0.3..0.5).contains(&p), "the roulette must fire: p = {p}");
        // The icosphere's radius along +y is 0.5 within 0.03 %.
        let want = 3.0 * rho * (-2.0f64 * 0.5).exp();
        // Travelling down, away from the light above.
        let (x, w) = (Vec3::ZERO, Vec3::NEG_Y);
        let n = 100_000;
        let mut rng = WalkRng::for_walk(23, 0);
        let sum: f64 = (0..n)
            .map(|_| f64::from(direct(&scene, x, w, |_| 0.0, 0, &mut rng)))
            .sum();
        let mean = sum / n as f64;
        let se = want * ((1.0 - p) / (p * n as f64)).sqrt();
        assert!(
            ((mean - want) / se).abs() < 4.0,
            "mean {mean}, want {want} ± {se}"
        );
    }
}
