// Kernel: ST-CVAE sphere tracing with NEE through EventGen (crates/render-gpu/src/
// integrator/sphere_step.rs). Composed as common + scene + nee + decoder + stcvae + path.
//
// φ^N already contains the albedo of event 1 (the collision at p), so p gets no separate
// albedo weight and no separate NEE: EventGen's representative event, weighted Λ(N),
// stands for NEE at all N events of the walk.

// SHRINK and EXACT_DISTANCE_SHRINK are sphere_step.rs's (prepended by gpu/kernels.rs).

fn scatter_at(channel: u32) -> bool {
    let sigma = params.sigma_t[channel];
    let min_tau = params.consts.w;
    let max_tau = params.consts2.x;
    let near = params.consts2.y;
    let grid_free = grid_radius(ps.pos);
    // The path's own bound (what is left of its last free ball) costs nothing.
    var free = max(grid_free, ps.free);
    // Refined wherever the step below would otherwise fall back (at min_tau = 0, a bound
    // of 0: sphere_step.rs).
    if free < near && !(free * SHRINK > 0.0 && sigma * free * SHRINK >= min_tau) {
        // The grid's Lipschitz bound loses up to two cell half-diagonals near the surface; the
        // exact distance often still allows a sphere step there. It comes from the cell's
        // candidate triangles, or else from a search that stops at the largest distance
        // the grid allows.
        var exact = grid_exact_distance(ps.pos);
        if exact < 0.0 {
            exact = surface_distance(ps.pos, grid_distance_upper_bound(grid_free));
        }
        free = max(free, exact * EXACT_DISTANCE_SHRINK - params.consts.z);
    }
    let r = min(free * SHRINK, max_tau / sigma);
    let tau = sigma * r;
    let fallback = !(r > 0.0) || tau < min_tau;
    let nee = NEE;
    let g = params.consts.x;
    let centre = ps.pos;
    // SIMD shape (lavapipe runs 8 invocations in lock-step, GPUs 32–64): the PT fallback
    // and the sphere step share one NEE loop, one EventGen call and one shadow-ray query
    // below, so lanes in different branches do not run each of them one after the other.
    var frame: WalkFrame; // set by the sphere step; unused by the fallback
    var n = 1.0;
    var e = Exit(1.0, 0.0, 0.0);
    var e_sin = 0.0; // the exit's sin θ
    var single = false;
    var wf: WalkFeatures;
    var lam = 0.0; // Λ(N) of the sphere step's walk
    var nee_count = 0u;
    var nee_weight = 0.0;
    var exact = false;
    var ex_exit_x = vec3<f32>(0.0, 0.0, 1.0);
    var ex_exit_w = vec3<f32>(0.0, 0.0, 1.0);
    if fallback {
        // A real collision handled as in PT (pt_event): NEE here, then albedo and HG.
        ps.free = max(free, 0.0);
        stats[C_EVENTS] += 1u;
        if nee {
            nee_count = 1u;
            nee_weight = ps.beta * params.albedo[channel];
        }
    } else if park_steps {
        // The staged render runs sphere steps, exact and model, in a kernel of their own
        // (step_main, staged_steps.wgsl): nothing above changed the path, and step_main
        // computes it again from the same state. Exact steps are queued by optical radius.
        step_parked = true;
        step_tau = select(-1.0, tau, tau < params.consts3.x);
        return false;
    } else if tau < params.consts3.x {
        // An exact step (sphere_step.rs, ExactStep; walk_lanes.rs): the walk simulated in
        // the ball, its NEE events chosen by importance with weights Q/q (ex_weight).
        exact = true;
        frame = walk_frame(ps.dir, vec2<f32>(1.0, 0.0));
        var m = 0u;
        if nee && LIGHTS > 0u {
            m = clamp(u32(params.consts3.y), 1u, MAX_EXACT_EVENTS);
        }
        let walk = exact_walk(tau, g, channel, m, frame, max(free / r, 1.0));
        stats[C_STEPS] += 1u;
        stats[C_EXACT] += 1u;
        stats[C_EXACT_EVENTS] += u32(walk.n);
        // A u32 of this invocation until add_stats: flushed before it could wrap (above
        // |g| = 0.98 every step is exact up to max_tau, ~10⁵ events a walk at g = −0.999,
        // and a dispatch may run up to 65,535 bounces).
        if stats[C_EXACT_EVENTS] >= 0x80000000u {
            add_counter(C_EXACT_EVENTS, stats[C_EXACT_EVENTS]);
            stats[C_EXACT_EVENTS] = 0u;
        }
        n = walk.n;
        ex_exit_x = walk.x;
        ex_exit_w = walk.w;
        nee_count = walk.used;
        nee_weight = ps.beta / f32(max(m, 1u));
    } else {
        stats[C_STEPS] += 1u;
        frame = walk_frame(ps.dir, unit_circle());
        // The walk: exact N = 1 branch (probability e^−τ, no decoder), else the decoders.
        if model.flags.x != 0u && rand() < exp(-tau) {
            single = true;
            let theta = hg_sample(g, rand());
            e = Exit(theta.x, 0.0, 0.0);
            e_sin = theta.y;
        } else {
            wf = walk_features(tau, g);
            n = sample_multiple_n(wf);
            wf.rel_log_n = log(n) - wf.log_prior;
            e = sample_exit(wf);
            e_sin = sin_of_cos(e.cos_theta);
        }
        if nee {
            // Representative events given N and the exit, each weighted Λ(N)/M; the
            // N = 1 walk has its one event at the centre (X = p, W = ω_in), Λ = φ.
            lam = params.albedo[channel];
            nee_count = 1u;
            if !single {
                lam = lambda_n(channel, n);
                nee_count = max(params.misc.z, 1u);
            }
            nee_weight = ps.beta * lam / f32(nee_count);
        }
    }
    var sum = 0.0;
    // Event draws in antithetic pairs, as on the CPU (cvae::sampler::event_draws): the
    // second of a pair mirrors the first's noise unless either is the centre event.
    var partner = false;
    for (var k = 0u; k < nee_count; k++) {
        var x = ps.pos;
        var w = ps.dir;
        var x_free = ps.free;
        // The free ball a step's event lies in (centre, `free`: sphere_step.rs); none for
        // the fallback, whose own ball around ps.pos is x_free already.
        var ball_c = ps.pos;
        var ball_f = 0.0;
        var wk = 1.0;
        if !fallback {
            var ev = Event(vec3<f32>(0.0), vec3<f32>(0.0, 0.0, 1.0));
            if exact {
                ev = Event(ex_x[k], ex_w[k]);
                wk = ex_weight[k];
            } else if !single {
                let mirror = partner;
                ev = sample_event(wf, channel, lam, e, mirror);
                partner = !mirror && !event_was_centre;
            }
            x = centre + to_world(frame, ev.x) * r;
            w = normalize(to_world(frame, ev.w));
            // The grid's ball around X, and the chord through the step's free ball.
            x_free = grid_radius(x);
            ball_c = centre;
            ball_f = free;
        }
        if PATH_NEE_M > 0u {
            // Path-level NEE: the event joins the path's reservoirs (sphere_step.rs,
            // complete; integrator/mod.rs, pt_event).
            let q = nee_proxy(x, w, x_free, ball_c, ball_f, channel);
            path_nee_offer(x, w, nee_weight * wk, q);
        } else {
            sum += wk * nee_direct(x, w, x_free, ball_c, ball_f, channel, true);
        }
    }
    ps.radiance += nee_weight * sum;
    if fallback {
        ps.beta *= params.albedo[channel];
        if !roulette() {
            ps.alive = false;
            return false;
        }
        ps.dir = hg_sample_direction(g, ps.dir);
        ps.scattered = true;
        return false;
    }
    ps.beta *= albedo_pow(channel, n);
    if !roulette() {
        ps.alive = false;
        return true;
    }
    var xc = canonical_exit_point(e.cos_theta, e_sin);
    var wc = canonical_exit_dir(e.cos_theta, e_sin, e.alpha, e.beta);
    if exact {
        xc = ex_exit_x;
        wc = ex_exit_w;
    }
    ps.pos = centre + to_world(frame, xc) * r;
    ps.dir = normalize(to_world(frame, wc));
    ps.scattered = true;
    // The grid at the exit often knows more than the ball it left (sphere_step.rs,
    // complete). Only the grid: an exact distance here (as the kernel once took in dense
    // media) makes the next step's ball larger than the CPU's, a different estimator.
    ps.free = max(free - r, grid_radius(ps.pos));
    return true;
}

// ---- exact sphere steps (crates/render-gpu/src/integrator/sphere_step.rs, ExactStep) ----

// MAX_EXACT_EVENTS = scene::MAX_EXACT_NEE_SAMPLES and MAX_PROXY_LIGHTS = the CPU's
// (event_choice.rs), prepended by gpu/kernels.rs.
// The exact step's event slots: (X, W) in the walk's frame, the proxy q of the event a slot
// holds, then (after exact_walk) the events' weights Q/q with equal slots merged.
var<private> ex_x: array<vec3<f32>, MAX_EXACT_EVENTS>;
var<private> ex_w: array<vec3<f32>, MAX_EXACT_EVENTS>;
var<private> ex_q: array<f32, MAX_EXACT_EVENTS>;
var<private> ex_weight: array<f32, MAX_EXACT_EVENTS>;
var<private> ex_total: f32;
// The lights in the walk's frame (xyz) with their irradiance in the path's channel (w).
var<private> ex_lights: array<vec4<f32>, MAX_PROXY_LIGHTS>;

struct ExactWalk {
    x: vec3<f32>,
    w: vec3<f32>,
    n: f32,
    used: u32,
}

/// q: the phase value toward each light times the transmittance across the free ball's
/// chord (radius² f2 in units of the walk's sphere), times the light's irradiance; 1 for
/// every event when nl = 0 (a light dark in this channel, or more lights than
/// MAX_PROXY_LIGHTS: events by φ^k alone).
fn exact_proxy(x: vec3<f32>, w: vec3<f32>, nl: u32, f2: f32, tau: f32, g: f32) -> f32 {
    if nl == 0u {
        return 1.0;
    }
    let dd = dot(x, x);
    var q = 0.0;
    for (var i = 0u; i < nl; i++) {
        let wl = ex_lights[i].xyz;
        let b = dot(x, wl);
        let chord = -b + sqrt(b * b + max(f2 - dd, 0.0));
        let d = max(1.0 + g * g - 2.0 * g * dot(w, wl), 1e-12);
        // The attenuation no smaller than 2^−126, as the CPU's (event_choice::exp2): the
        // proxy must be positive wherever the NEE can be, and exp flushes to 0 past τ·chord
        // ≈ 87 (reached where exact_tau > 43).
        let atten = exp2(max(-tau * chord * 1.4426950408889634, -126.0));
        q += ex_lights[i].w * (1.0 - g * g) * INV_4PI / (d * sqrt(d)) * atten;
    }
    return q;
}

/// Offers event (X, W) with weight φ^k·q to each of the m weighted reservoirs.
fn exact_offer(x: vec3<f32>, w: vec3<f32>, q: f32, phi_k: f32, m: u32) {
    let wk = phi_k * q;
    ex_total += wk;
    for (var i = 0u; i < m; i++) {
        if rand() * ex_total < wk {
            ex_x[i] = x;
            ex_w[i] = w;
            ex_q[i] = q;
        }
    }
}

/// The walk in the unit sphere of optical radius tau (integrator/walk_lanes.rs), its m NEE
/// events left in ex_x, ex_w, ex_weight (the first `used`).
fn exact_walk(tau: f32, g: f32, channel: u32, m: u32, frame: WalkFrame, f_unit: f32) -> ExactWalk {
    var nl = min(LIGHTS, MAX_PROXY_LIGHTS);
    // Beyond MAX_PROXY_LIGHTS lights every event weighs alike (q = 1), as on the CPU
    // (event_choice.rs, Proxy::new): a proxy of some lights only would stay unbiased but
    // choose other events than the CPU's.
    var flat = LIGHTS > MAX_PROXY_LIGHTS;
    for (var i = 0u; i < nl; i++) {
        let l = params.lights[i];
        let wl = l.to_light.xyz;
        let e = l.irradiance[channel];
        ex_lights[i] = vec4<f32>(dot(wl, frame.u), dot(wl, frame.v), dot(wl, frame.w), e);
        flat = flat || !(e > 0.0);
    }
    if flat {
        nl = 0u;
    }
    let f2 = f_unit * f_unit;
    let albedo = params.albedo[channel];
    ex_total = 0.0;
    for (var i = 0u; i < MAX_EXACT_EVENTS; i++) {
        ex_q[i] = 0.0;
    }
    var phi_k = albedo;
    var pos = vec3<f32>(0.0);
    var arriving = vec3<f32>(0.0, 0.0, 1.0);
    if m > 0u {
        exact_offer(pos, arriving, exact_proxy(pos, arriving, nl, f2, tau, g), phi_k, m);
    }
    var n = 1.0;
    var exit_x = vec3<f32>(0.0, 0.0, 1.0);
    var exit_w = vec3<f32>(0.0, 0.0, 1.0);
    loop {
        prof(4u);
        let dir = hg_sample_direction(g, arriving);
        let flight = -log(rand_open0()) / tau;
        let next = pos + dir * flight;
        if !(flight < 2.0) || dot(next, next) >= 1.0 {
            let b = dot(pos, dir);
            let c = dot(pos, pos) - 1.0;
            let t = -b + sqrt(max(b * b - c, 0.0));
            exit_x = normalize(pos + dir * t);
            exit_w = dir;
            break;
        }
        pos = next;
        arriving = dir;
        n += 1.0;
        if m > 0u {
            phi_k *= albedo;
            exact_offer(pos, dir, exact_proxy(pos, dir, nl, f2, tau, g), phi_k, m);
        }
    }
    // Weights Q/q; slots holding the same event share one shadow ray.
    var used = 0u;
    for (var i = 0u; i < m; i++) {
        if !(ex_q[i] > 0.0) {
            continue;
        }
        let wgt = ex_total / ex_q[i];
        var merged = false;
        for (var j = 0u; j < used; j++) {
            if all(ex_x[j] == ex_x[i]) && all(ex_w[j] == ex_w[i]) {
                ex_weight[j] += wgt;
                merged = true;
                break;
            }
        }
        if !merged {
            ex_x[used] = ex_x[i];
            ex_w[used] = ex_w[i];
            ex_weight[used] = wgt;
            used += 1u;
        }
    }
    return ExactWalk(exit_x, exit_w, n, used);
}
