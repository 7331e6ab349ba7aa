// Shared include: the model sampler (crates/cvae/src/sampler.rs, features.rs) in f32.
// `decoder_sample(d)` is generated for the model's architecture with its weights as
// constants (crates/render-gpu/src/gpu/decoder_gen.rs): rows of zero-padded vec4s, every
// output a short chain of dot(vec4, vec4), no loops.

const D_LENGTH: u32 = 0u;
const D_PATH: u32 = 1u;
const D_EVENT: u32 = 2u;

// Scratch of one decoder call: raw conditioning features in, normals (z then ε) in,
// de-standardised outputs out. Its sizes, MAX_DECODED_N and the prior's PRIOR_* come with
// the generated decoders (gpu/decoder_gen.rs, from cvae::features).
var<private> dec_cond: array<f32, DEC_MAX_COND>;
var<private> dec_noise: array<f32, DEC_MAX_NOISE>;
var<private> dec_out: array<f32, DEC_MAX_OUT>;

/// Fills dec_noise[0..n] with standard normals (Box–Muller).
fn fill_normals(n: u32) {
    for (var i = 0u; i < n; i += 2u) {
        let r = sqrt(-2.0 * log(rand_open0()));
        let cs = unit_circle();
        dec_noise[i] = r * cs.x;
        if i + 1u < n {
            dec_noise[i + 1u] = r * cs.y;
        }
    }
}

// ---- features (feature versions 2 and 3, crates/cvae/src/features.rs; model.flags.z
// says which radial map EventGen's X uses) ----

fn tau_feature(tau: f32) -> f32 {
    return log(1.0 + max(tau, 0.0));
}

fn log_n_prior(tau: f32, g: f32) -> f32 {
    return log(1.0 + PRIOR_QUADRATIC * (1.0 - g) * tau * tau + PRIOR_LINEAR * tau);
}

/// Λ(N) = Σ_{k=1..N} φ^k = φ(1 − φ^N)/(1 − φ), from ln φ and 1 − φ computed in f64.
fn lambda_n(channel: u32, n: f32) -> f32 {
    let albedo = params.albedo[channel];
    if albedo >= 1.0 {
        return n;
    }
    if albedo <= 0.0 {
        return 0.0;
    }
    let ln = params.ln_albedo[channel];
    return albedo * (-expm1(n * ln)) / params.one_minus_albedo[channel];
}

/// φ^N.
fn albedo_pow(channel: u32, n: f32) -> f32 {
    if params.albedo[channel] >= 1.0 {
        return 1.0;
    }
    return exp(n * params.ln_albedo[channel]);
}

/// A walk's conditioning features, shared by its three models (WalkFeatures in
/// features.rs): computed once per sphere step, not once per model. rel_log_n is set once
/// N is known.
struct WalkFeatures {
    tau: f32,
    g: f32,
    log_prior: f32,
    rel_log_n: f32,
}

fn walk_features(tau: f32, g: f32) -> WalkFeatures {
    return WalkFeatures(tau_feature(tau), g, log_n_prior(tau, g), 0.0);
}

/// LengthGen: N ≥ n_min (as f32: N enters only through φ^N, Λ(N) and ln N).
fn sample_multiple_n(wf: WalkFeatures) -> f32 {
    fill_normals(DEC_LATENT_0 + DEC_OUT_0);
    dec_cond[0] = wf.tau;
    dec_cond[1] = wf.g;
    decoder_sample(D_LENGTH);
    let v = floor(exp(dec_out[0] + wf.log_prior));
    let n_min = f32(model.flags.y);
    if !is_finite(v) {
        return select(n_min, MAX_DECODED_N, v > 0.0);
    }
    return clamp(v, n_min, MAX_DECODED_N);
}

struct Exit {
    cos_theta: f32,
    alpha: f32,
    beta: f32,
}

/// PathGen: the exit of a walk with N events (wf.rel_log_n); always a valid exit.
fn sample_exit(wf: WalkFeatures) -> Exit {
    fill_normals(DEC_LATENT_1 + DEC_OUT_1);
    dec_cond[0] = wf.tau;
    dec_cond[1] = wf.g;
    dec_cond[2] = wf.rel_log_n;
    decoder_sample(D_PATH);
    let y = select(0.0, dec_out[0], is_finite(dec_out[0]));
    let cos_theta = clamp(2.0 / (1.0 + exp(-y)) - 1.0, -1.0, 1.0);
    var b = dec_out[1];
    var a = dec_out[2];
    if !(is_finite(a) && is_finite(b)) {
        a = 0.0;
        b = 0.0;
    }
    // Inverse of the radial map R² = −ln(1 − r²): r² = 1 − e^{−R²}.
    let big_r2 = b * b + a * a;
    var f = 1.0;
    if big_r2 > 1e-12 {
        f = sqrt(-expm1(-big_r2) / big_r2);
    }
    a *= f;
    b *= f;
    let r2 = a * a + b * b;
    if r2 > 1.0 {
        let r = sqrt(r2);
        a /= r;
        b /= r;
    }
    return Exit(cos_theta, a, b);
}

struct Event {
    x: vec3<f32>,
    w: vec3<f32>,
}

/// Whether the last sample_event returned the centre event (exact mode, no decoder).
var<private> event_was_centre: bool;

/// The representative event given N (wf.rel_log_n, and lam = Λ(N)) and the exit; event 1
/// (the centre, W = +z) exactly with probability φ/Λ(N) when single scattering is exact
/// (1 at φ = 0, the limit, as on the CPU: cvae::sampler's centre_event).
/// `mirror`: the antithetic partner of the previous (decoded) event draw, its latent and
/// output normals negated (cvae::sampler::event_draws); dec_noise still holds them, as no
/// other decoder runs between a step's event draws and the decoders only read it.
fn sample_event(wf: WalkFeatures, channel: u32, lam: f32, e: Exit, mirror: bool) -> Event {
    let albedo = params.albedo[channel];
    event_was_centre = model.flags.x != 0u && (albedo <= 0.0 || rand() * lam < albedo);
    if event_was_centre {
        return Event(vec3<f32>(0.0), vec3<f32>(0.0, 0.0, 1.0));
    }
    if mirror {
        for (var i = 0u; i < DEC_LATENT_2 + DEC_OUT_2; i++) {
            dec_noise[i] = -dec_noise[i];
        }
    } else {
        fill_normals(DEC_LATENT_2 + DEC_OUT_2);
    }
    dec_cond[0] = wf.tau;
    dec_cond[1] = wf.g;
    dec_cond[2] = params.albedo_feature[channel];
    dec_cond[3] = wf.rel_log_n;
    dec_cond[4] = e.cos_theta;
    dec_cond[5] = e.beta;
    dec_cond[6] = e.alpha;
    decoder_sample(D_EVENT);
    var x = vec3<f32>(dec_out[0], dec_out[1], dec_out[2]);
    let big = length(x);
    if !is_finite(big) {
        x = vec3<f32>(0.0);
    } else if model.flags.z != 0u {
        // Feature version 3: |X|² = 1 − exp(−u²/2) (cvae::features::EventRadial); ρ/u →
        // 1/√2 at the centre, as on the CPU.
        x *= select(0.70710678, sqrt(-expm1(-0.5 * big * big)) / big, big > 1e-12);
    } else if big > 1e-12 {
        // tanh's argument bounded: WGSL lets a driver take it from exponentials, which
        // overflow to a NaN event above ~89 (tanh(20) is 1 in f32 already).
        x *= tanh(min(big, 20.0)) / big;
    }
    if dot(x, x) > 1.0 {
        x = normalize(x);
    }
    var w = vec3<f32>(dec_out[3], dec_out[4], dec_out[5]);
    let wl = dot(w, w);
    if is_finite(wl) && wl > 1e-20 {
        w = w / sqrt(wl);
    } else {
        w = vec3<f32>(0.0, 0.0, 1.0);
    }
    return Event(x, w);
}
