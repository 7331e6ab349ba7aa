// Kernel: ST-CVAE sphere tracing with NEE through EventGen (crates/render-gpu/src/
// integrator/sphere_step.rs). Composed as common + scene + nee + decoder + stcvae + path.
//
// φ^N already contains the albedo of event 1 (the collision at p), so p gets no separate
// albedo weight and no separate NEE: EventGen's representative event, weighted Λ(N),
// stands for NEE at all N events of the walk.

const SHRINK: f32 = 0.9999;

fn scatter_at(channel: u32) -> bool {
    let sigma = params.sigma_t[channel];
    let min_tau = params.consts.w;
    let max_tau = params.consts2.x;
    let near = params.consts2.y;
    let grid_free = grid_radius(ps.pos);
    // The path's own bound (what is left of its last free ball) costs nothing.
    var free = max(grid_free, ps.free);
    if free < near && sigma * free < min_tau {
        // The grid's Lipschitz bound loses up to two cell half-diagonals near the surface; the
        // exact distance often still allows a sphere step there. It comes from the cell's
        // candidate triangles, or else from a search that stops at the largest distance
        // the grid allows.
        var exact = grid_exact_distance(ps.pos);
        if exact < 0.0 {
            exact = surface_distance(ps.pos, grid_distance_upper_bound(grid_free));
        }
        free = max(free, exact * (1.0 - 1e-5) - params.consts.z);
    }
    let r = min(free * SHRINK, max_tau / sigma);
    let tau = sigma * r;
    let fallback = !(r > 0.0) || tau < min_tau;
    let nee = params.flags.y != 0u;
    let g = params.consts.x;
    let centre = ps.pos;
    // SIMD shape (lavapipe runs 8 invocations in lock-step, GPUs 32–64): the PT fallback
    // and the sphere step share one NEE loop, one EventGen call and one shadow-ray query
    // below, so lanes in different branches do not run each of them one after the other.
    var frame: WalkFrame; // set by the sphere step; unused by the fallback
    var n = 1.0;
    var e = Exit(1.0, 0.0, 0.0);
    var single = false;
    var wf: WalkFeatures;
    var lam = 0.0; // Λ(N) of the sphere step's walk
    var nee_count = 0u;
    var nee_weight = 0.0;
    if fallback {
        // A real collision handled as in PT (pt_event): NEE here, then albedo and HG.
        ps.free = max(free, 0.0);
        stats[C_EVENTS] += 1u;
        if nee {
            nee_count = 1u;
            nee_weight = ps.beta * params.albedo[channel];
        }
    } else {
        stats[C_STEPS] += 1u;
        frame = walk_frame(ps.dir, unit_circle());
        // The walk: exact N = 1 branch (probability e^−τ, no decoder), else the decoders.
        if model.flags.x != 0u && rand() < exp(-tau) {
            single = true;
            e = Exit(hg_sample_cos(g, rand()), 0.0, 0.0);
        } else {
            wf = walk_features(tau, g);
            n = sample_multiple_n(wf);
            wf.rel_log_n = log(n) - wf.log_prior;
            e = sample_exit(wf);
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
        if !fallback {
            var ev = Event(vec3<f32>(0.0), vec3<f32>(0.0, 0.0, 1.0));
            if !single {
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
        sum += nee_direct(x, w, x_free, ball_c, ball_f, channel);
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
    let xc = canonical_exit_point(e.cos_theta);
    let wc = canonical_exit_dir(e.cos_theta, e.alpha, e.beta);
    ps.pos = centre + to_world(frame, xc) * r;
    ps.dir = normalize(to_world(frame, wc));
    ps.scattered = true;
    // The grid at the exit often knows more than the ball it left (sphere_step.rs); in
    // dense media (cells many free paths wide) the exact distance spares most of the
    // next flights' ray casts (EXIT_REFINE_TAU, prepended from sphere_step.rs).
    ps.free = max(free - r, grid_radius(ps.pos));
    if sigma * ps.free < EXIT_REFINE_TAU && sigma * near > 4.0 * EXIT_REFINE_TAU {
        let d = grid_exact_distance(ps.pos);
        if d >= 0.0 {
            ps.free = max(ps.free, d * (1.0 - 1e-5) - params.consts.z);
        }
    }
    return true;
}
