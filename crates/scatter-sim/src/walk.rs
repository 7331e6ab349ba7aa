//! The unit-sphere random walk (design §2, paper §3.1).
//!
//! The photon arrives along +z at the centre, where event 1 happens; each event draws a
//! new direction from HG around the arriving one, then a free flight of optical length
//! Exp(1) (geometric length l = −ln ξ / τ in the unit sphere). The walk ends when a
//! flight crosses the sphere. Absorption is not simulated: it enters as φ^N.

use glam::DVec3;

use crate::frame::{CanonicalExit, to_canonical};
use crate::phase::hg_sample_direction;
use crate::reservoir::Reservoir;
use crate::rng::WalkRng;

/// A finished walk in the world frame of the simulation (ω_in = +z).
#[derive(Clone, Copy, Debug)]
pub struct Walk {
    /// Number of scattering events, the centre included (N ≥ 1).
    pub n: u64,
    /// Exit point, |x| = 1.
    pub exit_pos: DVec3,
    /// Exit direction (unit, pointing outward).
    pub exit_dir: DVec3,
    /// Index k of the representative event (1 = the centre).
    pub event_index: u64,
    /// Position X of the representative event.
    pub event_pos: DVec3,
    /// Direction W arriving at the representative event.
    pub event_dir: DVec3,
}

/// A walk in the canonical frame: what the models learn and the dataset stores.
#[derive(Clone, Copy, Debug)]
pub struct CanonicalWalk {
    pub n: u64,
    pub exit: CanonicalExit,
    pub event_pos: DVec3,
    pub event_dir: DVec3,
}

impl Walk {
    pub fn canonical(&self) -> CanonicalWalk {
        let (mut exit, rot) = to_canonical(self.exit_pos, self.exit_dir);
        if self.n == 1 {
            // A single-scattering walk leaves the centre along ω, so x = ω and α = β = 0
            // exactly; rounding would otherwise leave ±1e-17, which splits the point mass
            // at 0 in two and makes exact comparisons (KS against the model) meaningless.
            exit.alpha = 0.0;
            exit.beta = 0.0;
        }
        CanonicalWalk {
            n: self.n,
            exit,
            event_pos: rot.apply(self.event_pos),
            event_dir: rot.apply(self.event_dir),
        }
    }
}

/// Simulates one walk in the unit sphere of optical radius `tau`.
///
/// `albedo` only steers the choice of the representative event; the path itself is
/// independent of it. Callers validate the parameters (see [`crate::ranges`]).
pub fn simulate_walk(tau: f64, g: f64, albedo: f64, rng: &mut WalkRng) -> Walk {
    let (end, [(k, event_pos, event_dir)]) = walk_events::<1>(tau, g, albedo, rng);
    Walk {
        n: end.n,
        exit_pos: end.exit_pos,
        exit_dir: end.exit_dir,
        event_index: k,
        event_pos,
        event_dir,
    }
}

/// How a walk ended: its event count and where and how it crossed the unit sphere.
#[derive(Clone, Copy, Debug)]
pub struct WalkEnd {
    /// Number of scattering events, the centre included (N ≥ 1).
    pub n: u64,
    /// Exit point, |x| = 1.
    pub exit_pos: DVec3,
    /// Exit direction (unit, pointing outward).
    pub exit_dir: DVec3,
}

/// Simulates one walk with `M` representative events chosen independently (each event
/// k with probability φ^k/Λ(N), one reservoir each): (index k, X, W) per event. The
/// renderer's exact sphere steps use several for next-event estimation; `M = 0` makes
/// just the walk.
pub fn walk_events<const M: usize>(
    tau: f64,
    g: f64,
    albedo: f64,
    rng: &mut WalkRng,
) -> (WalkEnd, [(u64, DVec3, DVec3); M]) {
    let mut reservoirs: [Reservoir; M] = std::array::from_fn(|_| Reservoir::new(albedo, rng));
    let mut pos = DVec3::ZERO;
    let mut arriving = DVec3::Z;
    let mut events = [(1u64, pos, arriving); M];
    let inv_tau = 1.0 / tau;
    let mut n = 1u64;
    loop {
        let dir = hg_sample_direction(g, arriving, rng);
        let flight = -rng.uniform_open0().ln() * inv_tau;
        let next = pos + dir * flight;
        // A flight of 2 or more crosses the unit sphere from anywhere inside; testing it
        // first also catches τ = 0 (infinite flight) before it makes NaNs.
        if !(flight < 2.0) || next.length_squared() >= 1.0 {
            // Distance to the sphere along dir: t² + 2bt + c = 0 with c = |p|² − 1 ≤ 0.
            let b = pos.dot(dir);
            let c = pos.length_squared() - 1.0;
            let t = -b + (b * b - c).max(0.0).sqrt();
            let exit_pos = (pos + dir * t).normalize();
            let end = WalkEnd {
                n,
                exit_pos,
                exit_dir: dir,
            };
            return (end, events);
        }
        pos = next;
        arriving = dir;
        n += 1;
        for (r, e) in reservoirs.iter_mut().zip(events.iter_mut()) {
            if r.offer(n, rng) {
                *e = (n, pos, dir);
            }
        }
    }
}
