//! The ST-CVAE sphere step (design §4): at a real collision p, jump over the whole walk
//! inside the largest surface-free sphere around p with one draw from the models.
//!
//! φ^N already contains the albedo of event 1 (the collision at p), so p gets no
//! separate albedo weight and no separate NEE: EventGen's representative event, with
//! weight Λ(N) = Σ_{k=1..N} φ^k, stands for NEE at all N events of the walk.
//!
//! A step that needs the decoders runs in stages (`begin`, then `Pending`'s
//! `after_length`, `after_path` and `finish`), so that [`super::wavefront`] can evaluate
//! the decoder draws of many paths' steps together.

use cvae::decoder::{Draw, Output};
use cvae::features::WalkFeatures;
use cvae::sampler::CENTRE_EVENT;
use cvae::{ModelSet, ModelWalk};
use glam::{DVec3, Vec3};
use scatter_sim::frame::{WalkFrame, from_canonical};
use scatter_sim::rng::WalkRng;

use super::event_choice::{self, Proxy};
use super::walk_lanes::{WalkJob, WalkOutcome, WalkShared};
use super::{IntegratorSettings, PathState, PathStats, pt_event, roulette};
use crate::setup::SceneData;

/// The sphere radius is shrunk by this factor so the exit point stays strictly inside.
pub(crate) const SHRINK: f32 = 1.0 - 1e-4;

/// An exact surface distance is shrunk by this factor (far more than its f32 rounding)
/// before it bounds a sphere.
pub(crate) const EXACT_DISTANCE_SHRINK: f32 = 1.0 - 1e-5;

/// A shadow ray's chord through the free ball is shrunk by this factor, so that the
/// medium it is known to cross stays strictly inside the ball.
pub const BALL_CHORD_SHRINK: f32 = 1.0 - 1e-4;

/// What [`begin`] did.
pub(crate) enum Begun {
    /// A PT event (thin region, or no model or grid).
    Fallback,
    /// A whole sphere step from the exact single-scattering branch (no decoder ran).
    Done,
    /// A sphere step waiting for its LengthGen draw or its walk (in the caller's slot).
    Pending,
}

/// A sphere step between its decoder draws.
pub(crate) struct Pending {
    ball: Ball,
    features: WalkFeatures,
    albedo: f64,
    /// The draw the step waits for: LengthGen's, then PathGen's.
    pub draw: Draw,
    n: u64,
    walk: Option<ModelWalk>,
}

/// A sphere step waiting in its path for the wavefront: for its decoder draws, or for its
/// simulated walk. (Unboxed: each path has one slot, which a box would only move to the
/// heap and back at every step.)
#[allow(clippy::large_enum_variant)]
pub(crate) enum Waiting {
    Model(Pending),
    Exact(ExactStep),
}

/// Starts a step at `s.pos`: a PT fallback event, a finished exact single-scattering step,
/// or a step that needs the decoders or a simulated walk, left in `waiting` (a slot the
/// caller owns, so the step's few hundred bytes are not moved along through the return
/// values).
pub(crate) fn begin(
    scene: &SceneData,
    set: &IntegratorSettings,
    channel: usize,
    s: &mut PathState,
    stats: &mut PathStats,
    rng: &mut WalkRng,
    waiting: &mut Option<Waiting>,
) -> Begun {
    let (Some(model), Some(grid)) = (set.model, scene.grid.as_ref()) else {
        pt_event(scene, set, channel, s, stats, rng);
        return Begun::Fallback;
    };
    let sigma = scene.sigma_t[channel];
    // The path's own bound (s.free: what is left of the last free ball after the flight)
    // is often larger than the grid's near the surface, and costs nothing.
    let grid_free = grid.radius(s.pos);
    let mut free = grid_free.max(s.free);
    // Refined wherever the step below would otherwise fall back: at min_tau = 0 that is a
    // bound of 0, which `σ·free < min_tau` never caught (2.2 fallback events a path on
    // the bunny at ×4 where the exact distance leaves 0.013).
    if free < grid.near_surface && !(free * SHRINK > 0.0 && sigma * free * SHRINK >= set.min_tau) {
        // Near the surface the grid's Lipschitz bound loses up to two cell half-diagonals,
        // which at high density is many mean free paths of PT fallback events. When the
        // grid alone would force a fallback, the exact nearest-triangle distance (about
        // the cost of one ray cast) often still allows a sphere step.
        // The cell's candidate triangles give it directly; elsewhere a BVH search that
        // never looks beyond what the grid says the distance can be at most.
        let exact = grid.exact_distance(&scene.geo, s.pos).unwrap_or_else(|| {
            scene
                .geo
                .distance_within(s.pos, grid.distance_upper_bound(grid_free))
        });
        free = free.max(exact * EXACT_DISTANCE_SHRINK - scene.geo.eps);
    }
    let r = (free * SHRINK).min(set.max_tau / sigma);
    let tau = sigma * r;
    if !(r > 0.0) || tau < set.min_tau {
        s.free = free.max(0.0);
        pt_event(scene, set, channel, s, stats, rng);
        return Begun::Fallback;
    }
    stats.steps += 1;
    let albedo = scene.albedo[channel] as f64;
    if tau < set.exact_tau {
        stats.exact_steps += 1;
        *waiting = Some(Waiting::Exact(ExactStep::new(
            scene,
            set,
            channel,
            s,
            rng,
            (r, free),
        )));
        return Begun::Pending;
    }
    let frame = WalkFrame::new(s.dir.as_dvec3(), rng.unit_circle());
    let features = WalkFeatures::new(tau as f64, scene.g as f64, albedo);
    let single = model.single_walk(features, tau as f64, scene.g as f64, albedo, rng);
    let step = Pending {
        ball: Ball {
            centre: s.pos.as_dvec3(),
            frame,
            r,
            free,
        },
        features,
        albedo,
        draw: Draw::default(),
        n: 1,
        walk: single,
    };
    if single.is_some() {
        step.finish(scene, set, channel, s, &[CENTRE_EVENT], rng);
        return Begun::Done;
    }
    let draw = model.length_draw(&features, rng);
    *waiting = Some(Waiting::Model(Pending { draw, ..step }));
    Begun::Pending
}

impl Pending {
    /// Reads N from LengthGen's output and sets up the PathGen draw.
    pub fn after_length(&mut self, model: &ModelSet, out: &Output, rng: &mut WalkRng) {
        self.n = model.length_result(&self.features, out);
        self.draw = model.path_draw(&self.features, self.features.relative_log_n(self.n), rng);
    }

    /// Reads the exit from PathGen's output; with NEE on, appends the step's representative
    /// events to `events` (None: event 1, the centre, which needs no decoder).
    pub fn after_path(
        &mut self,
        model: &ModelSet,
        set: &IntegratorSettings,
        out: &Output,
        rng: &mut WalkRng,
        events: &mut Vec<Option<Draw>>,
    ) {
        let exit = model.path_result(out);
        let walk = ModelWalk::multiple(self.n, exit, self.features, self.albedo);
        if set.nee {
            // Extra representative events (EventGen draws given the same N and exit), each
            // weighted Λ(N)/M: the same expectation with less variance per sphere step.
            model.event_draws(&walk, set.nee_samples.max(1), rng, events);
        }
        self.walk = Some(walk);
    }

    /// Completes the step given its representative events (canonical frame; none with NEE
    /// off): NEE through them, the survival weight φ^N, roulette, and the jump to the exit.
    pub fn finish(
        &self,
        scene: &SceneData,
        set: &IntegratorSettings,
        channel: usize,
        s: &mut PathState,
        events: &[(DVec3, DVec3)],
        rng: &mut WalkRng,
    ) {
        let walk = self.walk.as_ref().expect("finish after the walk is drawn");
        // Each representative event stands for all N events with weight Λ(N).
        let nee = Nee {
            scale: walk.lambda as f32 / events.len().max(1) as f32,
            events,
            weights: None,
        };
        let walked = Walked {
            ball: &self.ball,
            nee,
            survival: walk.survival as f32,
            exit: from_canonical(walk.exit),
        };
        complete(scene, set, channel, s, walked, rng);
    }
}

/// Where a sphere step happens: the ball of radius `r` around `centre` that the walk
/// fills (its frame turns the walk's +z arrival into the path's direction), inside the
/// surface-free ball of radius `free`.
struct Ball {
    centre: DVec3,
    frame: WalkFrame,
    r: f32,
    /// The free radius around the centre (≥ r).
    free: f32,
}

/// A sphere step whose walk is simulated event by event instead of drawn from the models
/// (below `exact_tau`, where a walk has at most a few dozen events): inside the free ball a
/// free flight needs no ray cast, so the walk costs a few ns an event in
/// [`super::walk_lanes`]' SIMD lanes, less than the decoders' draws for a small ball, and its
/// exit is exact — the models' error is largest relative to the NEE where small balls
/// touch a lit surface. The step waits in its path until the wavefront simulates the
/// walks of many paths' steps together.
///
/// NEE: the step's term Σ_k φ^k f(X_k, W_k) over all N events is estimated from M events
/// each chosen with probability p_k = φ^k q_k / Q (Q = Σ_j φ^j q_j, one weighted reservoir
/// per event slot), as f(X_K) · Q / q_K. The proxy q_k bounds f apart from the shadow
/// ray's surfaces: the phase value toward each light times the transmittance across the
/// free ball's chord from X_k toward it, times the light's irradiance. Any positive q
/// keeps the estimate unbiased; this one picks the events near the ball's lit side, where
/// almost all of the NEE is, instead of events uniformly along the walk (the models'
/// Λ(N)-weighted representative event), and leaves f/q ≤ 1 for a delta light.
pub(crate) struct ExactStep {
    ball: Ball,
    pub job: WalkJob,
}

/// What all exact steps' walks of a render share (see [`WalkShared`]).
pub(crate) fn exact_shared(scene: &SceneData, set: &IntegratorSettings) -> WalkShared {
    let m = if set.nee && !scene.lights.is_empty() {
        (set.exact_nee_samples as usize).clamp(1, MAX_EXACT_EVENTS)
    } else {
        0
    };
    WalkShared {
        g: scene.g,
        m,
        n_lights: scene.lights.len().min(event_choice::MAX_PROXY_LIGHTS),
    }
}

impl ExactStep {
    fn new(
        scene: &SceneData,
        set: &IntegratorSettings,
        channel: usize,
        s: &PathState,
        rng: &mut WalkRng,
        (r, free): (f32, f32),
    ) -> Self {
        let tau = scene.sigma_t[channel] * r;
        // The simulated walk is already uniform in its azimuth about +z, so any frame
        // about the arriving direction will do.
        let frame = WalkFrame::new(s.dir.as_dvec3(), (1.0, 0.0));
        let m = exact_shared(scene, set).m;
        // The lights in the walk's frame, with their irradiance in this channel (none
        // when no event is chosen, which spares their transforms).
        let lights = scene.lights.iter().take(if m > 0 { usize::MAX } else { 0 });
        let proxy = Proxy::new(
            lights.map(|l| {
                let wl = frame.to_canonical(l.to_light.as_dvec3()).as_vec3();
                (wl, l.irradiance[channel])
            }),
            tau,
            (free / r).powi(2),
            scene.g,
        );
        Self {
            ball: Ball {
                centre: s.pos.as_dvec3(),
                frame,
                r,
                free,
            },
            job: WalkJob {
                tau,
                albedo: scene.albedo[channel],
                seed: rng.next_u64(),
                proxy,
            },
        }
    }

    /// Completes the step from its simulated walk.
    pub fn finish(
        &self,
        scene: &SceneData,
        set: &IntegratorSettings,
        channel: usize,
        s: &mut PathState,
        walk: &WalkOutcome,
        rng: &mut WalkRng,
    ) {
        let m = exact_shared(scene, set).m;
        let albedo = scene.albedo[channel] as f64;
        let survival = albedo.powi(walk.n.min(i32::MAX as u32) as i32);
        // Each reservoir's estimate of the walk's NEE is f(X_K)·Q/q_K; two holding the
        // same event share one entry with their weights summed (the estimate is linear in
        // each event's NEE, so one shadow ray serves both).
        let mut events = [CENTRE_EVENT; MAX_EXACT_EVENTS];
        let mut weights = [0.0f32; MAX_EXACT_EVENTS];
        let mut used = 0;
        for &(x, w, q) in &walk.slots[..m] {
            if !(q > 0.0) {
                continue;
            }
            let weight = walk.total / q;
            let (x, w) = (x.as_dvec3(), w.as_dvec3());
            match events[..used].iter().position(|e| *e == (x, w)) {
                Some(i) => weights[i] += weight,
                None => {
                    (events[used], weights[used]) = ((x, w), weight);
                    used += 1;
                }
            }
        }
        let nee = Nee {
            scale: 1.0 / m.max(1) as f32,
            events: &events[..used],
            weights: Some(&weights[..used]),
        };
        let walked = Walked {
            ball: &self.ball,
            nee,
            survival: survival as f32,
            exit: (walk.exit_pos.as_dvec3(), walk.exit_dir.as_dvec3()),
        };
        complete(scene, set, channel, s, walked, rng);
    }
}

/// The distance from `x` (inside the sphere of radius² `r2` about the origin) along unit
/// `dir` to that sphere.
#[inline]
fn chord_to_sphere(x: Vec3, dir: Vec3, r2: f32) -> f32 {
    let b = x.dot(dir);
    -b + (b * b + (r2 - x.length_squared()).max(0.0)).sqrt()
}

/// Most representative events of an exact step.
const MAX_EXACT_EVENTS: usize = event_choice::MAX_EVENTS;

/// A step's NEE: events (X, W) in the walk's frame; `scale` · Σ weight·f(X, W) (weights 1
/// when None) estimates the NEE of all the walk's events.
struct Nee<'a> {
    scale: f32,
    events: &'a [(DVec3, DVec3)],
    weights: Option<&'a [f32]>,
}

/// A sphere step's walk, drawn or simulated: where it happened, its NEE events, its
/// survival weight φ^N and its exit (x, ω) (in the walk's frame, arrival along +z, unit
/// sphere; no events with NEE off).
struct Walked<'a> {
    ball: &'a Ball,
    nee: Nee<'a>,
    survival: f32,
    exit: (DVec3, DVec3),
}

/// Completes a sphere step: NEE through its events, the survival weight, roulette, and the
/// jump to the exit.
fn complete(
    scene: &SceneData,
    set: &IntegratorSettings,
    channel: usize,
    s: &mut PathState,
    walked: Walked,
    rng: &mut WalkRng,
) {
    let Walked {
        ball,
        nee,
        survival,
        exit: (x, omega),
    } = walked;
    let grid = scene.grid.as_ref().expect("a sphere step has a grid");
    let r = ball.r;
    let centre = ball.centre;
    if set.nee && !nee.events.is_empty() {
        let m = set.path_nee();
        for (i, &(ep, ed)) in nee.events.iter().enumerate() {
            let weight = nee.weights.map_or(1.0, |w| w[i]);
            let x = centre + ball.frame.to_world(ep) * r as f64;
            let w = ball.frame.to_world(ed).normalize();
            // Two bounds on the medium a shadow ray from X crosses before any surface,
            // for the shadow-ray roulette: along ω_l it first crosses the free ball
            // around the centre (radius `free`; X is inside it, as |ep| ≤ 1 for a
            // repaired event and r < free), its chord from X being between
            // free − |X − c| and free + |X − c|; and the grid's ball around X (one
            // lookup, against a shadow ray's two traversals), often the larger for
            // events near the sphere's edge.
            let d = (x - centre).as_vec3();
            let x = x.as_vec3();
            let x_grid = grid.radius(x);
            let free_ball = ball.free;
            let x_free = |wl: Vec3| {
                let chord = chord_to_sphere(d, wl, free_ball * free_ball);
                (chord * BALL_CHORD_SHRINK).min(2.0 * free_ball).max(x_grid)
            };
            let c = s.beta * nee.scale * weight;
            s.add_nee(scene, m, (x, w.as_vec3()), c, x_free, channel, rng);
        }
    }
    s.beta *= survival;
    if !roulette(&mut s.beta, rng) {
        s.alive = false;
        return;
    }
    let exit: DVec3 = centre + ball.frame.to_world(x) * r as f64;
    s.pos = exit.as_vec3();
    s.dir = ball.frame.to_world(omega).as_vec3().normalize();
    s.scattered = true;
    // The exit lies on the sphere of radius r inside the free ball of radius `free`,
    // which leaves it almost no known free distance; the grid at the exit often knows
    // more, and a flight shorter than that needs no ray cast. The wavefront completes
    // many paths' steps before it moves any of them on, so the cell is fetched now and
    // read when the path flies on.
    s.free = ball.free - r;
    grid.prefetch(s.pos);
    s.grid_pending = true;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::IntegratorKind;
    use crate::scene::SceneFile;

    /// A sphere (radius 0.5, σ_t 2, 4, 8, g 0.5) under one delta light whose irradiance
    /// differs by channel.
    fn lit_sphere() -> SceneData {
        let f = SceneFile::parse(
            std::path::Path::new("t.toml"),
            "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
             width = 8\nheight = 8\n[object]\nshape = \"sphere\"\nradius = 0.5\n\
             [medium]\nsigma_t = [2.0, 4.0, 8.0]\nalbedo = [0.9, 0.9, 0.9]\ng = 0.5\n\
             [[light]]\nkind = \"directional\"\ndirection = [0.3, -0.8, 0.5]\n\
             irradiance = [1.0, 2.5, 0.5]\n",
        )
        .unwrap();
        SceneData::build(&f, std::path::Path::new("."), false, &[]).unwrap()
    }

    /// An exact step's walk sees its NEE proxy over the free ball it stands in, not over
    /// its own sphere: a step of radius r = 0.1 whose free ball is 0.25 (r capped below the
    /// free radius, as by `max_tau` under `exact_tau`) must hand the lanes f² = (free/r)² =
    /// 6.25 in units of its sphere, τ = σ_t·r of its channel, and the light in the walk's
    /// frame (canonical z along the arriving direction) with its irradiance in that
    /// channel. f² taken as (r/free)² is clamped to 1: the proxy's chords stop at the
    /// walk's sphere, which still bounds the NEE (so the estimate stays unbiased and every
    /// image test passes) but weighs the events' depth in the ball wrongly. No image test
    /// has a step capped below its free radius with a light: the exact tests' balls stay
    /// under max_tau 49 (σ_t·0.5 ≤ 40), and the half-space, where they reach it, is lit by
    /// its sky alone. Values to f32 rounding (10⁻⁵ relative; 10⁻⁶ for the unit direction).
    #[test]
    fn an_exact_steps_proxy_spans_its_free_ball() {
        let scene = lit_sphere();
        let set = IntegratorSettings {
            kind: IntegratorKind::Stcvae,
            nee: true,
            model: None,
            min_tau: 0.0,
            max_tau: 49.0,
            exact_tau: 50.0,
            nee_samples: 1,
            exact_nee_samples: 2,
            path_nee_rays: 1,
        };
        let channel = 1;
        let dir = Vec3::new(0.3, -0.5, 0.8).normalize();
        let path = crate::integrator::Path::new(
            Vec3::new(0.05, -0.02, 0.1),
            dir,
            channel,
            WalkRng::from_seed(3),
        );
        let mut rng = WalkRng::from_seed(4);
        let (r, free) = (0.1f32, 0.25f32);
        let step = ExactStep::new(&scene, &set, channel, &path.s, &mut rng, (r, free));
        let p = &step.job.proxy;
        assert!(!p.flat, "one lit light: no flat proxy");
        assert!(
            (p.f2 / 6.25 - 1.0).abs() < 1e-5,
            "the free ball's radius² in units of the walk's sphere: {} for 6.25",
            p.f2
        );
        let tau = scene.sigma_t[channel] * r;
        assert!(
            (step.job.tau / tau - 1.0).abs() < 1e-5
                && (p.tau_log2e / (tau * std::f32::consts::LOG2_E) - 1.0).abs() < 1e-5,
            "τ {} and τ·log₂e {} for τ = {tau}",
            step.job.tau,
            p.tau_log2e
        );
        // The light's direction in the walk's frame: its components along the frame's
        // axes (the third the arriving direction), written out as dot products.
        let light = &scene.lights[0];
        let l = light.to_light.as_dvec3();
        let b = step.ball.frame.basis;
        assert!((b.z_axis - dir.as_dvec3()).length() < 1e-6);
        let want = DVec3::new(b.x_axis.dot(l), b.y_axis.dot(l), b.z_axis.dot(l));
        let (wl, e) = p.lights[0];
        assert!(
            (wl.as_dvec3() - want).length() < 1e-6,
            "the light at {wl} in the walk's frame, {want} expected"
        );
        assert!(light.irradiance[channel] != light.irradiance[0]);
        assert_eq!(e, light.irradiance[channel], "the channel's irradiance");
    }
}
