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
    let mut reservoir = Reservoir::new(albedo, rng);
    let (mut event_pos, mut event_dir) = (DVec3::ZERO, DVec3::Z);
    let end = walk_with(tau, g, rng, |k, pos, dir, rng| {
        if reservoir.offer(k, rng) {
            event_pos = pos;
            event_dir = dir;
        }
    });
    Walk {
        n: end.n,
        exit_pos: end.exit_pos,
        exit_dir: end.exit_dir,
        event_index: reservoir.chosen(),
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

/// Simulates one walk, calling `event(k, X_k, W_k, rng)` at each event after the first
/// (k = 2, 3, …; event 1 is the centre, X = 0, W = +z). The simulator picks its
/// representative event there. The renderer's exact sphere steps run an f32 copy of this
/// walk (render-gpu's `integrator::walk_lanes`, tested against this one) and weigh every
/// event for next-event estimation.
#[inline]
pub fn walk_with(
    tau: f64,
    g: f64,
    rng: &mut WalkRng,
    mut event: impl FnMut(u64, DVec3, DVec3, &mut WalkRng),
) -> WalkEnd {
    let mut pos = DVec3::ZERO;
    let mut arriving = DVec3::Z;
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
            return WalkEnd {
                n,
                exit_pos,
                exit_dir: dir,
            };
        }
        pos = next;
        arriving = dir;
        n += 1;
        event(n, pos, dir, rng);
    }
}
