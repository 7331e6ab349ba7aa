//! Samples of every compared quantity, drawn from the simulator or the models.

use std::sync::atomic::{AtomicBool, Ordering};

use glam::DVec3;
use rayon::prelude::*;
use scatter_sim::frame::CanonicalExit;
use scatter_sim::{WalkRng, simulate_walk};

use super::{SHELLS, SURVIVAL_ALBEDOS, half_space_nee, sphere_nee};
use crate::model_file::ModelSet;
use crate::sampler::lambda;

/// A walk's N, exit and representative event (X, W).
pub type WalkSummary = (u64, CanonicalExit, DVec3, DVec3);

/// Samples of every quantity for one setting, one column per entry of
/// [`QUANTITIES`](super::QUANTITIES), and the walks they came from.
#[derive(Clone, Debug, Default)]
pub struct Columns(pub [Vec<f64>; 8], pub Vec<WalkSummary>);

impl Columns {
    pub(super) fn from_walks(walks: Vec<WalkSummary>) -> Self {
        let mut c = Columns::default();
        for &(n, e, x, w) in &walks {
            c.push(n, e.cos_theta, e.alpha, e.beta, x, w);
        }
        c.1 = walks;
        c
    }

    /// Per walk, the samples of the two expectations: Λ(N) and [`sphere_nee`]. Only the
    /// grid's comparison needs them (not the plots), so they are not columns.
    pub fn nee_samples(&self, tau: f64, g: f64, albedo: f64) -> [Vec<f64>; 2] {
        let weight = self.1.iter().map(|&(n, ..)| lambda(albedo, n)).collect();
        let sphere = self
            .1
            .iter()
            .map(|&(n, _, x, w)| sphere_nee(tau, g, albedo, n, x, w))
            .collect();
        [weight, sphere]
    }

    /// Per walk and per albedo of [`SURVIVAL_ALBEDOS`]: the samples of φ^N.
    pub fn survival_samples(&self) -> [Vec<f64>; 2] {
        SURVIVAL_ALBEDOS.map(|a| {
            self.1
                .iter()
                .map(|&(n, ..)| crate::sampler::walk_weights(a, n).1)
                .collect()
        })
    }

    /// Per walk and per side of [`SURFACE_SIDES`](super::SURFACE_SIDES): the samples of
    /// [`half_space_nee`].
    pub fn half_space_samples(&self, tau: f64, g: f64, albedo: f64) -> [Vec<f64>; 3] {
        let per_walk: Vec<[f64; 3]> = self
            .1
            .par_iter()
            .map(|&(n, _, x, w)| half_space_nee(tau, g, albedo, n, x, w))
            .collect();
        [0, 1, 2].map(|k| per_walk.iter().map(|v| v[k]).collect())
    }

    /// Per walk and per band of [`SHELLS`]: 1 if its representative event lies in it,
    /// else 0. The centre event (X = 0) lies in none.
    pub fn shell_samples(&self) -> [Vec<f64>; 2] {
        SHELLS.map(|[lo, hi]| {
            self.1
                .iter()
                .map(|&(_, _, x, _)| {
                    let d = edge_distance(x);
                    f64::from(u8::from(lo <= d && d < hi))
                })
                .collect()
        })
    }

    fn push(&mut self, n: u64, cos: f64, alpha: f64, beta: f64, x: glam::DVec3, w: glam::DVec3) {
        let v = [
            n as f64,
            (n as f64).ln(),
            cos,
            alpha,
            beta,
            x.length(),
            x.z,
            w.z,
        ];
        for (c, v) in self.0.iter_mut().zip(v) {
            c.push(v);
        }
    }
}

/// `count` simulator walks at fixed conditions (stream `seed`, one per walk).
pub fn simulator_columns(tau: f64, g: f64, albedo: f64, count: usize, seed: u64) -> Columns {
    simulator_columns_until((tau, g, albedo), count, seed, &AtomicBool::new(false))
        .unwrap_or_else(|| Columns::from_walks(Vec::new()))
}

/// As [`simulator_columns`] at (τ, g, φ), or None once `stop` is set: a Ctrl-C need not wait for a
/// setting's walks (minutes at 4M samples and τ = 125).
pub fn simulator_columns_until(
    (tau, g, albedo): (f64, f64, f64),
    count: usize,
    seed: u64,
    stop: &AtomicBool,
) -> Option<Columns> {
    let walks: Option<Vec<_>> = (0..count as u64)
        .into_par_iter()
        .map(|i| {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            let mut rng = WalkRng::for_walk(seed, i);
            let w = simulate_walk(tau, g, albedo, &mut rng).canonical();
            Some((w.n, w.exit, w.event_pos, w.event_dir))
        })
        .collect();
    walks.map(Columns::from_walks)
}

/// `count` model walks at fixed conditions.
pub fn model_columns(
    m: &ModelSet,
    tau: f64,
    g: f64,
    albedo: f64,
    count: usize,
    seed: u64,
) -> Columns {
    let never = AtomicBool::new(false);
    model_columns_until(m, (tau, g, albedo), count, seed, &never)
        .unwrap_or_else(|| Columns::from_walks(Vec::new()))
}

/// As [`model_columns`] at (τ, g, φ), or None once `stop` is set.
pub fn model_columns_until(
    m: &ModelSet,
    (tau, g, albedo): (f64, f64, f64),
    count: usize,
    seed: u64,
    stop: &AtomicBool,
) -> Option<Columns> {
    let walks: Option<Vec<_>> = (0..count as u64)
        .into_par_iter()
        .map(|i| {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            let mut rng = model_rng(seed, i);
            let w = m.sample_walk(tau, g, albedo, true, &mut rng);
            Some((w.n, w.exit, w.event_pos, w.event_dir))
        })
        .collect();
    walks.map(Columns::from_walks)
}

/// The random numbers of the model's walk `i` under `seed`: a stream apart from the
/// simulator's walk `i` of the same seed (`WalkRng::for_walk(seed, i)`), so that model and
/// simulator walks of one seed are independent. One stream for both drew the simulator's
/// first deflection and the decoders' first latent values from the same numbers: the
/// paired rows of `generate` and `sample` at one seed correlated (event z direction
/// r = 0.04 over 200,000 rows, z = 19). `sample --seed S` draws what `eval` draws for a
/// setting of seed S.
pub fn model_rng(seed: u64, i: u64) -> WalkRng {
    WalkRng::for_walk(seed ^ 0x6d6f_64656c, i)
}

/// 1 − |X|: an event's distance from the sphere's surface (0 for one repaired onto the
/// surface, which may read |X| = 1 + ulp).
pub(super) fn edge_distance(x: DVec3) -> f64 {
    (1.0 - x.length()).max(0.0)
}
