//! The ST-CVAE sphere step (design §4): at a real collision p, jump over the whole walk
//! inside the largest surface-free sphere around p with one draw from the models.
//!
//! φ^N already contains the albedo of event 1 (the collision at p), so p gets no
//! separate albedo weight and no separate NEE: EventGen's representative event, with
//! weight Λ(N) = Σ_{k=1..N} φ^k, stands for NEE at all N events of the walk.

use glam::DVec3;
use scatter_sim::frame::{WalkFrame, from_canonical};
use scatter_sim::rng::WalkRng;

use super::{IntegratorSettings, PathState, PathStats, nee, pt_event, roulette};
use crate::setup::SceneData;

/// The sphere radius is shrunk by this factor so the exit point stays strictly inside.
const SHRINK: f32 = 1.0 - 1e-4;

/// One step at `s.pos`; returns true if a sphere step was taken (false: PT fallback).
pub(crate) fn step(
    scene: &SceneData,
    set: &IntegratorSettings,
    channel: usize,
    s: &mut PathState,
    stats: &mut PathStats,
    rng: &mut WalkRng,
) -> bool {
    let (Some(model), Some(grid)) = (set.model, scene.grid.as_ref()) else {
        pt_event(scene, set, channel, s, stats, rng);
        return false;
    };
    let sigma = scene.sigma_t[channel];
    // The path's own bound (s.free: what is left of the last free ball after the flight)
    // is often larger than the grid's near the surface, and costs nothing.
    let grid_free = grid.radius(s.pos);
    let mut free = grid_free.max(s.free);
    if free < grid.near_surface && sigma * free < set.min_tau {
        // Near the surface the grid's Lipschitz bound loses up to two cell half-diagonals,
        // which at high density is many mean free paths of PT fallback events. When the
        // grid alone would force a fallback, the exact nearest-triangle distance (about
        // the cost of one ray cast) often still allows a sphere step.
        // The search never looks beyond what the grid says the distance can be at most.
        let exact = scene
            .geo
            .distance_within(s.pos, grid.distance_upper_bound(grid_free));
        free = free.max(exact * (1.0 - 1e-5) - scene.geo.eps);
    }
    let r = (free * SHRINK).min(set.max_tau / sigma);
    let tau = sigma * r;
    if !(r > 0.0) || tau < set.min_tau {
        s.free = free.max(0.0);
        pt_event(scene, set, channel, s, stats, rng);
        return false;
    }
    stats.steps += 1;
    let albedo = scene.albedo[channel] as f64;
    let frame = WalkFrame::new(s.dir.as_dvec3(), rng.unit_circle());
    let walk = model.sample_walk(tau as f64, scene.g as f64, albedo, set.nee, rng);
    let centre = s.pos.as_dvec3();
    if set.nee {
        // Extra representative events (EventGen draws given the same N and exit), each
        // weighted Λ(N)/M: the same expectation with less variance per sphere step.
        let m = if walk.single {
            1
        } else {
            set.nee_samples.max(1)
        };
        let mut sum = 0.0f32;
        for k in 0..m {
            let (ep, ed) = if k == 0 {
                (walk.event_pos, walk.event_dir)
            } else {
                model.sample_event_given(&walk, rng)
            };
            let x = centre + frame.to_world(ep) * r as f64;
            let w = frame.to_world(ed).normalize();
            // X lies |ep|·r from the centre, whose ball of radius `free` is surface-free;
            // the grid at X (one lookup, against a shadow ray's two traversals) is often
            // the larger bound for events away from the centre. A larger bound lets the
            // shadow-ray roulette skip more rays.
            let x = x.as_vec3();
            let x_free = (free - ep.length() as f32 * r).max(grid.radius(x));
            sum += nee::direct(scene, x, w.as_vec3(), x_free, channel, rng);
        }
        s.radiance += s.beta * walk.lambda as f32 * sum / m as f32;
    }
    s.beta *= walk.survival as f32;
    if !roulette(&mut s.beta, rng) {
        s.alive = false;
        return true;
    }
    let (x, omega) = from_canonical(walk.exit);
    let exit: DVec3 = centre + frame.to_world(x) * r as f64;
    s.pos = exit.as_vec3();
    s.dir = frame.to_world(omega).as_vec3().normalize();
    s.scattered = true;
    // The exit lies on the sphere of radius r inside the free ball of radius `free`, which
    // leaves it almost no known free distance; the grid at the exit often knows more, and
    // a flight shorter than that needs no ray cast.
    s.free = (free - r).max(grid.radius(s.pos));
    true
}
