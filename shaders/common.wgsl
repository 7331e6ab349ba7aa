// Shared include: constants, the per-path RNG, small math helpers, Henyey–Greenstein
// sampling and the canonical frame of a sphere walk. Mirrors crates/scatter-sim (phase.rs,
// frame.rs) in f32; the equality tests live in crates/render-gpu/tests/gpu/wgsl_blocks.rs.

const PI: f32 = 3.14159265358979;
const TWO_PI: f32 = 6.28318530717959;
const INV_4PI: f32 = 0.0795774715459477;

// ---- RNG: xoshiro128++ per (seed, pixel, sample), seeded through a 32-bit mixer ----

var<private> rng_s: vec4<u32>;

fn mix32(x0: u32) -> u32 {
    // lowbias32 (Wellons): a bijective 32-bit finaliser with low bias.
    var x = x0;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

fn rotl(x: u32, k: u32) -> u32 {
    return (x << k) | (x >> (32u - k));
}

// The colour channel of a pixel's sample 0 (sample s traces (offset + s) % 3): uniform
// over pixels and seeds, so each sample's channel is uniform and the hero weight 3 is
// unbiased per pixel for any spp. render.rs's channel_offset computes the same.
fn channel_offset(seed_lo: u32, seed_hi: u32, pixel: u32) -> u32 {
    let s = mix32(seed_lo ^ mix32(seed_hi ^ 0x43484e4cu));
    return mix32((pixel * 0x9e3779b9u) ^ s) % 3u;
}

fn rng_seed(seed_lo: u32, seed_hi: u32, pixel: u32, sample: u32) {
    let a = mix32(seed_lo ^ 0x53544356u);
    let b = mix32(seed_hi ^ rotl(a, 7u) ^ 0x41450001u);
    let c = mix32(pixel ^ rotl(b, 13u));
    let d = mix32(sample ^ rotl(c, 19u) ^ 0x9e3779b9u);
    rng_s = vec4<u32>(mix32(a ^ d), mix32(b + c), mix32(c ^ rotl(d, 11u)), mix32(d + a) | 1u);
}

fn rng_next() -> u32 {
    let result = rotl(rng_s.x + rng_s.w, 7u) + rng_s.x;
    let t = rng_s.y << 9u;
    rng_s.z ^= rng_s.x;
    rng_s.w ^= rng_s.y;
    rng_s.y ^= rng_s.z;
    rng_s.x ^= rng_s.w;
    rng_s.z ^= t;
    rng_s.w = rotl(rng_s.w, 11u);
    return result;
}

/// Uniform in [0, 1) with 24 random bits.
fn rand() -> f32 {
    return f32(rng_next() >> 8u) * (1.0 / 16777216.0);
}

/// Uniform in (0, 1]: safe to take the logarithm of.
fn rand_open0() -> f32 {
    return f32((rng_next() >> 8u) + 1u) * (1.0 / 16777216.0);
}

/// A uniform unit vector in the plane (cos ψ, sin ψ).
fn unit_circle() -> vec2<f32> {
    let a = TWO_PI * rand();
    return vec2<f32>(cos(a), sin(a));
}

// ---- math ----

/// Finite test through the bits: shader compilers may assume no NaN and fold x != x.
fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

/// e^x − 1 without cancellation for small |x| (albedos within 1e-5 of 1).
fn expm1(x: f32) -> f32 {
    if abs(x) < 1e-2 {
        return x * (1.0 + x * (0.5 + x * (1.0 / 6.0 + x * (1.0 / 24.0))));
    }
    return exp(x) - 1.0;
}

/// softplus(x) = max(x, 0) + ln(1 + u), u = e^−|x| ∈ (0, 1], with ln(1 + u) = u·q(u)
/// by the CPU decoders' polynomial (cvae::fastmath::LN1P_Q): no log, and no loss of
/// ln(1 + u)'s relative precision for tiny u.
fn softplus(x: f32) -> f32 {
    let u = exp(-abs(x));
    let u2 = u * u;
    let u4 = u2 * u2;
    let q03 = fma(u, -0.49999445, 0.999999966) + u2 * fma(u, -0.24835399, 0.33318122);
    let q47 = fma(u, -0.13602248, 0.19076881) + u2 * fma(u, -0.029074065, 0.077516086);
    return max(x, 0.0) + u * (q03 + u4 * (q47 + u4 * 0.005126102));
}

// ---- Henyey–Greenstein (convention of scatter_sim::phase) ----
//
// In f32 the textbook forms cancel as |g| → 1: 1 + g² − 2g·cos θ falls to (1 − |g|)², 1e-6
// at g = 0.999, where they lost ~10 % of the peak (the lobe integrated to 0.965) and drew
// backward cosines 0.06 off. The forms below are sums and products of non-negative terms
// in a = |g|, 1 − a (exact in f32 for a ≥ 0.5) and m = 1 − cos θ measured from the lobe's
// axis (cos θ for g ≥ 0, −cos θ for g < 0); scatter_sim::phase::hg_pdf_between is the
// CPU's counterpart of hg_pdf_between.

/// HG per steradian at m = 1 − sign(g)·cos θ ∈ [0, 2].
fn hg_pdf_m(g: f32, m: f32) -> f32 {
    let a = abs(g);
    let oma = 1.0 - a;
    let d = oma * oma + 2.0 * a * m;
    return oma * (1.0 + a) * INV_4PI / (d * sqrt(d));
}

fn hg_pdf(g: f32, c: f32) -> f32 {
    return hg_pdf_m(g, 1.0 - select(c, -c, g < 0.0));
}

/// HG from the arriving unit direction w to the departing unit direction l: m is half the
/// squared distance between w and ±l, which keeps its relative precision in a lobe of
/// θ ~ 1e-3 (g = 0.999), where 1 − dot(w, l) would be f32 rounding.
fn hg_pdf_between(g: f32, w: vec3<f32>, l: vec3<f32>) -> f32 {
    let e = w - select(l, -l, g < 0.0);
    return hg_pdf_m(g, min(0.5 * dot(e, e), 2.0));
}

/// HG's inverse CDF as (cos θ, sin θ). With a = |g| and ξ' = ξ (g ≥ 0) or 1 − ξ (g < 0,
/// as cos(g, ξ) = −cos(|g|, 1 − ξ)), and D = 1 − a + 2aξ', s = (1 − a²)/D,
///   m = (1 − a)(1 − ξ')(s + 1 − a)/D  and  p = (1 + a)ξ'(1 + a + s)/D
/// are exactly 1 − cos and 1 + cos of the textbook cos(a, ξ') = (1 + a² − s²)/2a, without
/// its cancellation at small a (m = 2(1 − ξ'), p = 2ξ' at a = 0: no isotropic special
/// case) or as a → 1. cos θ comes from the smaller of the two, sin θ from √(m·p), which
/// f32 keeps near either pole, where 1 − cos² θ would be rounding.
fn hg_sample(g: f32, xi: f32) -> vec2<f32> {
    let a = abs(g);
    let neg = g < 0.0;
    let u = select(xi, 1.0 - xi, neg);
    let v = select(1.0 - xi, xi, neg);
    let oma = 1.0 - a;
    let dd = oma + 2.0 * a * u;
    let s = oma * (1.0 + a) / dd;
    let m = oma * v * (s + oma) / dd;
    let p = (1.0 + a) * u * (1.0 + a + s) / dd;
    let c = select(p - 1.0, 1.0 - m, m < p);
    return vec2<f32>(select(c, -c, neg), sqrt(m * p));
}

/// copysign(1, z): −1 for −0.0 too, as the CPU's `1f32.copysign(n.z)` (a comparison
/// n.z >= 0 would give −0.0 the other basis, so the devices would deflect one direction
/// differently).
fn sign_bit_of(z: f32) -> f32 {
    return select(1.0, -1.0, (bitcast<u32>(z) >> 31u) != 0u);
}

/// Duff et al. (2017): t, b completing unit n to a right-handed basis.
fn basis_t(n: vec3<f32>) -> vec3<f32> {
    let s = sign_bit_of(n.z);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
}

fn basis_b(n: vec3<f32>) -> vec3<f32> {
    let s = sign_bit_of(n.z);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return vec3<f32>(b, s + n.y * n.y * a, -n.y);
}

/// The direction at (cos θ, sin θ) = `theta` from `dir`, at azimuth (cos ψ, sin ψ) = `cs`.
fn deflect(dir: vec3<f32>, theta: vec2<f32>, cs: vec2<f32>) -> vec3<f32> {
    return dir * theta.x + (basis_t(dir) * cs.x + basis_b(dir) * cs.y) * theta.y;
}

fn hg_sample_direction(g: f32, dir: vec3<f32>) -> vec3<f32> {
    return normalize(deflect(dir, hg_sample(g, rand()), unit_circle()));
}

// ---- canonical frame (scatter_sim::frame) ----

/// sin θ of a cos θ that comes alone (PathGen's). An exit drawn from HG brings its own,
/// which f32 keeps where this would be rounding (hg_sample).
fn sin_of_cos(cos_theta: f32) -> f32 {
    let c = clamp(cos_theta, -1.0, 1.0);
    return sqrt(max(1.0 - c * c, 0.0));
}

/// The exit point of a canonical exit: (0, sin θ, cos θ).
fn canonical_exit_point(cos_theta: f32, sin_theta: f32) -> vec3<f32> {
    return vec3<f32>(0.0, sin_theta, clamp(cos_theta, -1.0, 1.0));
}

/// The exit direction α e_b + β e_t + √(1−α²−β²) e_n with e_b = (−1, 0, 0) and
/// e_t = (0, cos θ, −sin θ); (α, β) is rescaled onto the unit disk if needed.
fn canonical_exit_dir(cos_theta: f32, sin_theta: f32, alpha0: f32, beta0: f32) -> vec3<f32> {
    let c = clamp(cos_theta, -1.0, 1.0);
    let s = sin_theta;
    var a = alpha0;
    var b = beta0;
    if !(is_finite(a) && is_finite(b)) {
        a = 0.0;
        b = 0.0;
    }
    let r2 = a * a + b * b;
    if r2 > 1.0 {
        let r = sqrt(r2);
        a /= r;
        b /= r;
    }
    let n = sqrt(max(1.0 - a * a - b * b, 0.0));
    let e_n = vec3<f32>(0.0, s, c);
    let e_b = vec3<f32>(-1.0, 0.0, 0.0);
    let e_t = vec3<f32>(0.0, c, -s);
    return normalize(a * e_b + b * e_t + n * e_n);
}

/// Maps canonical coordinates to the world: +z to omega_in, the x/y axes turned by the
/// azimuth (cos ψ, sin ψ) about it (scatter_sim::frame::WalkFrame).
struct WalkFrame {
    u: vec3<f32>,
    v: vec3<f32>,
    w: vec3<f32>,
}

fn walk_frame(omega_in: vec3<f32>, cs: vec2<f32>) -> WalkFrame {
    let t = basis_t(omega_in);
    let b = basis_b(omega_in);
    return WalkFrame(t * cs.x + b * cs.y, b * cs.x - t * cs.y, omega_in);
}

fn to_world(f: WalkFrame, v: vec3<f32>) -> vec3<f32> {
    return f.u * v.x + f.v * v.y + f.w * v.z;
}
