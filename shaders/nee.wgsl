// Shared include: next-event estimation to the directional lights from a point inside
// the medium (crates/render-gpu/src/integrator/nee.rs): phase toward the light, the
// transmittance summed over every inside segment of the shadow ray, and with a
// dielectric boundary the Fresnel transmittance at each crossing and the refraction at
// the nearest (nee.rs, shadow).

// MAX_OPTICAL_DEPTH, MAX_CROSSINGS and PROXY_DEPTH_CAP come from nee.rs (gpu/kernels.rs,
// source).

fn transmittance(x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    if overlapping() {
        // One traversal, its own (transmittance_of would discard this one's).
        return transmittance_union(x, dir, channel, false);
    }
    return transmittance_of(crossings(x, dir), x, dir, channel);
}

/// The transmittance of the shadow ray x + t·dir from its crossings.
fn transmittance_of(c: Crossings, x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    if overlapping() {
        return transmittance_union(x, dir, channel, false);
    }
    if c.balance == 1 && c.length >= 0.0 {
        return exp(-params.sigma_t[channel] * c.length) * c.fresnel_t;
    }
    // Crossings that do not pair up (a crack between triangles, an origin not inside):
    // walk them in order.
    return transmittance_ordered(x, dir, channel);
}

/// A shadow ray's refraction where it first leaves a dielectric medium through a face
/// of triangle `prim` (nee.rs, refraction): the beam's factor r = cos θ_i / cos θ_t
/// and the refracted direction d toward the light; r = 0 where it does not leave through
/// it (an entry: a point outside by rounding). `flip`: the face may be of either
/// orientation (overlapping pieces: a piece nested in another is a hole).
struct Refraction {
    r: f32,
    d: vec3<f32>,
}

fn refraction_at(prim: u32, dir: vec3<f32>, flip: bool) -> Refraction {
    var n = tri_normal(prim);
    if flip && dot(dir, n) < 0.0 {
        n = -n;
    }
    let cos_i = dot(dir, n);
    if !(cos_i > 0.0) {
        return Refraction(0.0, dir);
    }
    let ior = params.consts.y;
    let cos_t = sqrt(1.0 - max(1.0 - cos_i * cos_i, 0.0) / (ior * ior));
    return Refraction(cos_i / cos_t, normalize((dir - cos_i * n) / ior + cos_t * n));
}

/// Where the last shadow ray of shadow_of (or transmittance_union/_ordered_r refracting)
/// refracted: the distance to that face (1e30: it stayed straight) and its triangle.
var<private> sh_first_t: f32;
var<private> sh_first_prim: u32;

/// NEE's transmittance of the shadow ray x + t·dir (nee.rs, shadow, without its phase
/// ratio: refracted_phase_ratio), `c` its crossings where pieces do not overlap:
/// transmittance_of's, and with a dielectric boundary refracted where it first leaves the
/// medium: the depth up to there and the beam's irradiance multiplied by r.
fn shadow_of(c: Crossings, x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    sh_first_t = 1e30;
    if !DIELECTRIC {
        return transmittance_of(c, x, dir, channel);
    }
    if overlapping() {
        return transmittance_union(x, dir, channel, true);
    }
    if c.balance == 1 && c.length >= 0.0 {
        let sigma = params.sigma_t[channel];
        if c.first_t < 1e29 {
            let rf = refraction_at(c.first_prim, dir, false);
            if rf.r > 0.0 {
                sh_first_t = c.first_t;
                sh_first_prim = c.first_prim;
                let depth = sigma * (c.length - c.first_t * (1.0 - rf.r));
                return exp(-max(depth, 0.0)) * c.fresnel_t * rf.r;
            }
        }
        return exp(-sigma * c.length) * c.fresnel_t;
    }
    return transmittance_ordered_r(x, dir, channel, true);
}

/// shadow_of with the crossings gathered here (one traversal where pieces overlap).
fn shadow(x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    if overlapping() {
        sh_first_t = 1e30;
        return transmittance_union(x, dir, channel, DIELECTRIC);
    }
    return shadow_of(crossings(x, dir), x, dir, channel);
}

/// nee.rs, shadow: the phase value (from an event scattering along w) toward the direction
/// refraction at (first_t, first_prim) turns `dir` to, over that toward `dir`; 1 where
/// the ray stayed straight (first_t ≥ 1e29).
fn refracted_phase_ratio(first_t: f32, first_prim: u32, dir: vec3<f32>, w: vec3<f32>) -> f32 {
    if !DIELECTRIC || first_t >= 1e29 {
        return 1.0;
    }
    let rf = refraction_at(first_prim, dir, overlapping());
    let g = params.consts.x;
    let p = hg_pdf_between(g, w, dir);
    if rf.r > 0.0 && p > 0.0 {
        return hg_pdf_between(g, w, rf.d) / p;
    }
    return 1.0;
}

/// The phase value `phase` toward `wl`, or with a dielectric boundary the largest over a
/// share of the directions refraction can turn it to (nee.rs, phase_bound): the roulette's
/// and the proxy's bound.
fn phase_bound(w: vec3<f32>, wl: vec3<f32>, phase: f32) -> f32 {
    if !DIELECTRIC {
        return phase;
    }
    let g = params.consts.x;
    let angle = acos(clamp(dot(w, wl), -1.0, 1.0));
    // A share of 90° − the critical angle (nee.rs, PHASE_BOUND_TURN, refraction_turn).
    let turn = PHASE_BOUND_TURN * (0.5 * PI - asin(clamp(1.0 / params.consts.y, 0.0, 1.0)));
    var nearest = max(angle - turn, 0.0);
    if g < 0.0 {
        nearest = min(angle + turn, PI);
    }
    return max(phase, hg_pdf(g, cos(nearest)));
}

/// The crossings walked in order. Past each, the ray is in the medium by turns, or where
/// pieces overlap as in_union says (a closest-hit walk steps past the second of two faces
/// in one plane); Fresnel's factor applies where that changes (nee.rs,
/// transmittance_ordered).
fn transmittance_ordered(x: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    return transmittance_ordered_r(x, dir, channel, false);
}

/// transmittance_ordered, with `refract` refracted where it first crosses the boundary if
/// that is a way out (nee.rs, ordered; sets sh_first_t/_prim): the depth up to there and
/// the result multiplied by r. Until that crossing the depth is not cut off at
/// MAX_OPTICAL_DEPTH: refraction can shorten it below.
fn transmittance_ordered_r(x: vec3<f32>, dir: vec3<f32>, channel: u32, refract: bool) -> f32 {
    let sigma = params.sigma_t[channel];
    var o = x;
    var inside = !overlapping() || in_union(x, dir);
    var depth = 0.0;
    var fresnel_t = 1.0;
    var crossed = !refract;
    var travelled = 0.0;
    for (var i = 0u; i < MAX_CROSSINGS; i++) {
        let h = intersect(o, dir, 1e30);
        if !h.found {
            return exp(-depth) * fresnel_t;
        }
        travelled += h.t;
        if inside {
            depth += sigma * h.t;
            if crossed && depth > MAX_OPTICAL_DEPTH {
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
            if !crossed {
                crossed = true;
                if inside {
                    let rf = refraction_at(h.prim, dir, overlapping());
                    if rf.r > 0.0 {
                        // Everything so far was inside: the first segment's depth.
                        depth *= rf.r;
                        fresnel_t *= rf.r;
                        sh_first_t = travelled;
                        sh_first_prim = h.prim;
                    }
                }
                if depth > MAX_OPTICAL_DEPTH {
                    return 0.0;
                }
            }
            inside = now;
        }
    }
    return 0.0;
}

/// The transmittance where pieces overlap (nee.rs, transmittance): the crossings of one
/// traversal, sorted (scene.wgsl, union_keep), walked from the pieces around the origin
/// (those crossed an odd number of times); the length counts where the pieces around
/// the ray make medium, Fresnel's factor where that changes (geometry/mod.rs, union_walk).
/// Beyond UNION_CROSSINGS crossings, the ordered walk.
fn transmittance_union(x: vec3<f32>, dir: vec3<f32>, channel: u32, refract: bool) -> f32 {
    let c = crossings(x, dir);
    if u_more {
        return transmittance_ordered_r(x, dir, channel, refract);
    }
    // The first crossing of the union's boundary, if a way out (geometry/mod.rs,
    // union_walk).
    var first_t = 1e30;
    var first_prim = 0u;
    var boundary_seen = false;
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
        let k = u_tri[i];
        let cos = abs(dot(dir, tri_normal(k)));
        if medium {
            length += t - last;
        }
        last = t;
        // The faces within the spawn offset of this one are crossed with it
        // (geometry/mod.rs, union_walk: touching pieces make no boundary).
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
            if !boundary_seen && medium {
                first_t = t;
                first_prim = k;
            }
            boundary_seen = true;
            medium = now;
        }
    }
    var depth = params.sigma_t[channel] * length;
    if refract && first_t < 1e29 {
        let rf = refraction_at(first_prim, dir, true);
        if rf.r > 0.0 {
            sh_first_t = first_t;
            sh_first_prim = first_prim;
            depth = max(params.sigma_t[channel] * (length - first_t * (1.0 - rf.r)), 0.0);
            fresnel_t *= rf.r;
        }
    }
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
            let t = shadow(x, ray.dir, channel);
            sum += t * ray.weight * refracted_phase_ratio(sh_first_t, sh_first_prim, ray.dir, w);
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
    let bound = phase_bound(w, ls.dir, phase)
        * exp(-params.sigma_t[channel] * max(free, ball_chord(x, ls.dir, c, f)));
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
        let phase = phase_bound(w, wl, hg_pdf(g, cos_l));
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
