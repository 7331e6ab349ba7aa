//! The importance choice of an exact sphere step's NEE events (see
//! [`super::sphere_step`]): M events of the walk, each picked with probability
//! p_k = φ^k q_k / Q (Q = Σ_j φ^j q_j), where q_k is a cheap proxy of event k's NEE.
//!
//! Events are collected in batches of [`BATCH`]: the proxies of a batch are evaluated in
//! one loop over structure-of-arrays lanes that the compiler vectorises, and the batch is
//! merged into each slot's reservoir with two uniforms. Evaluated one event at a time
//! (a libm `exp` and `powf`, a uniform and an unpredictable branch per event) the proxy
//! and its reservoir took ~10 % of ST-CVAE's time on the bunny at k = 8.

use glam::{DVec3, Vec3};
use scatter_sim::rng::WalkRng;

/// Events per batch: one vector loop of the proxy; an exact walk has ~5 events.
pub(crate) const BATCH: usize = 8;
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
pub(crate) struct Proxy {
    /// Light directions in the walk's frame and irradiances (this channel).
    lights: [(Vec3, f32); MAX_PROXY_LIGHTS],
    n_lights: usize,
    /// q = 1 for every event (a light dark in this channel, or too many lights).
    flat: bool,
    /// The free ball's radius² in units of the walk's sphere (≥ 1).
    f2: f32,
    /// τ·log₂e: the transmittance as a power of two.
    tau_log2e: f32,
    /// HG as c · d^(−3/2) with d = a − b·cos.
    hg_a: f32,
    hg_b: f32,
    hg_c: f32,
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
        let mut n_lights = 0;
        for (slot, (dir, e)) in dirs.iter_mut().zip(lights) {
            // The proxy must be positive wherever the NEE can be.
            flat |= !(e > 0.0);
            *slot = (dir, e);
            n_lights += 1;
        }
        Self {
            lights: dirs,
            n_lights,
            flat,
            f2: f2.max(1.0),
            tau_log2e: tau * std::f32::consts::LOG2_E,
            hg_a: 1.0 + g * g,
            hg_b: 2.0 * g,
            hg_c: (1.0 - g * g) / (4.0 * std::f32::consts::PI),
        }
    }

    /// q for each lane of a batch (all BATCH lanes; unused ones hold harmless zeros).
    #[inline]
    fn eval(&self, b: &Batch, q: &mut [f32; BATCH]) {
        if self.flat {
            *q = [1.0; BATCH];
            return;
        }
        *q = [0.0; BATCH];
        for &(wl, e) in &self.lights[..self.n_lights] {
            let scale = e * self.hg_c;
            for (i, qi) in q.iter_mut().enumerate() {
                let bx = b.x[0][i] * wl.x + b.x[1][i] * wl.y + b.x[2][i] * wl.z;
                let x2 = b.x[0][i] * b.x[0][i] + b.x[1][i] * b.x[1][i] + b.x[2][i] * b.x[2][i];
                let chord = -bx + (bx * bx + (self.f2 - x2).max(0.0)).sqrt();
                let cos = (b.w[0][i] * wl.x + b.w[1][i] * wl.y + b.w[2][i] * wl.z).clamp(-1.0, 1.0);
                let d = (self.hg_a - self.hg_b * cos).max(f32::MIN_POSITIVE);
                *qi += scale * exp2(-self.tau_log2e * chord - 1.5 * log2(d));
            }
        }
    }
}

/// 2^x, clamped to the normal range [2^−126, 2^127]: the exponent bits from x rounded
/// to the nearest integer (by the 1.5·2^23 trick, which vectorises where `floor` needs
/// SSE4.1), 2^f for f ∈ [−0.5, 0.5] from a degree-4 least-squares polynomial (relative
/// error < 4·10⁻⁶).
#[inline]
fn exp2(x: f32) -> f32 {
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
fn log2(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000) - 1.0;
    let p = m
        * (1.441_88
            + m * (-0.708_865_2 + m * (0.415_245_6 + m * (-0.193_516_5 + m * 0.045_268_29))));
    e as f32 + p
}

/// Events waiting for their proxies: positions and directions as lanes for the proxy,
/// and as vectors for the chosen ones.
struct Batch {
    x: [[f32; BATCH]; 3],
    w: [[f32; BATCH]; 3],
    phi: [f64; BATCH],
    events: [(Vec3, Vec3); BATCH],
    len: usize,
}

impl Batch {
    fn empty() -> Self {
        Self {
            x: [[0.0; BATCH]; 3],
            w: [[0.0; BATCH]; 3],
            phi: [0.0; BATCH],
            events: [(Vec3::ZERO, Vec3::ZERO); BATCH],
            len: 0,
        }
    }
}

/// M weighted reservoirs of one event each over a walk's events.
pub(crate) struct EventChoice {
    m: usize,
    batch: Batch,
    /// Q so far.
    total: f64,
    /// (X, W, q) of the event each reservoir holds (q = 0: none yet).
    slots: [(Vec3, Vec3, f32); MAX_EVENTS],
}

impl EventChoice {
    /// `m` reservoirs (at most [`MAX_EVENTS`]; 0 chooses nothing).
    #[inline]
    pub fn new(m: usize) -> Self {
        Self {
            m: m.min(MAX_EVENTS),
            batch: Batch::empty(),
            total: 0.0,
            slots: [(Vec3::ZERO, Vec3::Z, 0.0); MAX_EVENTS],
        }
    }

    /// Offers event (x, w) with survival weight φ^k.
    #[inline]
    pub fn offer(&mut self, x: Vec3, w: Vec3, phi_k: f64, proxy: &Proxy, rng: &mut WalkRng) {
        let b = &mut self.batch;
        let i = b.len;
        for (lane, v) in b.x.iter_mut().zip(x.to_array()) {
            lane[i] = v;
        }
        for (lane, v) in b.w.iter_mut().zip(w.to_array()) {
            lane[i] = v;
        }
        b.phi[i] = phi_k;
        b.events[i] = (x, w);
        b.len += 1;
        if b.len == BATCH {
            self.flush(proxy, rng);
        }
    }

    /// Merges the batch into every reservoir: a slot takes an event of the batch with
    /// probability (the batch's weight)/(Q after it), and then event i with probability
    /// w_i/(the batch's weight), so every event seen so far is held with probability w/Q.
    fn flush(&mut self, proxy: &Proxy, rng: &mut WalkRng) {
        let b = &mut self.batch;
        let len = b.len;
        if len == 0 {
            return;
        }
        b.len = 0;
        if self.m == 0 {
            return;
        }
        let mut q = [0.0f32; BATCH];
        proxy.eval(b, &mut q);
        let mut cumulative = [0.0f64; BATCH];
        let mut sum = 0.0f64;
        for i in 0..len {
            sum += b.phi[i] * q[i] as f64;
            cumulative[i] = sum;
        }
        if !(sum > 0.0) {
            return;
        }
        self.total += sum;
        for slot in &mut self.slots[..self.m] {
            if rng.uniform() * self.total < sum {
                let t = rng.uniform() * sum;
                let i = cumulative[..len]
                    .iter()
                    .position(|&c| t < c)
                    .unwrap_or(len - 1);
                *slot = (b.events[i].0, b.events[i].1, q[i]);
            }
        }
    }

    /// The chosen events with their weights Q/q_K (each slot's estimate of the walk's NEE
    /// is f(X_K)·Q/q_K); two slots holding the same event share one entry with their
    /// weights summed (the estimate is linear in each event's NEE, so one shadow ray
    /// serves both). Returns how many entries `events` and `weights` hold.
    pub fn finish(
        &mut self,
        proxy: &Proxy,
        rng: &mut WalkRng,
        events: &mut [(DVec3, DVec3); MAX_EVENTS],
        weights: &mut [f32; MAX_EVENTS],
    ) -> usize {
        self.flush(proxy, rng);
        let mut used = 0;
        for &(x, w, q) in &self.slots[..self.m] {
            if !(q > 0.0) {
                continue;
            }
            let weight = (self.total / q as f64) as f32;
            let (x, w) = (x.as_dvec3(), w.as_dvec3());
            match events[..used].iter().position(|e| *e == (x, w)) {
                Some(i) => weights[i] += weight,
                None => {
                    (events[used], weights[used]) = ((x, w), weight);
                    used += 1;
                }
            }
        }
        used
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fast 2^x and log₂ x against the standard library over their ranges.
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

    /// The proxy against the direct formula it approximates.
    #[test]
    fn proxy_matches_its_formula() {
        let wl = Vec3::new(0.3, -0.4, 0.866).normalize();
        let (tau, f2, g) = (3.5f32, 1.7f32, 0.875f32);
        let proxy = Proxy::new([(wl, 2.0)].into_iter(), tau, f2, g);
        let mut rng = WalkRng::for_walk(7, 0);
        let mut choice = EventChoice::new(1);
        for _ in 0..BATCH {
            let x = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 0.5;
            let w = DVec3::new(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform()).normalize();
            choice.offer(x.as_vec3(), w.as_vec3(), 1.0, &proxy, &mut rng);
            // offer flushes on the last one; evaluate the lanes before that.
            if choice.batch.len == BATCH - 1 {
                let mut q = [0.0; BATCH];
                proxy.eval(&choice.batch, &mut q);
                for (i, &(x, w)) in choice.batch.events[..BATCH - 1].iter().enumerate() {
                    let b = x.dot(wl);
                    let chord = -b + (b * b + f2 - x.length_squared()).max(0.0).sqrt();
                    let hg = scatter_sim::phase::hg_pdf(g as f64, w.dot(wl) as f64) as f32;
                    let want = 2.0 * hg * (-tau * chord).exp();
                    assert!(
                        (q[i] / want - 1.0).abs() < 1e-4,
                        "lane {i}: {} vs {want}",
                        q[i]
                    );
                }
            }
        }
    }

    /// The reservoirs hold event k with probability w_k/Q, over several batches and with
    /// zero weights among them: a chi-square test of 200,000 choices of one event among 21
    /// (three batches), three of them of weight 0, against those probabilities. With
    /// 18 − 1 = 17 degrees of freedom the statistic exceeds 40.8 with probability 0.1 %;
    /// a wrong merge probability (e.g. the batch's weight over Q before it) moves whole
    /// batches by a third and fails by far (χ² ≈ 1.7·10⁵).
    #[test]
    fn events_are_chosen_in_proportion_to_their_weights() {
        let wl = Vec3::Z;
        let proxy = Proxy::new([(wl, 1.0)].into_iter(), 2.0, 1.0, 0.5);
        // Events on the z axis looking in various directions: their proxies differ.
        let events: Vec<(DVec3, DVec3, f64)> = (0..21)
            .map(|k| {
                let z = -0.9 + 1.8 * (k as f64) / 20.0;
                let c = (k as f64 * 0.7).cos();
                let w = DVec3::new((1.0 - c * c).sqrt(), 0.0, c);
                let phi = if k % 7 == 3 { 0.0 } else { 0.9f64.powi(k + 1) };
                (DVec3::new(0.0, 0.0, z), w, phi)
            })
            .collect();
        let mut weights = Vec::new();
        for &(x, w, phi) in &events {
            let mut b = Batch::empty();
            for (lane, v) in b.x.iter_mut().zip(x.as_vec3().to_array()) {
                lane[0] = v;
            }
            for (lane, v) in b.w.iter_mut().zip(w.as_vec3().to_array()) {
                lane[0] = v;
            }
            let mut q = [0.0; BATCH];
            proxy.eval(&b, &mut q);
            weights.push(phi * q[0] as f64);
        }
        let total: f64 = weights.iter().sum();
        let n = 200_000;
        let mut counts = vec![0u64; events.len()];
        let mut rng = WalkRng::for_walk(11, 0);
        for _ in 0..n {
            let mut choice = EventChoice::new(1);
            for &(x, w, phi) in &events {
                choice.offer(x.as_vec3(), w.as_vec3(), phi, &proxy, &mut rng);
            }
            let mut out = [(DVec3::ZERO, DVec3::Z); MAX_EVENTS];
            let mut wts = [0.0; MAX_EVENTS];
            let used = choice.finish(&proxy, &mut rng, &mut out, &mut wts);
            assert_eq!(used, 1);
            let k = events
                .iter()
                .position(|e| (e.0.as_vec3().as_dvec3(), e.1.as_vec3().as_dvec3()) == out[0])
                .unwrap();
            // The weight is Q/q_K, so f·weight has expectation Σ φ^k f_k.
            let q_k = weights[k] / events[k].2;
            assert!((wts[0] as f64 / (total / q_k) - 1.0).abs() < 1e-5);
            counts[k] += 1;
        }
        let (mut observed, mut expected) = (Vec::new(), Vec::new());
        for (k, &c) in counts.iter().enumerate() {
            if weights[k] == 0.0 {
                assert_eq!(c, 0, "event {k} has weight 0 but was chosen");
                continue;
            }
            observed.push(c);
            expected.push(n as f64 * weights[k] / total);
        }
        let chi2 = scatter_sim::stats::chi_square(&observed, &expected);
        assert!(chi2 < 40.8, "chi-square {chi2} with 17 degrees of freedom");
    }
}
