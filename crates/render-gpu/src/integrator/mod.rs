//! The CPU integrators: one path loop shared by volumetric PT and ST-CVAE; they differ
//! only in what happens at a real scattering point (`pt_event` or a sphere step,
//! `sphere_step::begin`).
//!
//! Each path traces one colour channel (the hero channel, chosen per sample and
//! stratified over a pixel's samples) and its estimate is added, times 3, to that channel;
//! `render::resolve_pixel` turns the sums into each channel's mean over its own samples.

pub(crate) mod event_choice;
pub mod nee;
pub mod sphere_step;
mod walk_lanes;
pub mod wavefront;

use glam::Vec3;
use scatter_sim::phase::hg_sample_direction;
use scatter_sim::rng::WalkRng;

use crate::geometry::{Hit, SKIP_BACK, SKIP_CLEAR_OF_EPS};
use crate::optics::{fresnel, reflect, refract};
use crate::setup::SceneData;

pub use crate::scene::IntegratorKind;

/// Per-path counters, summed over a render.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PathStats {
    pub paths: u64,
    /// Ordinary PT scattering events (ST-CVAE: the thin-region fallbacks).
    pub events: u64,
    /// ST-CVAE sphere steps.
    pub steps: u64,
    /// Of those, the steps whose walk was simulated exactly (below `exact_tau`).
    #[serde(default)]
    pub exact_steps: u64,
    /// The scattering events simulated inside those walks (each walk's N): the work an
    /// exact step hides, which `events` and `steps` do not show.
    #[serde(default)]
    pub exact_events: u64,
    /// Paths found outside the medium while believed inside: a flight from a sphere-step
    /// exit that met the surface from outside (the exit was not inside after all), or a
    /// collision outside the mesh's bounds. Should stay 0.
    pub leaks: u64,
    /// Paths stopped by the safety cap on loop iterations (should stay 0).
    pub capped: u64,
    /// Non-finite path estimates replaced by 0 (should stay 0).
    pub non_finite: u64,
}

impl PathStats {
    pub fn add(&mut self, o: &PathStats) {
        self.paths += o.paths;
        self.events += o.events;
        self.steps += o.steps;
        self.exact_steps += o.exact_steps;
        self.exact_events += o.exact_events;
        self.leaks += o.leaks;
        self.capped += o.capped;
        self.non_finite += o.non_finite;
    }
}

/// What the integrator needs beyond the scene.
#[derive(Clone, Copy)]
pub struct IntegratorSettings<'a> {
    pub kind: IntegratorKind,
    pub nee: bool,
    pub model: Option<&'a cvae::ModelSet>,
    /// Thin-region fallback threshold on σ_t·r.
    pub min_tau: f32,
    /// Largest σ_t·r of a sphere step.
    pub max_tau: f32,
    /// Below this σ_t·r a sphere step simulates its walk instead of drawing it from the
    /// models (0: always the models).
    pub exact_tau: f32,
    /// Representative events (EventGen draws) per model-drawn sphere step for NEE.
    pub nee_samples: u32,
    /// NEE events per exactly simulated sphere step (1..=`MAX_EXACT_NEE_SAMPLES`).
    pub exact_nee_samples: u32,
    /// ST-CVAE's shadow rays per path (`nee::PathNee`); 0: one at every NEE event.
    pub path_nee_rays: u32,
}

impl IntegratorSettings<'_> {
    /// The reservoirs of path-level NEE: `path_nee_rays` for ST-CVAE with NEE, else 0
    /// (PT always casts a shadow ray at every event; see `nee::PathNee`).
    #[inline]
    pub fn path_nee(&self) -> usize {
        if self.nee && self.kind == IntegratorKind::Stcvae {
            (self.path_nee_rays as usize).min(nee::MAX_PATH_NEE_RAYS)
        } else {
            0
        }
    }
}

/// Safety cap on loop iterations of one path; far beyond any physical path here.
pub(crate) const MAX_ITERATIONS: u64 = 50_000_000;
/// Russian roulette starts below this throughput; survivors are raised back to it.
pub(crate) const RR_THRESHOLD: f32 = 0.25;

/// Uniform in [0, 1) with 24 random bits, as the kernels' `rand()`: an f64 uniform cast
/// to f32 rounds to exactly 1.0 about once in 2^25 draws, which sent a totally reflected
/// path through the boundary (`u < F` false with F = 1) and made a flight infinite.
#[inline]
pub(crate) fn uniform(rng: &mut WalkRng) -> f32 {
    (rng.next_u64() >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// Unbiased Russian roulette; false when the path is terminated.
#[inline]
pub(crate) fn roulette(beta: &mut f32, rng: &mut WalkRng) -> bool {
    if *beta >= RR_THRESHOLD {
        return true;
    }
    if *beta <= 0.0 {
        return false;
    }
    if uniform(rng) * RR_THRESHOLD < *beta {
        *beta = RR_THRESHOLD;
        true
    } else {
        false
    }
}

/// A closest-hit cast of a short segment from a point near the surface: against the grid
/// cell's candidate list where ST-CVAE's grid has one that covers the segment
/// (`DistanceGrid::local_hit`, the same hit), else through the BVH. PT renders have no
/// grid, as standard volumetric path tracers have none.
#[inline]
fn short_cast(scene: &SceneData, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
    let geo = &scene.geo;
    scene
        .grid
        .as_ref()
        .and_then(|g| g.local_hit(geo, origin, dir, tmax))
        .unwrap_or_else(|| geo.intersect(origin, dir, tmax))
}

/// State carried along a path.
pub(crate) struct PathState {
    pub pos: Vec3,
    pub dir: Vec3,
    pub beta: f32,
    pub radiance: f32,
    /// Whether the path has scattered (or sphere-stepped) since the camera or its last
    /// reflection off the boundary: with NEE on, such a path must not also collect the sun
    /// disk when it escapes, as NEE counted that light (its shadow ray crosses the
    /// boundary straight, transmitted). After a reflection it must: NEE never samples
    /// light that reaches an event by way of a reflection (a prism's total internal
    /// reflection lost 41 % of its image with NEE on; `nee_counts_light_after_a_reflection`).
    pub scattered: bool,
    pub alive: bool,
    /// A lower bound on the distance from `pos` to the surface (0: unknown). ST-CVAE
    /// knows it from its free spheres; a free flight shorter than it cannot reach the
    /// surface, so it needs no ray cast. PT never sets it.
    pub free: f32,
    /// Medium the path passed when it was last spawned inside
    /// ([`Geometry::spawn_skip`](crate::geometry::Geometry::spawn_skip)), taken off its next
    /// flight, which is so measured from the surface (a collision drawn within it is moved back
    /// to its own depth). Spawned eps deep and flying from there, every entering path passed
    /// σ_t·eps of optical depth unattenuated: images came out 1 % dark at σ_t 3,000 on a sphere
    /// of size 1 and black at 10⁶, PT and ST-CVAE alike.
    pub skip: f32,
    /// `free` may grow by the grid's radius at `pos`, which is not looked up yet (it was
    /// prefetched; see `sphere_step::complete`).
    pub grid_pending: bool,
    /// The path's NEE events so far, with path-level NEE.
    pub nee: nee::PathNee,
}

impl PathState {
    /// The NEE of one event (x, w) whose term is c·f (f: [`nee::direct`]'s value, `free`
    /// its bound on the medium toward each light): offered to the path's `m` reservoirs
    /// with path-level NEE, else a shadow ray now.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn add_nee(
        &mut self,
        scene: &SceneData,
        m: usize,
        (x, w): (Vec3, Vec3),
        c: f32,
        free: impl Fn(Vec3) -> f32,
        channel: usize,
        rng: &mut WalkRng,
    ) {
        if m > 0 {
            let q = nee::proxy(scene, w, free, channel);
            self.nee.offer(m, (x, w), c, q, rng);
        } else {
            self.radiance += c * nee::direct(scene, x, w, free, channel, rng);
        }
    }
}

/// An ordinary PT scattering event at `s.pos` (a real collision).
pub(crate) fn pt_event(
    scene: &SceneData,
    set: &IntegratorSettings,
    channel: usize,
    s: &mut PathState,
    stats: &mut PathStats,
    rng: &mut WalkRng,
) {
    stats.events += 1;
    let albedo = scene.albedo[channel];
    if set.nee {
        let (event, c, free) = ((s.pos, s.dir), s.beta * albedo, s.free);
        s.add_nee(scene, set.path_nee(), event, c, |_| free, channel, rng);
    }
    s.beta *= albedo;
    if !roulette(&mut s.beta, rng) {
        s.alive = false;
        return;
    }
    let d = hg_sample_direction(scene.g as f64, s.dir.as_dvec3(), rng);
    s.dir = d.as_vec3().normalize();
    s.scattered = true;
}

/// Radiance arriving along an escaping direction.
fn escape(scene: &SceneData, dir: Vec3, channel: usize, with_sun: bool) -> f32 {
    let mut l = scene.env.lookup(dir, channel);
    if with_sun {
        for light in &scene.lights {
            l += light.radiance_toward(dir, channel);
        }
    }
    l
}

/// Traces one camera path in `channel` and returns its radiance estimate for that channel.
/// (The renderer traces many paths together with [`wavefront::trace_many`]; this is the
/// same path, its sphere steps' decoder draws evaluated one at a time.)
pub fn trace(
    scene: &SceneData,
    set: &IntegratorSettings,
    origin: Vec3,
    dir: Vec3,
    channel: usize,
    stats: &mut PathStats,
    rng: &mut WalkRng,
) -> f32 {
    let path = Path::new(origin, dir, channel, rng.clone());
    let (radiance, path) = wavefront::trace_alone(scene, set, path);
    *rng = path.rng;
    stats.add(&path.stats);
    radiance
}

/// A camera path and everything its loop carries, so that the loop can stop where a
/// sphere step needs the decoders and resume once they have run.
pub(crate) struct Path {
    pub s: PathState,
    pub channel: usize,
    pub rng: WalkRng,
    pub stats: PathStats,
    inside: bool,
    /// True right after a sphere step: the next flight starts at a model-made exit point.
    from_step: bool,
    /// The triangle the path has just left the surface through (outward), if it has: a
    /// direction in that triangle's escape cone escapes without a ray cast.
    left_through: Option<u32>,
    /// The result of the path's first cast (from the camera), when it was cast for several
    /// paths at once.
    pub first_hit: Option<Option<Hit>>,
    iterations: u64,
    /// The sphere step waiting for its decoder draws or its walk, after [`Advance::Step`].
    pub step: Option<sphere_step::Waiting>,
}

/// Where [`Path::advance`] stopped.
pub(crate) enum Advance {
    /// The path has ended with this radiance estimate.
    Done(f32),
    /// A sphere step waits for its decoder draws or its exact walk (in [`Path::step`]).
    Step,
    /// A stop request came while the path went on: it is abandoned.
    Stopped,
}

/// Iterations of one path between looks at the stop request: a path can run to
/// [`MAX_ITERATIONS`] (a huge optically thick object: 23 s for one PT path, which kept
/// SIGTERM waiting), and 65,536 of them take some tens of milliseconds.
const STOP_CHECK_EVERY: u64 = 1 << 16;

/// A stop request that never comes, for paths traced outside a render.
pub(crate) static NEVER: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

impl Path {
    pub fn new(origin: Vec3, dir: Vec3, channel: usize, rng: WalkRng) -> Self {
        Self {
            s: PathState {
                pos: origin,
                dir,
                beta: 1.0,
                radiance: 0.0,
                scattered: false,
                alive: true,
                free: 0.0,
                skip: 0.0,
                grid_pending: false,
                nee: nee::PathNee::new(),
            },
            channel,
            rng,
            stats: PathStats {
                paths: 1,
                ..PathStats::default()
            },
            inside: false,
            from_step: false,
            left_through: None,
            first_hit: None,
            iterations: 0,
            step: None,
        }
    }

    /// Follows the path until it ends or a sphere step needs the decoders (then finish
    /// that step and call this again), or `stop` is set ([`STOP_CHECK_EVERY`]).
    pub fn advance(
        &mut self,
        scene: &SceneData,
        set: &IntegratorSettings,
        stop: &std::sync::atomic::AtomicBool,
    ) -> Advance {
        while self.s.alive {
            self.iterations += 1;
            if self.iterations > MAX_ITERATIONS {
                self.stats.capped += 1;
                break;
            }
            if self.iterations.is_multiple_of(STOP_CHECK_EVERY)
                && stop.load(std::sync::atomic::Ordering::Relaxed)
            {
                return Advance::Stopped;
            }
            if !self.inside {
                if self.cast_from_air(scene, set) {
                    break;
                }
                continue;
            }
            let (hit, t) = self.flight(scene);
            if let Some(h) = hit {
                self.reach_face(scene, h);
                continue;
            }
            let geo = &scene.geo;
            let channel = self.channel;
            let Self {
                s,
                rng,
                stats,
                inside,
                from_step,
                step,
                ..
            } = self;
            s.pos += s.dir * t;
            s.free = (s.free - t).max(0.0);
            if !geo.within_bounds(s.pos) {
                // A collision outside the mesh's bounding box cannot be inside (a safety net:
                // with `flight`'s margin none has been seen). A path left believing
                // itself inside would scatter through the air for ~1/(1 − φ) events (10⁴–10⁵)
                // with unshadowed NEE — radiance estimates in the thousands.
                stats.leaks += 1;
                *inside = false;
                s.free = 0.0;
                *from_step = false;
                continue;
            }
            match set.kind {
                IntegratorKind::Pt => {
                    pt_event(scene, set, channel, s, stats, rng);
                    *from_step = false;
                }
                IntegratorKind::Stcvae => {
                    match sphere_step::begin(scene, set, channel, s, stats, rng, step) {
                        sphere_step::Begun::Fallback => *from_step = false,
                        sphere_step::Begun::Done => *from_step = true,
                        sphere_step::Begun::Pending => {
                            *from_step = true;
                            return Advance::Step;
                        }
                    }
                }
            }
        }
        let m = set.path_nee();
        let s = &mut self.s;
        if m > 0 {
            s.radiance += s.nee.finish(scene, m, self.channel, &mut self.rng);
        }
        Advance::Done(if s.radiance.is_finite() {
            s.radiance
        } else {
            self.stats.non_finite += 1;
            0.0
        })
    }

    /// Casts from the air: the path escapes (true: it has ended), passes a face inside a
    /// cavity, or meets the medium's boundary and enters or is reflected.
    #[inline]
    fn cast_from_air(&mut self, scene: &SceneData, set: &IntegratorSettings) -> bool {
        let geo = &scene.geo;
        let channel = self.channel;
        let Self {
            s,
            rng,
            inside,
            left_through,
            first_hit,
            ..
        } = self;
        let hit = match (first_hit.take(), left_through.take()) {
            (Some(hit), _) => hit,
            (None, Some(prim)) if geo.escapes_from(prim, s.dir) => None,
            _ => geo.intersect(s.pos, s.dir, f32::INFINITY),
        };
        let Some(mut h) = hit else {
            s.radiance += s.beta * escape(scene, s.dir, channel, !(set.nee && s.scattered));
            return true;
        };
        let mut turned = false;
        if let Some(pieces) = &geo.pieces {
            let past = geo.spawn(s.pos + s.dir * h.t, h.normal, s.dir);
            if !geo.in_union(pieces, past, s.dir) {
                // A face crossed in air (within a cavity's piece): no boundary.
                s.pos = past;
                return false;
            }
            // Into the medium: its boundary's normal faces the air the path is in.
            if s.dir.dot(h.normal) > 0.0 {
                h.normal = -h.normal;
                turned = true;
            }
        }
        if s.dir.dot(h.normal) > 0.0 {
            // Met a surface from inside while believed outside: the path left one
            // part of the mesh into another across a gap of air thinner than eps
            // (touching parts), and was spawned inside that one. It enters where
            // it is, in its direction, as through a gap of no thickness (with a
            // dielectric boundary the refraction out of the first part stays).
            // Taken for an entry at the far face instead, the path would be
            // spawned outside believing itself inside: air events with unshadowed
            // NEE, as at a sliver.
            *inside = true;
            return false;
        }
        let p = s.pos + s.dir * h.t;
        let incoming = s.dir;
        match scene.boundary.ior() {
            None => *inside = true,
            Some(ior) => {
                let f = fresnel(s.dir.dot(h.normal).abs(), 1.0, ior);
                if uniform(rng) < f {
                    s.dir = reflect(s.dir, h.normal);
                    // Light the path meets from here on is not NEE's
                    // (`PathState::scattered`).
                    s.scattered = false;
                    // (A turned normal is not the one the triangle's escape
                    // cone is about.)
                    *left_through = (!turned).then_some(h.prim);
                } else {
                    s.dir = refract(s.dir, h.normal, 1.0, ior).unwrap_or(s.dir);
                    *inside = true;
                }
            }
        }
        s.pos = geo.spawn(p, h.normal, s.dir);
        if *inside && geo.beyond_sliver(s.pos, h.normal, |o, d, t| short_cast(scene, o, d, t)) {
            // The medium under the entry is thinner than the spawn offset: pass it,
            // in (as through a slab of no thickness) the direction the path came.
            *inside = false;
            s.dir = incoming;
        }
        if *inside {
            s.skip = geo.spawn_skip(h.normal, s.dir);
        }
        false
    }

    /// Draws a free flight inside the medium and casts it where it may reach the surface:
    /// the face it meets first, if any, and the flight's length.
    #[inline]
    fn flight(&mut self, scene: &SceneData) -> (Option<Hit>, f32) {
        let geo = &scene.geo;
        let sigma = scene.sigma_t[self.channel];
        let Self { s, rng, .. } = self;
        if s.grid_pending {
            s.grid_pending = false;
            if let Some(grid) = &scene.grid {
                s.free = s.free.max(grid.radius(s.pos));
            }
        }
        let drawn = -(1.0 - uniform(rng)).ln() / sigma;
        if drawn < s.skip {
            // A collision within the way the spawn passed happens at its own depth:
            // back along the path from the spawn point, but at least a fiftieth of the
            // way deep, clear of the face just crossed (SKIP_BACK; placed at the spawn
            // point, such collisions lay too deep: 1.4 % dark at σ_t·eps = 0.4). Not
            // across another face: the way back also runs sideways (to 18 eps at
            // grazing entry) and near a convex edge it left the medium (36 % of the
            // paths entering a cube's top face at |cos| = 0.05 by its edge leaked);
            // there the collision stays at the spawn point. (The face must be clear by
            // SKIP_CLEAR_OF_EPS, less than the floor, so the cast never meets the face
            // the path came through.)
            let back = (s.skip - drawn).min(SKIP_BACK * s.skip);
            if geo
                .intersect(s.pos, -s.dir, back + SKIP_CLEAR_OF_EPS * geo.eps)
                .is_none()
            {
                s.pos -= s.dir * back;
            }
        }
        let t = (drawn - s.skip).max(0.0);
        s.skip = 0.0;
        let hit = if t < s.free {
            None
        } else {
            // The cast looks `geo.flight_margin()` beyond the collision: pos + t·dir is rounded,
            // and a collision that rounds to the far side of a surface the ray test puts
            // just beyond t would leave the path outside while it believes itself
            // inside (seen ~1 in 10⁶ paths near the surface, each then a runaway
            // firefly).
            short_cast(scene, s.pos, s.dir, t + geo.flight_margin())
        };
        // A face found only thanks to the margin is not reached (`Geometry::flight_end`).
        geo.flight_end(hit, s.dir, t)
    }

    /// The flight met face `h` from inside: the path passes into an overlapping piece,
    /// leaves the medium, or is reflected back in.
    #[inline]
    fn reach_face(&mut self, scene: &SceneData, mut h: Hit) {
        let geo = &scene.geo;
        let Self {
            s,
            rng,
            stats,
            inside,
            from_step,
            left_through,
            ..
        } = self;
        s.free = 0.0;
        let p = s.pos + s.dir * h.t;
        let mut turned = false;
        if let Some(pieces) = &geo.pieces {
            let past = geo.spawn(p, h.normal, s.dir);
            if geo.in_union(pieces, past, s.dir) {
                // A face within the union of overlapping pieces: into one more
                // of them, or out of one of several. No boundary; the flight goes
                // on, its rest redrawn past the face (flights have no memory),
                // from the face: the way to `past` is skipped like an entry's.
                // (A leak, met from outside while believed inside, is taken in
                // here too: with overlaps only `advance`'s bounding-box net counts
                // leaks.)
                s.pos = past;
                s.skip = geo.spawn_skip(h.normal, s.dir);
                *from_step = false;
                return;
            }
            // Out of the medium: its boundary's normal faces the air ahead.
            if s.dir.dot(h.normal) < 0.0 {
                h.normal = -h.normal;
                turned = true;
            }
        }
        if s.dir.dot(h.normal) < 0.0 {
            // Met the surface from outside while believed inside. After a sphere step
            // the exit was not inside after all: count it. The path is placed past
            // the surface, believed outside; the next cast meets the far side from
            // within and `cast_from_air`'s touching-parts rule takes it in there, without a
            // Fresnel choice (no difference index-matched; leaks are 0 in every
            // measured render, so it was left so).
            if *from_step {
                stats.leaks += 1;
            }
            *inside = false;
            s.pos = geo.spawn(p, h.normal, s.dir);
            *from_step = false;
            return;
        }
        match scene.boundary.ior() {
            None => *inside = false,
            Some(ior) => {
                let f = fresnel(s.dir.dot(h.normal).abs(), ior, 1.0);
                if uniform(rng) < f {
                    s.dir = reflect(s.dir, h.normal);
                    s.scattered = false; // (as in `cast_from_air`)
                } else {
                    s.dir = refract(s.dir, h.normal, ior, 1.0).unwrap_or(s.dir);
                    *inside = false;
                }
            }
        }
        if !*inside && !turned {
            // (A turned normal is not the one the triangle's escape cone is about.)
            *left_through = Some(h.prim);
        }
        s.pos = geo.spawn(p, h.normal, s.dir);
        if *inside && geo.beyond_sliver(s.pos, h.normal, |o, d, t| short_cast(scene, o, d, t)) {
            // Reflected back inside where the medium is thinner than the offset.
            *inside = false;
        }
        if *inside {
            s.skip = geo.spawn_skip(h.normal, s.dir);
        }
        *from_step = false;
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use scatter_sim::rng::WalkRng;

    use super::{Advance, IntegratorKind, IntegratorSettings, Path};
    use crate::scene::SceneFile;
    use crate::setup::SceneData;

    /// A dielectric (n = 1.5) wedge prism along z: cross-section (0, 0), (1, 0), (1, 10⁻³),
    /// so the lower face is y = 0, the upper face y = 10⁻³·x and the medium is 10⁻³·x
    /// thick: thinner than the spawn offset (eps = 2 × 10⁻⁵ of a scene of size 1) for
    /// x < 0.02. Almost no extinction, so a path inside flies straight.
    fn wedge(dir: &std::path::Path, camera: &str, sky: &str, light: &str) -> SceneData {
        let obj = "v 0 0 -0.5\nv 1 0 -0.5\nv 1 0.001 -0.5\nv 0 0 0.5\nv 1 0 0.5\nv 1 0.001 0.5\n\
                   f 1 3 2\nf 4 5 6\nf 1 2 5 4\nf 2 3 6 5\nf 1 4 6 3\n";
        let mesh = dir.join("wedge.obj");
        std::fs::write(&mesh, obj).unwrap();
        let text = format!(
            "[camera]\n{camera}\nup = [0.0, 0.0, 1.0]\nfov_deg = 0.01\nwidth = 4\nheight = 4\n\
             [object]\nmesh = \"{}\"\n\
             [medium]\nsigma_t = [0.001, 0.001, 0.001]\nalbedo = [1.0, 1.0, 1.0]\ng = 0.0\n\
             [boundary]\nkind = \"dielectric\"\nior = 1.5\n\
             {light}\n[environment]\nradiance = [{sky}, {sky}, {sky}]\n",
            mesh.display()
        );
        let file = SceneFile::parse(std::path::Path::new("wedge.toml"), &text).unwrap();
        SceneData::build(&file, dir, false, &[]).unwrap()
    }

    /// PT without NEE: the wedge's paths are followed to where they escape.
    fn pt() -> IntegratorSettings<'static> {
        IntegratorSettings {
            kind: IntegratorKind::Pt,
            nee: false,
            model: None,
            min_tau: 1.0,
            max_tau: 100.0,
            exact_tau: 0.0,
            nee_samples: 1,
            exact_nee_samples: 1,
            path_nee_rays: 1,
        }
    }

    /// A path inside the wedge (at x = 0.5, halfway up) heads at a grazing angle for the
    /// upper face, meeting it at x = 0.01 where the medium is half the spawn offset thick.
    /// Total internal reflection sends it back inside, to a point eps below the upper face:
    /// below the lower face, outside. The check after internal reflections must see that,
    /// and the path goes on outside and escapes to the environment (1) with no event and no
    /// leak. Without the check it believes itself inside, and its next flight (σ_t = 10⁻³)
    /// leaves the bounding box: a leak.
    #[test]
    fn an_internal_reflection_into_a_sliver_leaves_the_medium() {
        let dir = tempfile::tempdir().unwrap();
        let camera = "origin = [0.5, 1.0, 0.0]\ntarget = [0.5, 0.0, 0.0]";
        let scene = wedge(dir.path(), camera, "1.0", "");
        let set = pt();
        let start = Vec3::new(0.5, 2.5e-4, 0.0);
        let aim = Vec3::new(0.01, 1e-5, 0.0);
        for seed in 0..64 {
            let mut path = Path::new(
                start,
                (aim - start).normalize(),
                0,
                WalkRng::for_walk(3, seed),
            );
            path.inside = true;
            let Advance::Done(l) = path.advance(&scene, &set, &super::NEVER) else {
                panic!("PT has no sphere steps")
            };
            assert_eq!((path.stats.events, path.stats.leaks), (0, 0), "seed {seed}");
            assert_eq!(l, 1.0, "seed {seed}");
        }
    }

    /// A camera ray meets the wedge at 45° where it is a quarter of the offset thick: the
    /// paths that refract in pass the sliver and must go on in the direction they came (as
    /// through a slab of no thickness), into a 10° sun disk straight ahead; refracted (28°
    /// from the normal, 17° off) they would miss it. Each path gives the disk's radiance or
    /// 0 (1 − F = 0.95 at 45° refract; the rest reflect into a black sky).
    #[test]
    fn paths_passing_a_sliver_keep_their_direction() {
        let dir = tempfile::tempdir().unwrap();
        let camera = "origin = [-0.7, 0.705, 0.0]\ntarget = [0.005, 0.0, 0.0]";
        let light = "[[light]]\nkind = \"directional\"\ndirection = [-1.0, 1.0, 0.0]\n\
                     irradiance = [1.0, 1.0, 1.0]\nangular_diameter_deg = 10.0\n";
        let scene = wedge(dir.path(), camera, "0.0", light);
        let disk = scene.lights[0].radiance_toward(Vec3::new(1.0, -1.0, 0.0).normalize(), 0);
        assert!(disk > 0.0);
        let set = pt();
        let mut total = 0.0;
        let n = 4096;
        // The camera's ray (origin → target above).
        let origin = Vec3::new(-0.7, 0.705, 0.0);
        let d = (Vec3::new(0.005, 0.0, 0.0) - origin).normalize();
        for seed in 0..n {
            let mut path = Path::new(origin, d, 0, WalkRng::for_walk(5, seed));
            let Advance::Done(l) = path.advance(&scene, &set, &super::NEVER) else {
                panic!("PT has no sphere steps")
            };
            assert_eq!((path.stats.events, path.stats.leaks), (0, 0), "seed {seed}");
            total += l;
        }
        // 1 − F(45°, 1 → 1.5) = 0.950 of the disk's radiance expected (each path brings the
        // disk's radiance or 0): 4,096 paths put the mean within 4σ = 0.014 of it (σ =
        // √(0.95·0.05/4096) = 0.0034); with the direction lost it would be 0, a path that
        // counted the disk twice would give ~1.9, and one without the Fresnel choice 1.0,
        // 14.7σ off (with 256 paths, as before, 1.0 was inside 4σ).
        // Fresnel's textbook value, not `optics::fresnel` (which the integrator itself uses):
        // R_s = 0.0920, R_p = 0.0085 at 45° into n = 1.5.
        let transmitted = 1.0 - 0.5 * (0.092_02 + 0.008_47f32);
        let sigma = (transmitted * (1.0 - transmitted) / n as f32).sqrt();
        let mean = total / n as f32 / disk;
        assert!(
            (mean - transmitted).abs() < 4.0 * sigma,
            "mean {mean}, expected {transmitted} ± {sigma}"
        );
    }

    /// A path that has scattered and left the medium meets the dielectric from outside at
    /// 60° (a non-convex object's glint): the reflection clears `scattered`, so with NEE on
    /// the path still sees the sun disk it is reflected into, as NEE never samples light that
    /// reaches a point by way of a reflection. The cube (ior 1.5) absorbs whatever enters it
    /// (σ_t 1,000, albedo 0) under a black sky, so each path brings the disk's radiance with
    /// probability F(60°) and 0 otherwise. F from the textbook's angle form (R_s = 0.176571,
    /// R_p = 0.001802), not `optics::fresnel`. 20,000 paths: σ = √(F(1 − F)/n) = 0.0020;
    /// allowed 4σ. With `scattered` kept through the reflection the mean is 0, 44σ off.
    #[test]
    fn a_reflection_off_the_outside_after_scattering_sees_the_sun() {
        let text = "[camera]\norigin = [0.0, 3.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\n\
                    up = [0.0, 0.0, 1.0]\nfov_deg = 30.0\nwidth = 4\nheight = 4\n\
                    [object]\nshape = \"cube\"\n\
                    [medium]\nsigma_t = [1000.0, 1000.0, 1000.0]\nalbedo = [0.0, 0.0, 0.0]\n\
                    [boundary]\nkind = \"dielectric\"\nior = 1.5\n\
                    [[light]]\nkind = \"directional\"\ndirection = [-0.8660254, -0.5, 0.0]\n\
                    irradiance = [1.0, 1.0, 1.0]\nangular_diameter_deg = 10.0\n\
                    [environment]\nradiance = [0.0, 0.0, 0.0]\n";
        let file = SceneFile::parse(std::path::Path::new("glint.toml"), text).unwrap();
        let scene = SceneData::build(&file, std::path::Path::new("."), false, &[]).unwrap();
        // Meets the top face (y = 0.5) at its centre, 60° from its normal; the mirror
        // direction is the sun's centre.
        let d = Vec3::new(0.866_025_4, -0.5, 0.0);
        let start = Vec3::new(0.0, 0.5, 0.0) - d;
        let mirror = Vec3::new(d.x, -d.y, d.z);
        let disk = scene.lights[0].radiance_toward(mirror, 0);
        assert!(disk > 0.0);
        let set = IntegratorSettings { nee: true, ..pt() };
        let n = 20_000;
        let mut total = 0.0;
        for seed in 0..n {
            let mut path = Path::new(start, d, 0, WalkRng::for_walk(13, seed));
            path.s.scattered = true;
            let Advance::Done(l) = path.advance(&scene, &set, &super::NEVER) else {
                panic!("PT has no sphere steps")
            };
            assert!(l == 0.0 || l == disk, "seed {seed}: {l} (disk {disk})");
            total += l;
        }
        let f = 0.5 * (0.176_571_5 + 0.001_801_9f32);
        let sigma = (f * (1.0 - f) / n as f32).sqrt();
        let mean = total / n as f32 / disk;
        assert!(
            (mean - f).abs() < 4.0 * sigma,
            "mean {mean}, expected F(60°) = {f} ± {sigma}"
        );
    }

    /// Asserts that of `n` PT paths (NEE off) from `start` along `dir`, inside the medium
    /// if `inside`, each escaping to a sky of 1 or absorbed (0), the share escaping is
    /// `want` within 4 standard errors of a Bernoulli mean.
    fn assert_escapes(
        scene: &SceneData,
        (start, dir, inside): (Vec3, Vec3, bool),
        seed: u64,
        n: u64,
        want: f64,
    ) {
        let escaped: f64 = (0..n)
            .map(|i| {
                let mut path = Path::new(start, dir, 0, WalkRng::for_walk(seed, i));
                path.inside = inside;
                let Advance::Done(l) = path.advance(scene, &pt(), &super::NEVER) else {
                    panic!("PT has no sphere steps")
                };
                l as f64
            })
            .sum();
        let mean = escaped / n as f64;
        let se = (want * (1.0 - want) / n as f64).sqrt();
        assert!(
            (mean - want).abs() < 4.0 * se,
            "escaped {mean:.5}, expected {want:.5} ± {se:.5}"
        );
    }

    /// A path inside a purely absorbing cube, eps (its spawn offset) below the top face and
    /// heading straight out, at σ_t·eps = 0.2 under a sky of 1: it escapes (1) with
    /// probability e^−0.2 = 0.81873 and is absorbed (0) otherwise. A face the cast finds
    /// only within the flight margin (0.02 eps) beyond a collision once ended the path as an
    /// exit (up to e^−0.196 = 0.82201 escaped; measured 0.82147). 2·10⁶ paths: standard
    /// error √(0.819·0.181/2·10⁶) = 2.7·10⁻⁴, so the old rule is 10 standard errors off;
    /// allowed 4.
    #[test]
    fn collisions_within_the_flight_margin_stand() {
        let text = "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\n\
                    fov_deg = 20.0\nwidth = 4\nheight = 4\n[object]\nshape = \"cube\"\n\
                    [medium]\nsigma_t = [SIGMA, SIGMA, SIGMA]\nalbedo = [0.0, 0.0, 0.0]\n\
                    [environment]\nradiance = [1.0, 1.0, 1.0]\n";
        let probe = SceneFile::parse(
            std::path::Path::new("cube.toml"),
            &text.replace("SIGMA", "1.0"),
        )
        .unwrap();
        let eps = SceneData::build(&probe, std::path::Path::new("."), false, &[])
            .unwrap()
            .geo
            .eps;
        let sigma = 0.2 / eps as f64;
        let file = SceneFile::parse(
            std::path::Path::new("cube.toml"),
            &text.replace("SIGMA", &format!("{sigma:?}")),
        )
        .unwrap();
        let scene = SceneData::build(&file, std::path::Path::new("."), false, &[]).unwrap();
        let start = Vec3::new(0.0, 0.5 - eps, 0.0);
        let want = (-(sigma * eps as f64)).exp();
        assert_escapes(&scene, (start, Vec3::Y, true), 11, 2_000_000, want);
    }

    /// Summing counters adds each field to its own: with a distinct power of two in every
    /// field of each side, any field taken from another shows. (A leak count taken from
    /// `capped` left the JSON's `leaks` at 0 and its warning silent.)
    #[test]
    fn path_stats_add_field_by_field() {
        let stats = |k: u32| super::PathStats {
            paths: 1 << k,
            events: 2 << k,
            steps: 4 << k,
            exact_steps: 8 << k,
            exact_events: 16 << k,
            leaks: 32 << k,
            capped: 64 << k,
            non_finite: 128 << k,
        };
        let mut sum = stats(0);
        sum.add(&stats(8));
        let want = super::PathStats {
            paths: 1 + (1 << 8),
            events: 2 + (2 << 8),
            steps: 4 + (4 << 8),
            exact_steps: 8 + (8 << 8),
            exact_events: 16 + (16 << 8),
            leaks: 32 + (32 << 8),
            capped: 64 + (64 << 8),
            non_finite: 128 + (128 << 8),
        };
        assert_eq!(sum, want);
    }

    /// A non-finite path estimate (NaN or ±∞) is counted and replaced by 0, so that no
    /// pixel sum turns NaN; a finite one passes unchanged.
    #[test]
    fn non_finite_estimates_are_counted_and_dropped() {
        let scene = absorbing_unit_cube();
        for (radiance, want, counted) in [
            (f32::NAN, 0.0, 1),
            (f32::INFINITY, 0.0, 1),
            (f32::NEG_INFINITY, 0.0, 1),
            (0.25, 0.25, 0),
        ] {
            let mut path = Path::new(Vec3::splat(2.0), Vec3::X, 0, WalkRng::for_walk(29, 0));
            path.s.radiance = radiance;
            path.s.alive = false;
            let Advance::Done(l) = path.advance(&scene, &pt(), &super::NEVER) else {
                panic!("PT has no sphere steps")
            };
            assert_eq!((l, path.stats.non_finite), (want, counted), "{radiance}");
        }
    }

    /// A purely absorbing cube of side 1 about the origin (σ_t 1, index-matched) under a
    /// sky of 1.
    fn absorbing_unit_cube() -> SceneData {
        let dir = tempfile::tempdir().unwrap();
        absorbing_boxes(
            dir.path(),
            &[([-0.5; 3], [0.5; 3])],
            1.0,
            "kind = \"index-matched\"",
        )
    }

    /// Axis-aligned boxes (lo, hi) as one mesh written into `dir`, purely absorbing at
    /// `sigma`, with `boundary` as the [boundary] table's body, under a sky of 1. (The
    /// integration tests' `common::boxes_obj` writes boxes the same way; unit tests cannot
    /// reach it.)
    fn absorbing_boxes(
        dir: &std::path::Path,
        boxes: &[([f32; 3], [f32; 3])],
        sigma: f32,
        boundary: &str,
    ) -> SceneData {
        let mut obj = String::new();
        for (lo, hi) in boxes {
            for k in 0..8 {
                let c = |bit: usize, i: usize| if k >> bit & 1 == 1 { hi[i] } else { lo[i] };
                obj += &format!("v {} {} {}\n", c(0, 0), c(1, 1), c(2, 2));
            }
        }
        // Vertex k of a box has bits (x, y, z); faces counter-clockwise seen from outside.
        for b in 0..boxes.len() {
            for f in [
                [0, 4, 6, 2],
                [1, 3, 7, 5],
                [0, 1, 5, 4],
                [2, 6, 7, 3],
                [0, 2, 3, 1],
                [4, 5, 7, 6],
            ] {
                let v = f.map(|k| 1 + 8 * b + k);
                obj += &format!("f {} {} {} {}\n", v[0], v[1], v[2], v[3]);
            }
        }
        let mesh = dir.join("boxes.obj");
        std::fs::write(&mesh, obj).unwrap();
        let text = format!(
            "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
             width = 4\nheight = 4\n[object]\nmesh = {:?}\n\
             [medium]\nsigma_t = [{sigma:?}, {sigma:?}, {sigma:?}]\nalbedo = [0.0, 0.0, 0.0]\n\
             [boundary]\n{boundary}\n[environment]\nradiance = [1.0, 1.0, 1.0]\n",
            mesh.display().to_string()
        );
        let file = SceneFile::parse(std::path::Path::new("boxes.toml"), &text).unwrap();
        SceneData::build(&file, dir, false, &[]).unwrap()
    }

    /// Where pieces overlap, a path crossing a face within the union is spawned eps past
    /// it, and that way is taken off its next flight too. Two overlapping absorbing boxes,
    /// A = [0, 20 eps] and B = [10 eps, 30 eps] in x (B narrower in y and z, so no faces
    /// share planes), index-matched, σ_t·eps = 0.1: a ray along +x through both crosses
    /// 30 eps of medium and two faces inside it, escaping with probability e^−3 = 0.04979.
    /// Without the skip at the inner faces it passes 2 eps of medium unseen: e^−2.8 =
    /// 0.06081. 10⁵ paths: standard error 6.9e-4, so that is 16 standard errors off;
    /// allowed 4.
    #[test]
    fn a_face_inside_a_union_takes_its_spawn_offset_off_the_next_flight() {
        let dir = tempfile::tempdir().unwrap();
        let boxes = |e: f32| {
            [
                ([0.0, -0.5, -0.5], [20.0 * e, 0.5, 0.5]),
                ([10.0 * e, -0.4, -0.4], [30.0 * e, 0.4, 0.4]),
            ]
        };
        let eps = absorbing_boxes(dir.path(), &boxes(1e-4), 1.0, "kind = \"index-matched\"")
            .geo
            .eps;
        let scene = absorbing_boxes(
            dir.path(),
            &boxes(eps),
            0.1 / eps,
            "kind = \"index-matched\"",
        );
        assert!(scene.geo.pieces.is_some(), "the boxes overlap");
        assert!(
            (scene.geo.eps - eps).abs() <= 1e-3 * eps,
            "eps {eps}, {}",
            scene.geo.eps
        );
        let start = Vec3::new(-1.0, 0.1, 0.2);
        assert_escapes(
            &scene,
            (start, Vec3::X, false),
            23,
            100_000,
            (-3.0f64).exp(),
        );
    }

    /// A path reflected back inside a dielectric is spawned eps deep, and that way is taken
    /// off its next flight (`spawn_skip`), as after an entry. A purely absorbing glass slab
    /// (ior 1.5) two spawn offsets thick (x ∈ [0, 2 eps], σ_t·eps = 0.1) under a sky of 1;
    /// a path starts at its middle heading 40° from +x (near the critical angle, 41.8°, so
    /// that F(40°) = 0.2453 from the textbook's angle form, R_s = 0.390518, R_p = 0.100064,
    /// reflects often). With T = e^(−0.2/cos 40°) a crossing's transmittance it escapes with
    /// probability √T·(1 − F)/(1 − F·T) = 0.81663. Without the skip each crossing after a
    /// reflection passes only half the slab: 0.84405. 10⁵ paths: standard error 0.0012, so
    /// that is 22 standard errors off; allowed 4.
    #[test]
    fn a_reflection_inside_takes_its_spawn_offset_off_the_next_flight() {
        let dir = tempfile::tempdir().unwrap();
        let slab = |x1: f32, sigma: f32| {
            let slab = ([0.0, -0.5, -0.5], [x1, 0.5, 0.5]);
            absorbing_boxes(
                dir.path(),
                &[slab],
                sigma,
                "kind = \"dielectric\"\nior = 1.5",
            )
        };
        // eps follows the scene's size, which the slab's 1 × 1 face sets.
        let eps = slab(1e-4, 1.0).geo.eps;
        let scene = slab(2.0 * eps, 0.1 / eps);
        assert!(
            (scene.geo.eps - eps).abs() <= 1e-3 * eps,
            "eps {eps}, {}",
            scene.geo.eps
        );
        let (c, s) = (40f32.to_radians().cos(), 40f32.to_radians().sin());
        let f = 0.5 * (0.390_518 + 0.100_064);
        let t = (-0.2 / 40f64.to_radians().cos()).exp();
        let want = t.sqrt() * (1.0 - f) / (1.0 - f * t);
        let start = Vec3::new(eps, 0.0, 0.0);
        assert_escapes(
            &scene,
            (start, Vec3::new(c, s, 0.0), true),
            19,
            100_000,
            want,
        );
    }

    /// With path-level NEE (m ≥ 1 reservoirs) an event's NEE is offered to the path's
    /// reservoirs and cast when the path ends, not at once: `add_nee` leaves the radiance
    /// alone and the reservoir holds the light. `path_nee_rays = 1`, the default, is one
    /// shadow ray a path; taken for 0 it would cast one at every event (the same mean, so
    /// no image test sees it, at several times the shadow rays). With m = 0, at once.
    #[test]
    fn path_level_nee_defers_the_shadow_ray() {
        let text = "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\n\
                    fov_deg = 20.0\nwidth = 4\nheight = 4\n[object]\nshape = \"sphere\"\n\
                    radius = 0.5\n[medium]\nsigma_t = [10.0, 10.0, 10.0]\n\
                    albedo = [0.9, 0.9, 0.9]\ng = 0.0\n[[light]]\nkind = \"directional\"\n\
                    direction = [0.0, -1.0, 0.0]\nirradiance = [1.0, 1.0, 1.0]\n";
        let file = SceneFile::parse(std::path::Path::new("lit.toml"), text).unwrap();
        let scene = SceneData::build(&file, std::path::Path::new("."), false, &[]).unwrap();
        // 0.01 under the lit top, scattering upward: e^−0.1 of the light reaches it.
        let event = (Vec3::new(0.0, 0.49, 0.0), Vec3::Y);
        let mut rng = WalkRng::from_seed(5);
        for m in [0, 1, 2] {
            let mut path = Path::new(Vec3::ZERO, Vec3::Y, 0, WalkRng::from_seed(6));
            path.s.add_nee(&scene, m, event, 1.0, |_| 0.0, 0, &mut rng);
            let deferred = path.s.nee.finish(&scene, m, 0, &mut rng);
            if m == 0 {
                assert!(path.s.radiance > 0.0, "m = 0: no shadow ray cast");
            } else {
                assert!(
                    path.s.radiance == 0.0 && deferred > 0.0,
                    "m = {m}: radiance {} at the event, {deferred} at the end",
                    path.s.radiance
                );
            }
        }
    }

    /// `uniform` is the kernels' rand(): the top 24 bits k of the stream's next u64, over
    /// 2^24, so that every draw is k/2^24 < 1 (never 1: its doc says why). Divided by
    /// 2^24 − 1 instead (the largest k then gives exactly 1), every draw with k > 0 is off
    /// that grid by 1–2 ulps, far below what a statistical test sees; compared here exactly.
    #[test]
    fn uniform_draws_are_the_top_24_bits_over_2_to_the_24() {
        let mut rng = WalkRng::for_walk(31, 0);
        for _ in 0..10_000 {
            let k = rng.clone().next_u64() >> 40;
            let u = super::uniform(&mut rng);
            assert_eq!(u, k as f32 / 16_777_216.0, "k = {k}");
            assert!(u < 1.0);
        }
    }

    /// `trace` hands the caller's stream back where the path left it, so that paths traced
    /// one after another from one stream are independent. Through a purely absorbing cube
    /// (side 1, σ_t 1, index-matched) under a sky of 1, each path along −z (off the faces'
    /// diagonals) escapes (1) with probability e^−1 = 0.36788, else is absorbed (0). 4,000
    /// paths from one stream: standard error √(0.368·0.632/4000) = 0.0076; allowed 4.5 of
    /// them. A stream handed back unadvanced repeats the first path every time: a mean of 0
    /// or 1, 48 or 83 standard errors off.
    #[test]
    fn paths_traced_from_one_stream_are_independent() {
        let scene = absorbing_unit_cube();
        let mut rng = WalkRng::for_walk(37, 0);
        let mut stats = super::PathStats::default();
        let n = 4_000;
        let mut escaped = 0.0f64;
        for _ in 0..n {
            let origin = Vec3::new(0.1, 0.2, 4.0);
            let l = super::trace(&scene, &pt(), origin, Vec3::NEG_Z, 0, &mut stats, &mut rng);
            assert!(l == 0.0 || l == 1.0, "{l}");
            escaped += f64::from(l);
        }
        assert_eq!(stats.paths, n);
        let want = (-1.0f64).exp();
        let se = (want * (1.0 - want) / n as f64).sqrt();
        let mean = escaped / n as f64;
        assert!(
            (mean - want).abs() < 4.5 * se,
            "escaped {mean:.4}, expected {want:.4} ± {se:.4}"
        );
    }

    /// Path-level NEE is ST-CVAE's alone, with NEE on: PT casts a shadow ray at every
    /// event whatever `path_nee_rays` says (as the GPU's PT kernel does; the setting is
    /// ST-CVAE's), and the reservoirs are at most `nee::MAX_PATH_NEE_RAYS`. (PT with path
    /// reservoirs has the same mean, so no image test would see it.)
    #[test]
    fn only_stcvae_with_nee_keeps_path_reservoirs() {
        let st = |nee: bool, rays: u32| IntegratorSettings {
            kind: IntegratorKind::Stcvae,
            nee,
            path_nee_rays: rays,
            ..pt()
        };
        for rays in [0, 1, 2] {
            let pt_nee = IntegratorSettings {
                nee: true,
                path_nee_rays: rays,
                ..pt()
            };
            assert_eq!(pt_nee.path_nee(), 0, "PT, {rays} rays");
            assert_eq!(
                st(true, rays).path_nee(),
                rays as usize,
                "ST-CVAE, {rays} rays"
            );
            assert_eq!(st(false, rays).path_nee(), 0, "ST-CVAE without NEE");
        }
        assert_eq!(st(true, 100).path_nee(), super::nee::MAX_PATH_NEE_RAYS);
    }
}
