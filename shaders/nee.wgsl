// Shared include: next-event estimation to the directional lights from a point inside
// the medium (crates/render-gpu/src/integrator/nee.rs): phase toward the light, the
// transmittance summed over every inside segment of the straight shadow ray, and with a
// dielectric boundary the Fresnel transmittance at each crossing (documented bias).

// MAX_OPTICAL_DEPTH, MAX_CROSSINGS and PROXY_DEPTH_CAP come from nee.rs (gpu/kernels.rs,
// source).

fn transmittance(x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    if overlapping() {
        // One traversal, its own (transmittance_of would discard this one's).
        return transmittance_union(x, dir, channel);
    }
    return transmittance_of(crossings(x, dir), x, dir, channel);
}

/// The transmittance of the shadow ray x + t·dir from its crossings.
fn transmittance_of(c: Crossings, x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    if overlapping() {
        return transmittance_union(x, dir, channel);
    }
    if c.balance == 1 && c.length >= 0.0 {
        return exp(-params.sigma_t[channel] * c.length) * c.fresnel_t;
    }
    // Crossings that do not pair up (a crack between triangles, an origin not inside):
    // walk them in order.
    return transmittance_ordered(x, dir, channel);
}

/// The crossings walked in order. Past each, the ray is in the medium by turns, or where
/// pieces overlap as in_union says (a closest-hit walk steps past the second of two faces
/// in one plane); Fresnel's factor applies where that changes (nee.rs,
/// transmittance_ordered).
fn transmittance_ordered(x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    let sigma = params.sigma_t[channel];
    var o = x;
    var inside = !overlapping() || in_union(x, dir);
    var depth = 0.0;
    var fresnel_t = 1.0;
    for (var i = 0u; i < MAX_CROSSINGS; i++) {
        let h = intersect(o, dir, 1e30);
        if !h.found {
            return exp(-depth) * fresnel_t;
        }
        if inside {
            depth += sigma * h.t;
            if depth > MAX_OPTICAL_DEPTH {
                return 0.0;
            }
        }
        let n = tri_normal(h.prim);
        o = spawn(o + dir * h.t, n, dir);
        var now = !inside;
        if overlapping() {
            now = in_union(o, dir);
        }
        if now != inside {
            fresnel_t *= crossing_transmittance(abs(dot(dir, n)));
            inside = now;
        }
    }
    return 0.0;
}

/// The transmittance where pieces overlap (nee.rs, transmittance): the crossings of one
/// traversal, sorted (scene.wgsl, union_keep), walked from the pieces around the origin
/// (those crossed an odd number of times); the length counts where the pieces around
/// the ray make medium, Fresnel's factor where that changes (geometry.rs, union_walk).
/// Beyond UNION_CROSSINGS crossings, the ordered walk.
fn transmittance_union(x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    let c = crossings(x, dir);
    if u_more {
        return transmittance_ordered(x, dir, channel);
    }
    var around = c.pieces;
    var medium = union_medium(around);
    var length = 0.0;
    var last = 0.0;
    var fresnel_t = 1.0;
    var i = 0u;
    loop {
        if i >= u_count {
            break;
        }
        let t = u_t[i];
        let cos = abs(dot(dir, tri_normal(u_tri[i])));
        if medium {
            length += t - last;
        }
        last = t;
        // The faces within the spawn offset of this one are crossed with it (geometry.rs,
        // union_walk: touching pieces make no boundary).
        let reach = t + params.consts.z / max(cos, GRAZING_COS_FLOOR);
        loop {
            if i >= u_count || u_t[i] > reach {
                break;
            }
            around ^= piece_bit(u_tri[i]);
            i += 1u;
        }
        let now = union_medium(around);
        if now != medium {
            fresnel_t *= crossing_transmittance(cos);
            medium = now;
        }
    }
    let depth = params.sigma_t[channel] * length;
    return select(exp(-depth) * fresnel_t, 0.0, depth > MAX_OPTICAL_DEPTH);
}

/// The chord from `x` along `dir` to the edge of the surface-free ball (centre `c`,
/// radius `f`, x inside): medium a shadow ray crosses before it can meet the surface.
fn ball_chord(x: vec3<f32>, dir: vec3<f32>, c: vec3<f32>, f: f32) -> f32 {
    let d = x - c;
    let b = dot(d, dir);
    let chord = -b + sqrt(b * b + max(f * f - dot(d, d), 0.0));
    return min(chord * BALL_CHORD_SHRINK, 2.0 * f);
}

/// Σ over lights of ρ_g(W·ω_l) · T(x → light) · (E, or L/pdf for a sun disk). Every
/// shadow ray crosses at least max(`free`, its chord through the free ball (`c`, `f`))
/// of medium, so T ≤ exp(−σ_t·that), and a shadow ray whose bound ρ_g·T is below
/// ROULETTE_BOUND/4π (ROULETTE_BOUND prepended from nee.rs by kernels.rs) goes through an
/// unbiased roulette, as on the CPU (nee::direct's `free`); none when `rouletted` is false
/// (nee::direct_unrouletted: path-level NEE has already spent the ray on an event worth
/// it).
fn nee_direct(x: vec3<f32>, w: vec3<f32>, free: f32, c: vec3<f32>, f: f32, channel: u32, rouletted: bool) -> f32 {
    var sum = 0.0;
    for (var i = 0u; i < LIGHTS; i++) {
        let ray = nee_light_ray(i, x, w, free, c, f, channel, rouletted);
        if ray.casts {
            sum += transmittance(x, ray.dir, channel) * ray.weight;
        }
    }
    return sum;
}

/// One light's shadow ray of nee_direct before its cast: the direction, the weight its
/// transmittance is multiplied by, and whether it is cast at all (a dark light, or lost
/// in the roulette: not). Kernels that defer the cast (path.wgsl, bounce) draw the same
/// random numbers in the same order.
struct LightRay {
    dir: vec3<f32>,
    weight: f32,
    casts: bool,
}

fn nee_light_ray(i: u32, x: vec3<f32>, w: vec3<f32>, free: f32, c: vec3<f32>, f: f32, channel: u32, rouletted: bool) -> LightRay {
    let u1 = rand();
    let u2 = rand();
    let g = params.consts.x;
    var ls = light_sample(i, u1, u2, channel);
    let share = light_phase_share(i, g);
    if share > 0.0 {
        // nee.rs, light_sample: a third uniform picks the strategy of the mixture; either
        // direction is weighed by L over the mixture's density.
        if rand() < share {
            let phi = TWO_PI * u2;
            ls.dir = normalize(deflect(w, hg_sample(g, u1), vec2<f32>(cos(phi), sin(phi))));
        }
        let density = share * hg_pdf_between(g, w, ls.dir)
            + (1.0 - share) / (TWO_PI * params.lights[i].to_light.w);
        ls.factor = light_radiance_toward(i, ls.dir, channel) * params.consts4.x / density;
    }
    if ls.factor <= 0.0 {
        return LightRay(ls.dir, 0.0, false);
    }
    let threshold = ROULETTE_BOUND * INV_4PI;
    let phase = hg_pdf_between(g, w, ls.dir);
    var weight = ls.factor * phase;
    let bound = phase * exp(-params.sigma_t[channel] * max(free, ball_chord(x, ls.dir, c, f)));
    if rouletted && bound < threshold {
        if rand() * threshold >= bound {
            return LightRay(ls.dir, 0.0, false);
        }
        weight *= threshold / bound;
    }
    return LightRay(ls.dir, weight, true);
}

// ---- path-level NEE (integrator/nee.rs, PathNee) ----
// PATH_NEE_M (prepended by kernels.rs; at most 2, scene::MAX_PATH_NEE_RAYS) weighted
// reservoirs over a path's NEE events, whose shadow rays are cast when the path ends
// (path.wgsl); 0: a shadow ray at every event (PT, and ST-CVAE with path_nee_rays = 0).
// Saved between dispatches with the path (path.wgsl, save_path).
var<private> pn_x: array<vec3<f32>, 2>;
var<private> pn_w: array<vec3<f32>, 2>;
var<private> pn_q: array<f32, 2>;
// A = Σ c·q of the events offered so far (0: none).
var<private> pn_total: f32;

fn path_nee_reset() {
    pn_total = 0.0;
    for (var i = 0u; i < 2u; i++) {
        pn_q[i] = 0.0;
    }
}

/// nee::proxy: Σ_l E_l · ρ_g(W·ω_l) · exp(−min(σ_t·free(ω_l), PROXY_DEPTH_CAP)) with the
/// light's central direction (or the disk's where ρ_g is largest, for a disk wider than its
/// lobe), free(ω_l) = max(`free`, the chord through the free ball (`c`, `f`)): the bound
/// nee_direct's roulette uses, up to the cap.
fn nee_proxy(x: vec3<f32>, w: vec3<f32>, free: f32, c: vec3<f32>, f: f32, channel: u32) -> f32 {
    let g = params.consts.x;
    let sigma = params.sigma_t[channel];
    var q = 0.0;
    for (var i = 0u; i < LIGHTS; i++) {
        let l = params.lights[i];
        let wl = l.to_light.xyz;
        // nee::proxy: the phase function's largest value over a disk wider than its lobe.
        var cos_l = clamp(dot(w, wl), -1.0, 1.0);
        if light_phase_share(i, g) > 0.0 {
            cos_l = light_extreme_cos(i, w, g);
        }
        let phase = hg_pdf(g, cos_l);
        // nee::PROXY_DEPTH_CAP: a positive proxy for every event (a wide disk's centre
        // chord underflowed to 0 and the event's light was lost).
        let depth = min(sigma * max(free, ball_chord(x, wl, c, f)), PROXY_DEPTH_CAP);
        q += l.irradiance[channel] * phase * exp(-depth);
    }
    return q;
}

/// Offers event (x, w) with NEE coefficient `c` and proxy `q` to the reservoirs: each
/// holds it with probability c·q / A (PathNee::offer).
fn path_nee_offer(x: vec3<f32>, w: vec3<f32>, c: f32, q: f32) {
    let a = c * q;
    if !(a > 0.0) {
        return;
    }
    pn_total += a;
    for (var i = 0u; i < PATH_NEE_M; i++) {
        if rand() * pn_total < a {
            pn_x[i] = x;
            pn_w[i] = w;
            pn_q[i] = q;
        }
    }
}

/// The shadow rays of the path's NEE, cast one per bounce after the path's last
/// (path.wgsl, bounce): one per reservoir and light; none without an event offered.
fn path_nee_rays() -> u32 {
    if PATH_NEE_M == 0u || !(pn_total > 0.0) {
        return 0u;
    }
    return PATH_NEE_M * LIGHTS;
}
