//! The sampling API the renderers use: (τ, g, φ) and random numbers in, a walk's
//! summary (N, exit, representative event) out, in the canonical frame of
//! `scatter_sim::frame`.

use glam::DVec3;
use scatter_sim::frame::CanonicalExit;
use scatter_sim::phase::hg_sample_cos;
use scatter_sim::rng::WalkRng;

use crate::decoder::{Decoder, Draw, MAX_INPUT, MAX_OUT, Output};
use crate::features;
use crate::model_file::{ModelSet, SingleScattering};

/// A walk drawn from the models.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelWalk {
    /// Number of scattering events, before absorption (N ≥ 1).
    pub n: u64,
    pub exit: CanonicalExit,
    /// Representative event X (|X| ≤ 1) and the direction W arriving there (|W| = 1).
    pub event_pos: DVec3,
    pub event_dir: DVec3,
    /// True if this came from the exact single-scattering branch (no decoder ran).
    pub single: bool,
    /// Λ(N), the NEE weight of the representative event, and φ^N, the walk's survival
    /// weight (computed once per walk: see [`walk_weights`]).
    pub lambda: f64,
    pub survival: f64,
    /// The walk's conditioning features and its relative log N, so further EventGen
    /// draws for the same walk ([`ModelSet::sample_event_given`]) recompute nothing.
    pub features: features::WalkFeatures,
    pub relative_log_n: f64,
    pub albedo: f64,
}

impl ModelWalk {
    /// A walk of N events (from the decoders) with its weights and features filled in and
    /// the centre as a placeholder event.
    pub fn multiple(
        n: u64,
        exit: CanonicalExit,
        features: features::WalkFeatures,
        albedo: f64,
    ) -> Self {
        let (lambda, survival) = walk_weights(albedo, n);
        ModelWalk {
            n,
            exit,
            event_pos: DVec3::ZERO,
            event_dir: DVec3::Z,
            single: false,
            lambda,
            survival,
            features,
            relative_log_n: features.relative_log_n(n),
            albedo,
        }
    }
}

/// Λ(N) = Σ_{k=1..N} φ^k, the NEE weight of a walk's representative event (f64: φ is
/// often within 1e-5 of 1).
pub fn lambda(albedo: f64, n: u64) -> f64 {
    walk_weights(albedo, n).0
}

/// (Λ(N), φ^N) from one logarithm and one exp_m1 (plus an exp when φ^N < 1/2): a renderer
/// needs both for every sphere step and the exact-mode EventGen needs Λ(N) for every draw
/// (computed apart they took three logarithms and five exponentials per step).
pub fn walk_weights(albedo: f64, n: u64) -> (f64, f64) {
    if albedo >= 1.0 {
        (n as f64, 1.0)
    } else if albedo <= 0.0 {
        (0.0, 0.0)
    } else {
        let ln = albedo.ln();
        let x = n as f64 * ln;
        let e = x.exp_m1();
        // Λ = φ (1 − φ^N) / (1 − φ): 1 − φ^N through exp_m1; 1 − φ is exact in f64 for
        // φ ≥ 1/2 (Sterbenz) and within an ulp below. 1 + e loses φ^N's relative precision
        // once it is small: take exp there.
        let survival = if e > -0.5 { 1.0 + e } else { x.exp() };
        (albedo * (-e) / (1.0 - albedo), survival)
    }
}

/// Fills `out` with standard normal variates (a ziggurat on the walk's stream: Box–Muller
/// with its logarithm was a tenth of the renderer's time).
pub fn normals(rng: &mut WalkRng, out: &mut [f32]) {
    for v in out {
        *v = rng.standard_normal();
    }
}

/// Event 1 of every walk, in the canonical frame: the centre, arrived at along +z.
pub const CENTRE_EVENT: (DVec3, DVec3) = (DVec3::ZERO, DVec3::Z);

/// A decoder draw with its latent and output normals taken from `rng` (latent first).
fn draw_with_noise(decoder: &Decoder, cond: &[f64], rng: &mut WalkRng) -> Draw {
    let mut noise = [0f32; MAX_INPUT + MAX_OUT];
    let k = decoder.latent + decoder.out;
    normals(rng, &mut noise[..k]);
    let (z, eps) = noise[..k].split_at(decoder.latent);
    decoder.draw(cond, z, eps)
}

/// Repairs a model-made exit so that it is a valid canonical exit: cos θ ∈ [−1, 1],
/// α² + β² ≤ 1, everything finite.
pub fn repair_exit(cos_theta: f64, beta: f64, alpha: f64) -> CanonicalExit {
    let cos_theta = if cos_theta.is_finite() {
        cos_theta.clamp(-1.0, 1.0)
    } else {
        1.0
    };
    let (mut a, mut b) = if alpha.is_finite() && beta.is_finite() {
        (alpha, beta)
    } else {
        (0.0, 0.0)
    };
    let r2 = a * a + b * b;
    if r2 > 1.0 {
        let r = r2.sqrt();
        a /= r;
        b /= r;
    }
    CanonicalExit {
        cos_theta,
        alpha: a,
        beta: b,
    }
}

/// Repairs a model-made representative event: X clamped to the unit ball, W normalised.
pub fn repair_event(x: DVec3, w: DVec3) -> (DVec3, DVec3) {
    let x = if x.is_finite() { x } else { DVec3::ZERO };
    let x = if x.length_squared() > 1.0 {
        x.normalize()
    } else {
        x
    };
    let w = if w.is_finite() && w.length_squared() > 1e-20 {
        w.normalize()
    } else {
        DVec3::Z
    };
    (x, w)
}

impl ModelSet {
    /// Smallest N the decoders produce: 2 when N = 1 is handled exactly.
    pub fn n_min(&self) -> u64 {
        match self.single_scattering {
            SingleScattering::Exact => 2,
            SingleScattering::Learned => 1,
        }
    }

    /// LengthGen: N for a walk known to have N ≥ n_min.
    pub fn sample_multiple_n(&self, f: &features::WalkFeatures, rng: &mut WalkRng) -> u64 {
        let d = self.length_draw(f, rng);
        self.length_result(f, &self.length.output(&d))
    }

    /// LengthGen's draw for a walk known to have N ≥ n_min (its noise from `rng`).
    pub fn length_draw(&self, f: &features::WalkFeatures, rng: &mut WalkRng) -> Draw {
        draw_with_noise(&self.length, &f.length_cond(), rng)
    }

    /// N from LengthGen's output.
    pub fn length_result(&self, f: &features::WalkFeatures, out: &Output) -> u64 {
        f.n_from_target(out[0] as f64, self.n_min())
    }

    /// PathGen: the exit of a walk with N events (N ≥ 2, or any N in learned mode), given
    /// its relative log N.
    pub fn sample_exit(
        &self,
        f: &features::WalkFeatures,
        relative_log_n: f64,
        rng: &mut WalkRng,
    ) -> CanonicalExit {
        let d = self.path_draw(f, relative_log_n, rng);
        self.path_result(&self.path.output(&d))
    }

    /// PathGen's draw for a walk of the given relative log N.
    pub fn path_draw(
        &self,
        f: &features::WalkFeatures,
        relative_log_n: f64,
        rng: &mut WalkRng,
    ) -> Draw {
        draw_with_noise(&self.path, &f.path_cond(relative_log_n), rng)
    }

    /// The exit from PathGen's output.
    pub fn path_result(&self, out: &Output) -> CanonicalExit {
        let v = [out[0], out[1], out[2]].map(f64::from);
        let (cos_theta, beta, alpha) = features::path_from_target(v);
        repair_exit(cos_theta, beta, alpha)
    }

    /// The representative event given the walk's N and exit. In exact mode event 1 (the
    /// centre, W = +z) is chosen analytically with probability φ/Λ(N) and EventGen draws
    /// among events k ≥ 2.
    pub fn sample_event(
        &self,
        tau: f64,
        g: f64,
        albedo: f64,
        n: u64,
        exit: CanonicalExit,
        rng: &mut WalkRng,
    ) -> (DVec3, DVec3) {
        let walk =
            ModelWalk::multiple(n, exit, features::WalkFeatures::new(tau, g, albedo), albedo);
        self.sample_event_given(&walk, rng)
    }

    /// Another representative event of `walk` (its N and exit), independent of the one
    /// it holds.
    pub fn sample_event_given(&self, walk: &ModelWalk, rng: &mut WalkRng) -> (DVec3, DVec3) {
        match self.event_draw(walk, rng) {
            None => CENTRE_EVENT,
            Some(d) => self.event_result(&self.event.output(&d)),
        }
    }

    /// EventGen's draw for another representative event of `walk`, or None when the
    /// exact-mode choice picks event 1 ([`CENTRE_EVENT`], no decoder needed).
    pub fn event_draw(&self, walk: &ModelWalk, rng: &mut WalkRng) -> Option<Draw> {
        if self.centre_event(walk, rng) {
            return None;
        }
        let e = walk.exit;
        let cond = walk
            .features
            .event_cond(walk.relative_log_n, e.cos_theta, e.beta, e.alpha);
        Some(draw_with_noise(&self.event, &cond, rng))
    }

    /// `m` representative-event draws of one walk into `out`, in antithetic pairs: the
    /// second of a pair mirrors the first's noise ([`Decoder::mirrored`]) unless either
    /// is the centre event. Each draw alone has the distribution of [`Self::event_draw`];
    /// only their correlation changes, so an average over them keeps its mean.
    pub fn event_draws(
        &self,
        walk: &ModelWalk,
        m: u32,
        rng: &mut WalkRng,
        out: &mut Vec<Option<Draw>>,
    ) {
        let mut partner: Option<Draw> = None;
        for _ in 0..m {
            let fresh = partner.is_none();
            let d = match partner.take() {
                Some(p) if !self.centre_event(walk, rng) => Some(self.event.mirrored(&p)),
                Some(_) => None,
                None => self.event_draw(walk, rng),
            };
            if fresh {
                partner = d;
            }
            out.push(d);
        }
    }

    /// Exact mode's choice of event 1 (the centre) as the representative event, with its
    /// probability φ/Λ(N); at φ = 0 its limit 1 (φ/Λ(N) → 1 as φ → 0⁺), as the
    /// simulator's reservoir keeps event 1 there.
    fn centre_event(&self, walk: &ModelWalk, rng: &mut WalkRng) -> bool {
        self.single_scattering == SingleScattering::Exact
            && (walk.albedo <= 0.0 || rng.uniform() * walk.lambda < walk.albedo)
    }

    /// The event (X, W) from EventGen's output.
    pub fn event_result(&self, out: &Output) -> (DVec3, DVec3) {
        let v = [out[0], out[1], out[2], out[3], out[4], out[5]].map(f64::from);
        let (x, w) = features::event_from_target(self.event_radial(), v);
        repair_event(DVec3::from_array(x), DVec3::from_array(w))
    }

    /// The exact single-scattering branch: with probability e^(−τ) (exact mode only) the
    /// walk has N = 1 and leaves the centre in the HG direction (x = ω, event 1 at the
    /// centre); None otherwise, and the decoders draw a walk with N ≥ 2.
    pub fn single_walk(
        &self,
        features: features::WalkFeatures,
        tau: f64,
        g: f64,
        albedo: f64,
        rng: &mut WalkRng,
    ) -> Option<ModelWalk> {
        if self.single_scattering != SingleScattering::Exact || rng.uniform() >= (-tau).exp() {
            return None;
        }
        Some(ModelWalk {
            n: 1,
            exit: CanonicalExit {
                cos_theta: hg_sample_cos(g, rng.uniform()),
                alpha: 0.0,
                beta: 0.0,
            },
            event_pos: CENTRE_EVENT.0,
            event_dir: CENTRE_EVENT.1,
            single: true,
            lambda: albedo,
            survival: albedo,
            features,
            relative_log_n: -features.log_prior,
            albedo,
        })
    }

    /// A whole walk. With `with_event` false EventGen is not run (NEE off) and the
    /// event fields hold the centre and +z.
    pub fn sample_walk(
        &self,
        tau: f64,
        g: f64,
        albedo: f64,
        with_event: bool,
        rng: &mut WalkRng,
    ) -> ModelWalk {
        self.sample_walk_checked(tau, g, albedo, with_event, rng).0
    }

    /// [`Self::sample_walk`] (the same draws from `rng`), and whether a decoder's output
    /// was not finite and so repaired ([`repair_exit`], [`repair_event`], N's clamp): a
    /// trained model's never is, but a hand-edited one that passes the model file's
    /// checks can be, and `sample` wrote its repaired exits (cos θ = 1, α = β = 0) as
    /// if drawn.
    pub fn sample_walk_checked(
        &self,
        tau: f64,
        g: f64,
        albedo: f64,
        with_event: bool,
        rng: &mut WalkRng,
    ) -> (ModelWalk, bool) {
        // A decoder's outputs are the first `out` values of its Output.
        let finite = |d: &Decoder, o: &Output| o[..d.out].iter().all(|v| v.is_finite());
        let features = features::WalkFeatures::new(tau, g, albedo);
        if let Some(walk) = self.single_walk(features, tau, g, albedo, rng) {
            return (walk, false);
        }
        let length = self.length.output(&self.length_draw(&features, rng));
        let n = self.length_result(&features, &length);
        let path = self
            .path
            .output(&self.path_draw(&features, features.relative_log_n(n), rng));
        let mut walk = ModelWalk::multiple(n, self.path_result(&path), features, albedo);
        let mut repaired = !finite(&self.length, &length) || !finite(&self.path, &path);
        if with_event && let Some(d) = self.event_draw(&walk, rng) {
            let event = self.event.output(&d);
            repaired |= !finite(&self.event, &event);
            (walk.event_pos, walk.event_dir) = self.event_result(&event);
        }
        (walk, repaired)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The weights equal Λ(N) summed term by term, Σ_{k=1..N} φ^k, and φ^N by powf. The
    /// sum of N positive terms carries a relative rounding error below N·2.2e-16; the
    /// closed forms are a few correctly rounded operations: 1e-12 + N·2.2e-16 relative.
    #[test]
    fn walk_weights_match_lambda_and_power() {
        for &albedo in &[0.0, 0.3, 0.975, 0.99995, 0.99999, 1.0] {
            for &n in &[1u64, 2, 7, 100, 10_000, 1_000_000] {
                let (l, p) = walk_weights(albedo, n);
                let mut term = 1.0f64;
                let mut l0 = 0.0f64;
                for _ in 0..n {
                    term *= albedo;
                    l0 += term;
                }
                let p0 = albedo.powf(n as f64);
                let tol = 1e-12 + n as f64 * 2.2e-16;
                assert!(
                    (l - l0).abs() <= tol * l0.abs().max(1e-300),
                    "Λ({albedo}, {n})"
                );
                assert!(
                    (p - p0).abs() <= 1e-12 * p0.max(1e-300),
                    "φ^N({albedo}, {n}): {p} vs {p0}"
                );
            }
        }
    }
}
