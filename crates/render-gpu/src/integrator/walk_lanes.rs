//! The walks of exact sphere steps (see [`super::sphere_step`]), [`LANES`] at a time:
//! each lane simulates one walk, and a lane whose walk has left its sphere takes the next
//! waiting walk. Once none is waiting the batch runs on until its last walk ends: on the
//! bunny ladder that tail is 43–50 % of the lane iterations at ~21 % of the lanes busy,
//! yet keeping its walks in the lanes for the next batch gained ≤ 1 % (an iteration costs
//! the same vector instructions however many lanes are idle; docs/BENCHMARKS.md,
//! twenty-third session), so a batch ends here.
//!
//! One walk is a serial chain (each direction depends on the last) of a few to a few
//! dozen events, whose latencies — a division in the basis, a logarithm, the rejection
//! loop of the azimuth and its mispredicted branches — left a core mostly idle: at k = 8 on
//! the bunny the walks (then ~5 events each) and their NEE event choice were a quarter of
//! ST-CVAE's time, done one walk at a time. Here every operation of
//! an event is written branch-free over the lanes (the azimuth from a polynomial sine
//! instead of rejection, the logarithm from a polynomial), so that the compiler turns
//! each into vector instructions, and the lanes' chains hide each other's latencies.
//!
//! Each walk draws from its own xoshiro256++ stream, seeded from its path's stream, so a
//! walk's outcome does not depend on which walks share its batch.
//!
//! NEE: the walk's events (the centre first) are offered to `m` weighted reservoirs with
//! weight φ^k·q_k ([`Proxy`]), exactly as the event choice of design §4 describes; a slot
//! holds event k with probability φ^k q_k / Q (Q = Σ_j φ^j q_j).

// Loops over a lane index that address several arrays at once are the form the
// compiler vectorises; iterator chains over zipped arrays hide that.
#![allow(clippy::needless_range_loop)]

use glam::Vec3;
use scatter_sim::rng::splitmix64;

use super::event_choice::{MAX_EVENTS, MAX_PROXY_LIGHTS, Proxy, exp2, log2};

/// Walks simulated side by side.
pub(crate) const LANES: usize = 16;

/// 2^−24 and 2^−31: integers to [0, 1). (Conversions go through i32, which vector units
/// convert directly.)
const INV_2_24: f32 = 1.0 / 16_777_216.0;
const INV_2_31: f32 = 1.0 / 2_147_483_648.0;

/// One walk to simulate: in the unit sphere of optical radius τ, from the centre arriving
/// along +z.
#[derive(Clone, Copy)]
pub(crate) struct WalkJob {
    pub tau: f32,
    /// Single-scattering albedo φ (in the path's channel).
    pub albedo: f32,
    /// Seeds the walk's own random stream.
    pub seed: u64,
    /// The NEE proxy of the walk's events (unused when no reservoirs are asked for).
    pub proxy: Proxy,
}

/// How a walk ended.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WalkOutcome {
    /// Scattering events, the centre included (N ≥ 1).
    pub n: u32,
    /// Exit point (|x| = 1) and direction (unit, outward).
    pub exit_pos: Vec3,
    pub exit_dir: Vec3,
    /// Q, the sum of the offered events' weights φ^k q_k.
    pub total: f32,
    /// Each reservoir's event (X, W, q); q = 0: none.
    pub slots: [(Vec3, Vec3, f32); MAX_EVENTS],
}

impl Default for WalkOutcome {
    fn default() -> Self {
        Self {
            n: 1,
            exit_pos: Vec3::Z,
            exit_dir: Vec3::Z,
            total: 0.0,
            slots: [(Vec3::ZERO, Vec3::Z, 0.0); MAX_EVENTS],
        }
    }
}

/// What all walks of a batch share: the phase function's g, and the reservoirs per walk
/// and the lights their proxy weighs.
#[derive(Clone, Copy)]
pub(crate) struct WalkShared {
    pub g: f32,
    /// Reservoirs per walk (0: no NEE, nothing offered).
    pub m: usize,
    /// Lights in each job's proxy.
    pub n_lights: usize,
}

/// Simulates every job, writing `out[i]` for `jobs[i]`.
pub(crate) fn simulate(jobs: &[WalkJob], shared: &WalkShared, out: &mut [WalkOutcome]) {
    assert_eq!(jobs.len(), out.len(), "one outcome per walk");
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports these features (checked just above).
            unsafe { simulate_avx512(jobs, shared, out) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above).
            unsafe { simulate_avx2(jobs, shared, out) };
            return;
        }
    }
    simulate_lanes(jobs, shared, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
fn simulate_avx512(jobs: &[WalkJob], shared: &WalkShared, out: &mut [WalkOutcome]) {
    simulate_lanes(jobs, shared, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn simulate_avx2(jobs: &[WalkJob], shared: &WalkShared, out: &mut [WalkOutcome]) {
    simulate_lanes(jobs, shared, out);
}

type F = [f32; LANES];

/// The lanes' state, structure of arrays.
struct Lanes {
    /// The job each lane runs (usize::MAX: idle).
    job: [usize; LANES],
    rng: [[u64; LANES]; 4],
    pos: [F; 3],
    dir: [F; 3],
    n: [u32; LANES],
    inv_tau: F,
    albedo: F,
    /// φ^k of the last event.
    phi: F,
    total: F,
    /// The proxy's constants per lane: lights (direction, E·(1 − g²)/4π), τ·log₂e, the
    /// free ball's radius², and 1 where the proxy is flat (q = 1).
    light_dir: [[F; 3]; MAX_PROXY_LIGHTS],
    light_e: [F; MAX_PROXY_LIGHTS],
    tau_log2e: F,
    f2: F,
    flat: F,
    /// The reservoirs: X, W, q.
    slot_x: [[F; 3]; MAX_EVENTS],
    slot_w: [[F; 3]; MAX_EVENTS],
    slot_q: [F; MAX_EVENTS],
}

/// The proxy's HG constants, shared by all lanes (see [`Proxy`]).
#[derive(Clone, Copy)]
struct Hg {
    a: f32,
    b: f32,
}

#[inline(always)]
fn simulate_lanes(jobs: &[WalkJob], shared: &WalkShared, out: &mut [WalkOutcome]) {
    let g = shared.g;
    let hg = Hg {
        a: 1.0 + g * g,
        b: 2.0 * g,
    };
    let n_lights = shared.n_lights.min(MAX_PROXY_LIGHTS);
    let m = shared.m.min(MAX_EVENTS);
    let zero = [0.0; LANES];
    let mut st = Lanes {
        job: [usize::MAX; LANES],
        rng: [[1; LANES]; 4],
        pos: [zero; 3],
        dir: [zero; 3],
        n: [1; LANES],
        inv_tau: [1.0; LANES],
        albedo: zero,
        phi: zero,
        total: zero,
        light_dir: [[zero; 3]; MAX_PROXY_LIGHTS],
        light_e: [zero; MAX_PROXY_LIGHTS],
        tau_log2e: zero,
        f2: [1.0; LANES],
        flat: zero,
        slot_x: [[zero; 3]; MAX_EVENTS],
        slot_w: [[zero; 3]; MAX_EVENTS],
        slot_q: [zero; MAX_EVENTS],
    };
    let mut next_job = 0;
    for lane in 0..LANES {
        if next_job < jobs.len() {
            load(&mut st, lane, next_job, &jobs[next_job], &hg, n_lights, m);
            next_job += 1;
        }
    }
    let mut busy = jobs.len().min(LANES);
    let g64 = g as f64;
    while busy > 0 {
        let exited = event(&mut st, g64, &hg, n_lights, m);
        for lane in 0..LANES {
            let j = st.job[lane];
            if !exited[lane] || j == usize::MAX {
                continue;
            }
            out[j] = finish(&st, lane, m);
            if next_job < jobs.len() {
                load(&mut st, lane, next_job, &jobs[next_job], &hg, n_lights, m);
                next_job += 1;
            } else {
                st.job[lane] = usize::MAX;
                busy -= 1;
            }
        }
    }
}

/// Starts `job` in `lane`: its stream, the centre event (X = 0, W = +z, φ^1) offered to
/// its reservoirs.
#[inline(always)]
fn load(
    st: &mut Lanes,
    lane: usize,
    index: usize,
    job: &WalkJob,
    hg: &Hg,
    n_lights: usize,
    m: usize,
) {
    st.job[lane] = index;
    let mut z = job.seed;
    for word in 0..4 {
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        st.rng[word][lane] = splitmix64(z);
    }
    // xoshiro forbids the all-zero state (four splitmix outputs all zero: never, but cheap).
    if (0..4).all(|w| st.rng[w][lane] == 0) {
        st.rng[0][lane] = 1;
    }
    for a in 0..3 {
        st.pos[a][lane] = 0.0;
        st.dir[a][lane] = if a == 2 { 1.0 } else { 0.0 };
    }
    st.n[lane] = 1;
    st.inv_tau[lane] = 1.0 / job.tau;
    st.albedo[lane] = job.albedo;
    st.phi[lane] = job.albedo;
    let p = &job.proxy;
    for l in 0..MAX_PROXY_LIGHTS {
        let (d, e) = p.lights[l];
        st.light_dir[l][0][lane] = d.x;
        st.light_dir[l][1][lane] = d.y;
        st.light_dir[l][2][lane] = d.z;
        st.light_e[l][lane] = e * p.hg_c;
    }
    st.tau_log2e[lane] = p.tau_log2e;
    st.f2[lane] = p.f2;
    st.flat[lane] = if p.flat { 1.0 } else { 0.0 };
    let q = if m > 0 {
        proxy_q(st, lane, [0.0; 3], [0.0, 0.0, 1.0], hg, n_lights)
    } else {
        0.0
    };
    let w = job.albedo * q;
    st.total[lane] = w;
    for s in 0..m {
        // The first offer always fills a slot (when its weight is positive).
        let take = w > 0.0;
        st.slot_x[s].iter_mut().for_each(|c| c[lane] = 0.0);
        st.slot_w[s][0][lane] = 0.0;
        st.slot_w[s][1][lane] = 0.0;
        st.slot_w[s][2][lane] = 1.0;
        st.slot_q[s][lane] = if take { q } else { 0.0 };
    }
}

/// Lane `lane`'s finished walk.
#[inline(always)]
fn finish(st: &Lanes, lane: usize, m: usize) -> WalkOutcome {
    let v = |a: &[F; 3]| Vec3::new(a[0][lane], a[1][lane], a[2][lane]);
    let mut out = WalkOutcome {
        n: st.n[lane],
        // `event` leaves an exited lane's exit point in `pos` and its direction in `dir`.
        exit_pos: v(&st.pos),
        exit_dir: v(&st.dir),
        total: st.total[lane],
        ..WalkOutcome::default()
    };
    for s in 0..m {
        out.slots[s] = (v(&st.slot_x[s]), v(&st.slot_w[s]), st.slot_q[s][lane]);
    }
    out
}

/// The proxy q of event (x, w) of `lane` (see [`Proxy`]).
#[inline(always)]
fn proxy_q(st: &Lanes, lane: usize, x: [f32; 3], w: [f32; 3], hg: &Hg, n_lights: usize) -> f32 {
    let x2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
    let mut q = 0.0;
    for l in 0..n_lights {
        let ld = &st.light_dir[l];
        let wl = [ld[0][lane], ld[1][lane], ld[2][lane]];
        let (e, f2, tau) = (st.light_e[l][lane], st.f2[lane], st.tau_log2e[lane]);
        q += light_term(x, x2, w, wl, e, f2, tau, hg);
    }
    if st.flat[lane] > 0.0 { 1.0 } else { q }
}

/// One light's term of the proxy: E·ρ_g(W·ω_l)·2^(−τ log₂e · chord of the free ball of
/// radius² `f2` from X along ω_l), with ρ_g = c·(a − b cos)^(−3/2) and E holding c.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn light_term(
    x: [f32; 3],
    x2: f32,
    w: [f32; 3],
    wl: [f32; 3],
    e: f32,
    f2: f32,
    tau_log2e: f32,
    hg: &Hg,
) -> f32 {
    let bx = x[0] * wl[0] + x[1] * wl[1] + x[2] * wl[2];
    let chord = -bx + (bx * bx + (f2 - x2).max(0.0)).sqrt();
    let cos = (w[0] * wl[0] + w[1] * wl[1] + w[2] * wl[2]).clamp(-1.0, 1.0);
    let d = (hg.a - hg.b * cos).max(f32::MIN_POSITIVE);
    e * exp2(-tau_log2e * chord - 1.5 * log2(d))
}

/// xoshiro256++ on every lane's stream (the generator of `rand_xoshiro`'s
/// `Xoshiro256PlusPlus`, checked against it in the tests).
#[inline(always)]
fn next_u64(s: &mut [[u64; LANES]; 4]) -> [u64; LANES] {
    let mut out = [0u64; LANES];
    for i in 0..LANES {
        out[i] = s[0][i]
            .wrapping_add(s[3][i])
            .rotate_left(23)
            .wrapping_add(s[0][i]);
        let t = s[1][i] << 17;
        s[2][i] ^= s[0][i];
        s[3][i] ^= s[1][i];
        s[1][i] ^= s[2][i];
        s[0][i] ^= s[3][i];
        s[2][i] ^= t;
        s[3][i] = s[3][i].rotate_left(45);
    }
    out
}

/// ln x for positive normal x: x = 2^e·m with m ∈ [√½, √2), ln m = 2 artanh s with
/// s = (m − 1)/(m + 1), |s| ≤ 0.172, from its series to s⁹ (truncation < 10⁻⁹; the
/// result is as accurate as f32 allows).
#[inline(always)]
fn ln(x: f32) -> f32 {
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let big = m > std::f32::consts::SQRT_2;
    m = if big { 0.5 * m } else { m };
    e += big as i32;
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let series = 1.0 + s2 * (1.0 / 3.0 + s2 * (0.2 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0))));
    e as f32 * std::f32::consts::LN_2 + 2.0 * s * series
}

/// (cos 2πv, sin 2πv) for v ∈ [0, 1): the quarter turn from v, the angle within it as
/// π/4 + x with |x| ≤ π/4, and x's sine and cosine from their Taylor series to x⁹ and
/// x⁸ (truncation < 3·10⁻⁸).
#[inline(always)]
fn cos_sin_turn(v: f32) -> (f32, f32) {
    let t = v * 4.0;
    let quarter = (t as i32).min(3);
    let x = (t - quarter as f32 - 0.5) * std::f32::consts::FRAC_PI_2;
    let x2 = x * x;
    let sin = x
        * (1.0
            + x2 * (-1.0 / 6.0
                + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 * (1.0 / 362_880.0)))));
    let cos = 1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0 + x2 * (1.0 / 40_320.0))));
    // The angle π/4 + x.
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let (c, s) = (h * (cos - sin), h * (cos + sin));
    // Turned by `quarter` quarter turns: one by bit 0, two (a sign flip) by bit 1.
    let (c, s) = if quarter & 1 != 0 { (-s, c) } else { (c, s) };
    if quarter & 2 != 0 { (-c, -s) } else { (c, s) }
}

/// One event of every lane's walk: a deflection and a flight. A lane whose flight leaves
/// its sphere is marked in the result, with its exit point in `pos` and its direction in
/// `dir`; the others move to their next event, which is offered to their reservoirs.
/// Idle lanes compute along harmlessly. Written as several loops over the lanes, each
/// free of inner loops and branches, which is what the compiler vectorises.
#[inline(always)]
fn event(st: &mut Lanes, g: f64, hg: &Hg, n_lights: usize, m: usize) -> [bool; LANES] {
    let b1 = next_u64(&mut st.rng);
    let b2 = next_u64(&mut st.rng);
    // The deflection's cos θ and azimuth, and the flight, from the draws: ξ from b1's high
    // bits, the flight's uniform in (0, 1] from its low half, the azimuth from b2's high
    // bits (its low half: the first reservoir's uniform).
    let mut cos_theta = [0.0f32; LANES];
    let mut sin_theta = [0.0f32; LANES];
    let mut flight = [0.0f32; LANES];
    let mut cos_psi = [0.0f32; LANES];
    let mut sin_psi = [0.0f32; LANES];
    for i in 0..LANES {
        let xi = (b1[i] >> 40) as i32 as f32 * INV_2_24;
        let u = (((b1[i] as u32) >> 1) as i32 as f32 + 1.0) * INV_2_31;
        let v = (b2[i] >> 40) as i32 as f32 * INV_2_24;
        // In f64: the inverse CDF cancels for small |g|; and sin θ from it, which f32's
        // 1 − cos² θ holds to ~10 % in the lobe of g = 0.999 (1 − cos θ ~ 5e-7).
        let c = scatter_sim::phase::hg_sample_cos(g, xi as f64);
        cos_theta[i] = c as f32;
        sin_theta[i] = ((1.0 - c) * (1.0 + c)).max(0.0).sqrt() as f32;
        (cos_psi[i], sin_psi[i]) = cos_sin_turn(v);
        flight[i] = -ln(u) * st.inv_tau[i];
    }
    // The new direction: Duff et al. (2017)'s branchless orthonormal basis about the
    // arriving direction, then one Newton step toward unit length.
    let mut d = [[0.0f32; LANES]; 3];
    for i in 0..LANES {
        let (dx, dy, dz) = (st.dir[0][i], st.dir[1][i], st.dir[2][i]);
        let sign = 1.0f32.copysign(dz);
        let a = -1.0 / (sign + dz);
        let b = dx * dy * a;
        let (cp, sp) = (cos_psi[i] * sin_theta[i], sin_psi[i] * sin_theta[i]);
        let x = dx * cos_theta[i] + (1.0 + sign * dx * dx * a) * cp + b * sp;
        let y = dy * cos_theta[i] + sign * b * cp + (sign + dy * dy * a) * sp;
        let z = dz * cos_theta[i] - sign * dx * cp - dy * sp;
        let norm = 1.5 - 0.5 * (x * x + y * y + z * z);
        (d[0][i], d[1][i], d[2][i]) = (x * norm, y * norm, z * norm);
    }
    // The flight: to the next event, or out through the sphere.
    let mut exited = [false; LANES];
    let mut next = [[0.0f32; LANES]; 3];
    for i in 0..LANES {
        let p = [st.pos[0][i], st.pos[1][i], st.pos[2][i]];
        let dd = [d[0][i], d[1][i], d[2][i]];
        let f = flight[i];
        let nx = [p[0] + dd[0] * f, p[1] + dd[1] * f, p[2] + dd[2] * f];
        let r2 = nx[0] * nx[0] + nx[1] * nx[1] + nx[2] * nx[2];
        // A flight of 2 or more crosses the unit sphere from anywhere inside; testing it
        // first also catches an infinite flight before it makes NaNs.
        let out = !(f < 2.0) | (r2 >= 1.0);
        // Where the flight crosses the sphere: t² + 2bt + c = 0 with c = |p|² − 1 ≤ 0.
        let bd = p[0] * dd[0] + p[1] * dd[1] + p[2] * dd[2];
        let cc = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] - 1.0;
        let te = -bd + (bd * bd - cc).max(0.0).sqrt();
        let e = [p[0] + dd[0] * te, p[1] + dd[1] * te, p[2] + dd[2] * te];
        let inv = 1.0 / (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        for c in 0..3 {
            next[c][i] = nx[c];
            st.pos[c][i] = if out { e[c] * inv } else { nx[c] };
            st.dir[c][i] = dd[c];
        }
        exited[i] = out;
        st.n[i] += (!out) as u32;
        let phi = st.phi[i] * st.albedo[i];
        st.phi[i] = if out { st.phi[i] } else { phi };
    }
    if m == 0 {
        return exited;
    }
    // The proxy of each moved lane's new event, light by light.
    let mut q = [0.0f32; LANES];
    let mut x2 = [0.0f32; LANES];
    for i in 0..LANES {
        x2[i] = next[0][i] * next[0][i] + next[1][i] * next[1][i] + next[2][i] * next[2][i];
    }
    for l in 0..n_lights {
        let (ld, le) = (&st.light_dir[l], &st.light_e[l]);
        for i in 0..LANES {
            let x = [next[0][i], next[1][i], next[2][i]];
            let w = [d[0][i], d[1][i], d[2][i]];
            let wl = [ld[0][i], ld[1][i], ld[2][i]];
            q[i] += light_term(x, x2[i], w, wl, le[i], st.f2[i], st.tau_log2e[i], hg);
        }
    }
    // Each reservoir takes the event with probability w/Q after it (Q: the lane's total).
    let mut w = [0.0f32; LANES];
    for i in 0..LANES {
        q[i] = if st.flat[i] > 0.0 { 1.0 } else { q[i] };
        w[i] = if exited[i] { 0.0 } else { st.phi[i] * q[i] };
        st.total[i] += w[i];
    }
    let mut uniform = [0.0f32; LANES];
    for s in 0..m {
        if s == 0 {
            for i in 0..LANES {
                uniform[i] = ((b2[i] as u32) >> 8) as i32 as f32 * INV_2_24;
            }
        } else {
            let bits = next_u64(&mut st.rng);
            for i in 0..LANES {
                uniform[i] = (bits[i] >> 40) as i32 as f32 * INV_2_24;
            }
        }
        for i in 0..LANES {
            let take = uniform[i] * st.total[i] < w[i];
            offer(
                st,
                s,
                i,
                take,
                [next[0][i], next[1][i], next[2][i]],
                [d[0][i], d[1][i], d[2][i]],
                q[i],
            );
        }
    }
    exited
}

/// Reservoir `s` of lane `i` takes event (x, w, q) when `take`.
#[inline(always)]
fn offer(st: &mut Lanes, s: usize, i: usize, take: bool, x: [f32; 3], w: [f32; 3], q: f32) {
    for c in 0..3 {
        st.slot_x[s][c][i] = if take { x[c] } else { st.slot_x[s][c][i] };
        st.slot_w[s][c][i] = if take { w[c] } else { st.slot_w[s][c][i] };
    }
    st.slot_q[s][i] = if take { q } else { st.slot_q[s][i] };
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use rand::{Rng, SeedableRng};
    use scatter_sim::rng::WalkRng;

    use super::*;

    /// A job at optical radius `tau` with one light (or a flat proxy when `e` = 0).
    fn job(tau: f32, albedo: f32, seed: u64, g: f32, light: (Vec3, f32), f2: f32) -> WalkJob {
        WalkJob {
            tau,
            albedo,
            seed,
            proxy: Proxy::new([light].into_iter(), tau, f2, g),
        }
    }

    fn run(jobs: &[WalkJob], shared: &WalkShared) -> Vec<WalkOutcome> {
        let mut out = vec![WalkOutcome::default(); jobs.len()];
        simulate(jobs, shared, &mut out);
        out
    }

    /// The lanes' generator is xoshiro256++: the same numbers as `rand_xoshiro`'s from the
    /// same state, in every lane.
    #[test]
    fn lane_generator_is_xoshiro256plusplus() {
        let mut state = [[0u64; LANES]; 4];
        let mut reference = Vec::new();
        for lane in 0..LANES {
            let mut bytes = [0u8; 32];
            for (w, chunk) in bytes.chunks_exact_mut(8).enumerate() {
                let word = splitmix64(lane as u64 * 4 + w as u64);
                state[w][lane] = word;
                chunk.copy_from_slice(&word.to_le_bytes());
            }
            reference.push(rand_xoshiro::Xoshiro256PlusPlus::from_seed(bytes));
        }
        for _ in 0..1000 {
            let ours = next_u64(&mut state);
            for (lane, r) in reference.iter_mut().enumerate() {
                assert_eq!(ours[lane], r.next_u64(), "lane {lane}");
            }
        }
    }

    /// The polynomial ln and turn against the standard library. Their series are truncated
    /// below f32's precision (< 10⁻⁹ and < 3·10⁻⁸), so what is left is f32 rounding: ln
    /// within 2·10⁻⁷ relative (~2 ulp), cos and sin within 3·10⁻⁷ absolute (~2–3 ulp of
    /// values up to 1 after a dozen operations); a wrong term of a series errs by 10⁻⁵ or
    /// more.
    #[test]
    fn ln_and_turn_are_accurate() {
        for i in 0..=100_000 {
            let x = (i as f32 + 1.0) / 100_001.0;
            let x = x * x * x;
            let err = ln(x) - x.ln();
            assert!(
                err.abs() <= 2e-7 * x.ln().abs().max(1.0),
                "ln({x}): error {err}"
            );
        }
        for i in 0..100_000 {
            let v = i as f32 / 100_000.0;
            let (c, s) = cos_sin_turn(v);
            let a = std::f64::consts::TAU * v as f64;
            assert!((c as f64 - a.cos()).abs() < 3e-7, "cos at {v}: {c}");
            assert!((s as f64 - a.sin()).abs() < 3e-7, "sin at {v}: {s}");
        }
    }

    /// One light's proxy term against the formula it evaluates with its polynomials.
    #[test]
    fn light_term_matches_its_formula() {
        let (tau, f2, g) = (3.5f32, 1.7f32, 0.875f32);
        let wl = Vec3::new(0.3, -0.4, 0.866).normalize();
        let proxy = Proxy::new([(wl, 2.0)].into_iter(), tau, f2, g);
        let hg = Hg {
            a: 1.0 + g * g,
            b: 2.0 * g,
        };
        let mut rng = WalkRng::for_walk(7, 0);
        for _ in 0..1000 {
            let x = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 0.5;
            let w = DVec3::new(
                rng.uniform() - 0.5,
                rng.uniform() - 0.5,
                rng.uniform() - 0.3,
            );
            let (x, w) = (x.as_vec3(), w.normalize().as_vec3());
            let q = light_term(
                x.to_array(),
                x.length_squared(),
                w.to_array(),
                wl.to_array(),
                2.0 * proxy.hg_c,
                proxy.f2,
                proxy.tau_log2e,
                &hg,
            );
            let b = x.dot(wl);
            let chord = -b + (b * b + f2 - x.length_squared()).max(0.0).sqrt();
            let rho = scatter_sim::phase::hg_pdf(g as f64, w.dot(wl) as f64) as f32;
            let want = 2.0 * rho * (-tau * chord).exp();
            assert!((q / want - 1.0).abs() < 1e-4, "{q} vs {want}");
        }
    }

    /// The lanes' walks against the simulator's f64 walk, an independent implementation of
    /// the same process: the distribution of N (chi-square over N = 1..11 and a tail bin)
    /// and of the exit's cos θ to +z and of the exit direction's cos to the exit normal
    /// (two-sample Kolmogorov–Smirnov), for forward (g = 0.875) and isotropic scattering,
    /// 40,000 walks each, up to τ = 18 (near the default `exact_tau`, where N is counted
    /// in bins of 8 events). Twelve tests (four media, each a chi-square and two KS), each
    /// at a false-alarm rate of 10⁻⁴, ~1.2·10⁻³ in all (at 0.1 % each it was 1.2 %): the
    /// chi-square with 11 degrees of freedom (two samples: the statistic Σ (a − b)²/(a + b))
    /// exceeds 37.4 with probability 10⁻⁴; the KS distance of two samples of n exceeds
    /// 2.23·√(2/n) = 0.0158 with probability 10⁻⁴. Flights 5 % too long or azimuths over
    /// half a turn each fail the N test by far.
    #[test]
    fn lane_walks_match_the_simulator() {
        let n = 40_000;
        for &(tau, g) in &[(4.0f32, 0.875f32), (3.0, 0.0), (7.5, 0.875), (18.0, 0.875)] {
            let bin = |n: u32| ((n as usize - 1) / if tau > 10.0 { 8 } else { 1 }).min(11);
            let shared = WalkShared {
                g,
                m: 0,
                n_lights: 0,
            };
            let seed = tau.to_bits() as u64 ^ g.to_bits() as u64;
            let jobs: Vec<WalkJob> = (0..n)
                .map(|i| job(tau, 1.0, splitmix64(seed ^ i), g, (Vec3::Z, 0.0), 1.0))
                .collect();
            let mut ours = (vec![0u64; 12], Vec::new(), Vec::new());
            for e in run(&jobs, &shared) {
                ours.0[bin(e.n)] += 1;
                ours.1.push(e.exit_pos.z as f64);
                ours.2.push(e.exit_pos.dot(e.exit_dir) as f64);
            }
            let mut rng = WalkRng::for_walk(5, seed);
            let mut theirs = (vec![0u64; 12], Vec::new(), Vec::new());
            for _ in 0..n {
                let e = scatter_sim::walk_with(tau as f64, g as f64, &mut rng, |_, _, _, _| {});
                theirs.0[bin(e.n as u32)] += 1;
                theirs.1.push(e.exit_pos.z);
                theirs.2.push(e.exit_pos.dot(e.exit_dir));
            }
            let chi2: f64 = ours
                .0
                .iter()
                .zip(&theirs.0)
                .filter(|(a, b)| **a + **b > 0)
                .map(|(&a, &b)| (a as f64 - b as f64).powi(2) / (a + b) as f64)
                .sum();
            assert!(chi2 < 37.4, "τ {tau}, g {g}: N chi-square {chi2}");
            for (a, b, what) in [
                (&mut ours.1, &mut theirs.1, "exit cos θ"),
                (&mut ours.2, &mut theirs.2, "exit direction"),
            ] {
                let d = scatter_sim::stats::ks_two_sample(a, b);
                assert!(d < 0.0158, "τ {tau}, g {g}: {what} KS distance {d}");
            }
        }
    }

    /// The reservoirs' NEE estimate is unbiased: with f = q·h for a positive h, each
    /// slot's estimate f(X_K)·Q/q_K = h(X_K)·Q must have the mean of Σ_k φ^k f(X_k, W_k)
    /// over the simulator's walks (every event summed, q by its direct formula), for one
    /// reservoir and for two. 400,000 walks each side: the estimate's relative spread is
    /// 3.2 a walk on both sides (measured), so the difference of the means is known to
    /// 0.72 %; |z| < 4.5 (a false alarm ~10⁻⁵). A slot that took an event with probability
    /// w/Q before it instead of after is 7 % off (z ≈ 9.7); one that ignored φ^k, 25 %
    /// (z ≈ 35).
    #[test]
    fn reservoir_estimates_are_unbiased() {
        let (tau, g, albedo, f2) = (4.0f32, 0.875f32, 0.9f32, 1.7f32);
        let wl = Vec3::new(0.3, -0.4, 0.866).normalize();
        // Larger far from the centre: a choice leaning to late (outer) events shows.
        let h = |x: Vec3| 1.1 + x.z + 2.0 * x.length_squared();
        let n = 400_000;
        for m in [1usize, 2] {
            let shared = WalkShared { g, m, n_lights: 1 };
            let jobs: Vec<WalkJob> = (0..n)
                .map(|i| {
                    job(
                        tau,
                        albedo,
                        splitmix64(i ^ (m as u64) << 40),
                        g,
                        (wl, 2.0),
                        f2,
                    )
                })
                .collect();
            let ours: Vec<f64> = run(&jobs, &shared)
                .iter()
                .map(|e| {
                    let slots = &e.slots[..m];
                    assert!(slots.iter().all(|s| s.2 > 0.0), "every slot holds an event");
                    slots.iter().map(|s| (h(s.0) * e.total) as f64).sum::<f64>() / m as f64
                })
                .collect();
            let q = |x: DVec3, w: DVec3| {
                let wl = wl.as_dvec3();
                let b = x.dot(wl);
                let chord = -b + (b * b + f2 as f64 - x.length_squared()).max(0.0).sqrt();
                2.0 * scatter_sim::phase::hg_pdf(g as f64, w.dot(wl)) * (-tau as f64 * chord).exp()
            };
            let mut rng = WalkRng::for_walk(13, m as u64);
            let theirs: Vec<f64> = (0..n)
                .map(|_| {
                    let a = albedo as f64;
                    let mut sum = a * q(DVec3::ZERO, DVec3::Z) * h(Vec3::ZERO) as f64;
                    let mut phi = a;
                    scatter_sim::walk_with(tau as f64, g as f64, &mut rng, |_, x, w, _| {
                        phi *= a;
                        sum += phi * q(x, w) * h(x.as_vec3()) as f64;
                    });
                    sum
                })
                .collect();
            let stats = |v: &[f64]| {
                let mean = v.iter().sum::<f64>() / v.len() as f64;
                let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
                (mean, var / v.len() as f64)
            };
            let ((a, va), (b, vb)) = (stats(&ours), stats(&theirs));
            let z = (a - b) / (va + vb).sqrt();
            assert!(z.abs() < 4.5, "m {m}: {a} vs {b}, z {z}");
        }
    }

    /// Events stay inside the unit sphere and the exit on it, with unit directions; a
    /// walk's outcome does not depend on the walks it shares lanes with; and the vector
    /// code gives the plain code's outcomes bit for bit.
    #[test]
    fn walks_are_well_formed_and_independent_of_their_batch() {
        let shared = WalkShared {
            g: 0.9,
            m: MAX_EVENTS,
            n_lights: 1,
        };
        let light = (Vec3::new(0.0, 0.6, 0.8), 1.0);
        let jobs: Vec<WalkJob> = (0..5000)
            .map(|i| job(0.5 + (i % 13) as f32, 0.99, i, 0.9, light, 1.3))
            .collect();
        let all = run(&jobs, &shared);
        let mut plain = vec![WalkOutcome::default(); jobs.len()];
        simulate_lanes(&jobs, &shared, &mut plain);
        for (i, e) in all.iter().enumerate() {
            assert!(e.n >= 1);
            assert!(
                (e.exit_pos.length() - 1.0).abs() < 1e-5,
                "exit {}",
                e.exit_pos
            );
            assert!((e.exit_dir.length() - 1.0).abs() < 1e-5);
            assert!(e.exit_pos.dot(e.exit_dir) >= -1e-5);
            for &(x, w, q) in &e.slots {
                assert!(q > 0.0 && x.length_squared() < 1.0, "slot event at {x}");
                assert!((w.length() - 1.0).abs() < 1e-5, "direction {w}");
            }
            let p = &plain[i];
            assert_eq!(
                (e.n, e.exit_pos, e.exit_dir, e.total, e.slots),
                (p.n, p.exit_pos, p.exit_dir, p.total, p.slots),
                "walk {i}: vector and plain code differ"
            );
        }
        for i in [0usize, 7, 4999] {
            let alone = run(&jobs[i..=i], &shared)[0];
            assert_eq!(
                (alone.n, alone.exit_pos, alone.slots),
                (all[i].n, all[i].exit_pos, all[i].slots)
            );
        }
    }

    /// Each reservoir's q is the proxy of the event it holds, computed from its own walk's
    /// constants: Σ_l E_l·ρ_g(W·ω_l)·e^(−τ·chord of the free ball from X along ω_l), written
    /// out here in f64 (`scatter_sim`'s HG, `exp`), for walks under two lights of unequal
    /// irradiance whose τ, free ball, light directions and irradiances (1 to 2 and 1.8 to
    /// 3) differ from job to job, 600 jobs through the 16 lanes (so lanes hold different
    /// walks and take new ones). The proxy only chooses events: any positive proxy keeps
    /// the NEE unbiased, so no image test sees one that is wrong, only more variance.
    /// `reservoir_estimates_are_unbiased` holds the proxy to its formula too, but with one
    /// light and the same constants for every walk (only the seeds differ), so it cannot
    /// see the second light's term read with the first's irradiance (here 0.33–1.1 of it),
    /// the first light's direction read for another's, or the loop over the lights cut
    /// short, nor a lane reading another lane's constants. Bound: the fast log₂ is good to
    /// 2·10⁻⁵ absolute (×1.5 in the exponent: 2·10⁻⁵ relative), 2^x to 4·10⁻⁶
    /// (`fast_exp2_and_log2_are_accurate`); f32 rounding of d = 1 + g² − 2g·cos (≥ 0.0625
    /// at g = 0.75) and of the exponent (|·| ≤ 40) adds < 10⁻⁵; 2·10⁻⁴ leaves ~5× room,
    /// while the second light's term read with the first's irradiance misses it by far
    /// wherever that light matters (the two never agree: E₀ ∈ {1, 1.5, 2}, E₁ ∈ {1.8, 2.2,
    /// 2.6, 3}).
    #[test]
    fn slots_hold_the_proxy_of_their_own_events() {
        let g = 0.75f32;
        let shared = WalkShared {
            g,
            m: MAX_EVENTS,
            n_lights: 2,
        };
        // Per job: τ, the free ball's radius² (≥ 1) and two lights (direction, irradiance).
        type Job = (f32, f32, [(Vec3, f32); 2]);
        let params: Vec<Job> = (0..600u32)
            .map(|i| {
                let t = i as f32;
                let tau = 0.5 + (i % 11) as f32 * 0.7;
                let f2 = 1.0 + (i % 5) as f32 * 0.6;
                let l0 = Vec3::new(0.8, 0.4 * (0.7 * t).sin(), 0.5).normalize();
                let l1 = Vec3::new(-0.4 * (0.3 * t).cos(), -0.9, 0.3).normalize();
                let (e0, e1) = (1.0 + (i % 3) as f32 * 0.5, 3.0 - (i % 4) as f32 * 0.4);
                (tau, f2, [(l0, e0), (l1, e1)])
            })
            .collect();
        let jobs: Vec<WalkJob> = params
            .iter()
            .enumerate()
            .map(|(i, &(tau, f2, lights))| WalkJob {
                tau,
                albedo: 0.95,
                seed: splitmix64(i as u64 ^ 0x5107),
                proxy: Proxy::new(lights.into_iter(), tau, f2, g),
            })
            .collect();
        let mut worst = 0.0f64;
        for (k, (&(tau, f2, lights), e)) in params.iter().zip(run(&jobs, &shared)).enumerate() {
            for &(x, w, q) in &e.slots {
                assert!(q > 0.0, "walk {k}: every slot holds an event");
                let (x, w) = (x.as_dvec3(), w.as_dvec3());
                let want: f64 = lights
                    .iter()
                    .map(|&(wl, el)| {
                        let wl = wl.as_dvec3();
                        let b = x.dot(wl);
                        let chord = -b + (b * b + f2 as f64 - x.length_squared()).max(0.0).sqrt();
                        el as f64
                            * scatter_sim::phase::hg_pdf(g as f64, w.dot(wl))
                            * (-(tau as f64) * chord).exp()
                    })
                    .sum();
                let rel = (q as f64 / want - 1.0).abs();
                assert!(
                    rel < 2e-4,
                    "walk {k} (τ {tau}, f² {f2}): q {q} for the event at {x}, {w}; its proxy is {want}"
                );
                worst = worst.max(rel);
            }
        }
        eprintln!("largest relative difference of a slot's q from its proxy: {worst:.1e}");
    }

    /// The reservoirs choose independently: two slots of a walk hold the same event with
    /// probability Σ_k p_k², p_k = φ^k q_k / Q. With a flat proxy (q = 1: the light is dark)
    /// p_k = φ^k / Σ_{j ≤ N} φ^j follows from the walk's N alone, so for each pair of the
    /// four slots the count of walks whose two slots coincide (the same X and W: distinct
    /// events lie at distinct points) must match Σ_walks Σ_k p_k² to |z| < 4.5 (a binomial
    /// sum over independent walks; 6 pairs: a false alarm ~4·10⁻⁵). 20,000 walks at τ = 3
    /// (5.7 events each on average) give an expectation of ~5,440 coincidences a pair and a
    /// spread of ~56 (from an independent f64 walk in Python). Slots that drew from one
    /// uniform (slot 1 reusing slot 0's bits) always coincide, 20,000 (z ≈ 260): each alone
    /// still holds event k with probability p_k, so every mean test
    /// (`reservoir_estimates_are_unbiased`, the images, the GPU comparisons) passes, but a
    /// step's two NEE events become one, its shadow ray's weight doubled: the variance of
    /// a single reservoir where two were asked for.
    #[test]
    fn reservoirs_choose_independently() {
        let (tau, g, albedo) = (3.0f32, 0.5f32, 0.9f32);
        let shared = WalkShared {
            g,
            m: MAX_EVENTS,
            n_lights: 1,
        };
        let n = 20_000u64;
        let jobs: Vec<WalkJob> = (0..n)
            .map(|i| {
                job(
                    tau,
                    albedo,
                    splitmix64(i ^ (0x1d << 40)),
                    g,
                    (Vec3::Z, 0.0),
                    1.0,
                )
            })
            .collect();
        assert!(jobs[0].proxy.flat, "a dark light makes the proxy flat");
        let pairs: Vec<(usize, usize)> = (0..MAX_EVENTS)
            .flat_map(|s| (s + 1..MAX_EVENTS).map(move |t| (s, t)))
            .collect();
        let mut same = vec![0u64; pairs.len()];
        let (mut expected, mut var) = (0.0f64, 0.0f64);
        let a = albedo as f64;
        for e in run(&jobs, &shared) {
            let total: f64 = (1..=e.n).map(|k| a.powi(k as i32)).sum();
            let pi: f64 = (1..=e.n).map(|k| (a.powi(k as i32) / total).powi(2)).sum();
            expected += pi;
            var += pi * (1.0 - pi);
            for (count, &(s, t)) in same.iter_mut().zip(&pairs) {
                let (x, y) = (e.slots[s], e.slots[t]);
                *count += (x.0 == y.0 && x.1 == y.1) as u64;
            }
        }
        for (&count, &(s, t)) in same.iter().zip(&pairs) {
            let z = (count as f64 - expected) / var.sqrt();
            assert!(
                z.abs() < 4.5,
                "slots {s} and {t}: {count} walks hold one event in both, {expected:.0} ± {:.0} expected (z = {z:.1})",
                var.sqrt()
            );
        }
    }

    /// A flat proxy (more lights than [`MAX_PROXY_LIGHTS`], or one dark in the channel)
    /// weighs every event by φ^k alone: q = 1 for the centre (`load`'s `proxy_q`) as for
    /// the events after it (`event`), so each slot holds q = 1 and the total is
    /// Σ_{k ≤ N} φ^k (f32 sums and products of at most ~30 terms here, the longest of
    /// 40,000 such walks simulated in python having 27: rounding < 4·10⁻⁶, so 10⁻⁴ is
    /// ~25× that). Five lit lights here, of which the lanes hold four. The centre taken
    /// with the four lights' terms instead of 1 (q ≈ 0.085 here) is consistent, as the same
    /// q chooses and weighs it, so the NEE stays unbiased and no image test sees it; it
    /// only makes the centre rare and heavy in the estimate.
    #[test]
    fn a_flat_proxy_weighs_every_event_alike() {
        let (tau, g, albedo) = (2.5f32, 0.6f32, 0.9f32);
        let lights: Vec<(Vec3, f32)> = (0..MAX_PROXY_LIGHTS + 1)
            .map(|l| {
                let d = Vec3::new(0.3 * l as f32 - 0.6, 0.5, 0.7).normalize();
                (d, 1.0 + l as f32)
            })
            .collect();
        let shared = WalkShared {
            g,
            m: MAX_EVENTS,
            n_lights: MAX_PROXY_LIGHTS,
        };
        let jobs: Vec<WalkJob> = (0..2000u64)
            .map(|i| WalkJob {
                tau,
                albedo,
                seed: splitmix64(i ^ (0x2f << 40)),
                proxy: Proxy::new(lights.iter().copied(), tau, 1.5, g),
            })
            .collect();
        assert!(jobs[0].proxy.flat, "five lights make the proxy flat");
        let a = albedo as f64;
        let mut centres = 0;
        for (k, e) in run(&jobs, &shared).iter().enumerate() {
            let want: f64 = (1..=e.n).map(|j| a.powi(j as i32)).sum();
            assert!(
                (e.total as f64 / want - 1.0).abs() < 1e-4,
                "walk {k} of {} events: total {} against Σ φ^k = {want}",
                e.n,
                e.total
            );
            for &(x, _, q) in &e.slots {
                assert_eq!(q, 1.0, "walk {k}: a slot's q at {x}");
                centres += (x == Vec3::ZERO) as usize;
            }
        }
        assert!(centres > 0, "some slot must hold the centre");
    }
}
