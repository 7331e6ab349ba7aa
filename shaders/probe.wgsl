// Test kernels: run the shared includes on inputs from the host so tests can compare them
// with the Rust implementations (crates/render-gpu/tests/gpu/wgsl_blocks.rs). Composed as
// common + scene + nee + decoder + pt + path + probe. Items are 8 vec4s (32 floats) in
// `accum`; params.image.x holds the item count.

fn item_f(i: u32, k: u32) -> f32 {
    return accum[i * 8u + k / 4u][k % 4u];
}

/// Floats 4q..4q + 3 of item i as a vector (q = 0: floats 0..3, q = 1: floats 4..7).
fn item_v3(i: u32, q: u32) -> vec3<f32> {
    return accum[i * 8u + q].xyz;
}

fn set_f(i: u32, k: u32, v: f32) {
    accum[i * 8u + k / 4u][k % 4u] = v;
}

/// Zeroes item i's 32 floats (outputs a probe does not write read back as 0).
fn clear_item(i: u32) {
    for (var k = 0u; k < 32u; k++) {
        set_f(i, k, 0.0);
    }
}

// The item layout below holds the decoders' whole scratch (gpu/decoder_gen.rs).
const_assert DEC_MAX_COND == 12u && DEC_MAX_NOISE == 16u && DEC_MAX_OUT == 8u;

/// Item i's decoder conditions (floats 0..12) and noise (12..28) into the decoders' inputs.
fn load_decoder_inputs(i: u32) {
    for (var k = 0u; k < 12u; k++) {
        dec_cond[k] = item_f(i, k);
    }
    for (var k = 0u; k < 16u; k++) {
        dec_noise[k] = item_f(i, 12u + k);
    }
}

/// In: cond[0..12], noise[12..28], decoder id at 28. Out: outputs at 0..8.
@compute @workgroup_size(WORKGROUP)
fn probe_decoder(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    load_decoder_inputs(i);
    decoder_sample(u32(item_f(i, 28u)));
    for (var k = 0u; k < 8u; k++) {
        set_f(i, k, dec_out[k]);
    }
}

/// Decoder throughput (`stcvae bench decoders`). In: as probe_decoder, plus rounds at 29.
/// Out, at 31 (the inputs stay, for the next timed dispatch): the sum over the rounds of
/// output 0, each round with its first noise value moved by 1e-3 more (so no round can be
/// folded into another; the host recomputes some sums). A
/// decoder chosen by a constant (`which` < 3, inlined, as the render kernels call them) or
/// by the item's id, known only at run time (3): on a driver that runs every branch of an
/// `if` whether or not a lane takes it (Mesa 22's llvmpipe) that case costs all three.
fn decoder_rate(i: u32, which: u32) {
    load_decoder_inputs(i);
    let id = u32(item_f(i, 28u));
    let rounds = u32(item_f(i, 29u));
    var sum = 0.0;
    for (var r = 0u; r < rounds; r++) {
        dec_noise[0] += 1e-3;
        if which == 0u {
            decoder_sample(0u);
        } else if which == 1u {
            decoder_sample(1u);
        } else if which == 2u {
            decoder_sample(2u);
        } else if id == 0u {
            decoder_sample(0u);
        } else if id == 1u {
            decoder_sample(1u);
        } else {
            decoder_sample(2u);
        }
        sum += dec_out[0];
    }
    set_f(i, 31u, sum);
}

@compute @workgroup_size(WORKGROUP)
fn probe_decoder_rate_0(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < params.image.x {
        decoder_rate(gid.x, 0u);
    }
}

@compute @workgroup_size(WORKGROUP)
fn probe_decoder_rate_1(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < params.image.x {
        decoder_rate(gid.x, 1u);
    }
}

@compute @workgroup_size(WORKGROUP)
fn probe_decoder_rate_2(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < params.image.x {
        decoder_rate(gid.x, 2u);
    }
}

@compute @workgroup_size(WORKGROUP)
fn probe_decoder_rate_any(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < params.image.x {
        decoder_rate(gid.x, 3u);
    }
}

/// In: g, ξ at 0, 1; dir at 4..7; (cos ψ, sin ψ) at 8, 9; exit (cos θ, α, β) at 12..15;
/// X at 16..19. Out: HG (cos θ, sin θ) at 0, 1; deflect(dir, θ, ψ) at 4..7, normalised at
/// 20..23, and HG's density from dir to it at 2; world exit point at 8..11; world exit
/// direction at 12..15; world X at 16..19; the canonical exit point of HG's (cos θ, sin θ)
/// (the single-scattering branch's exit) at 24..27.
@compute @workgroup_size(WORKGROUP)
fn probe_frame(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let g = item_f(i, 0u);
    let xi = item_f(i, 1u);
    let dir = item_v3(i, 1u);
    let cs = vec2<f32>(item_f(i, 8u), item_f(i, 9u));
    let ct = item_f(i, 12u);
    let al = item_f(i, 13u);
    let be = item_f(i, 14u);
    let x = vec3<f32>(item_f(i, 16u), item_f(i, 17u), item_f(i, 18u));
    let c = hg_sample(g, xi);
    let d = deflect(dir, c, cs);
    let l = normalize(d);
    let single_exit = canonical_exit_point(c.x, c.y);
    let f = walk_frame(dir, cs);
    let p = to_world(f, canonical_exit_point(ct, sin_of_cos(ct)));
    let w = to_world(f, canonical_exit_dir(ct, sin_of_cos(ct), al, be));
    let xw = to_world(f, x);
    clear_item(i);
    set_f(i, 0u, c.x);
    set_f(i, 1u, c.y);
    set_f(i, 2u, hg_pdf_between(g, dir, l));
    for (var k = 0u; k < 3u; k++) {
        set_f(i, 4u + k, d[k]);
        set_f(i, 20u + k, l[k]);
        set_f(i, 24u + k, single_exit[k]);
        set_f(i, 8u + k, p[k]);
        set_f(i, 12u + k, w[k]);
        set_f(i, 16u + k, xw[k]);
    }
}

/// In: origin at 0..3, direction at 4..7 (scene geometry bound). Out: closest hit found
/// (1/0) and t at 0, 1; the unordered crossings' exits − entries and inside length at 2, 3;
/// `trace`'s closest hit (found, t, triangle) at 4..6 and `intersect`'s triangle at 7;
/// `trace`'s crossings (exits − entries, length, Fresnel) at 8..10 and `crossings`' Fresnel
/// at 11.
@compute @workgroup_size(WORKGROUP)
fn probe_ray(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    stack_base = li * STACK_STRIDE;
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let o = item_v3(i, 0u);
    let d = item_v3(i, 1u);
    let h = intersect(o, d, 1e30);
    let c = crossings(o, d);
    // The path loop's shared traversal in both modes (scene.wgsl, trace).
    let th = trace(o, d, 1e30, false);
    _ = trace(o, d, 1e30, true);
    let tc = tr_cross;
    clear_item(i);
    set_f(i, 0u, select(0.0, 1.0, h.found));
    set_f(i, 1u, h.t);
    set_f(i, 2u, f32(c.balance));
    set_f(i, 3u, c.length);
    set_f(i, 4u, select(0.0, 1.0, th.found));
    set_f(i, 5u, th.t);
    set_f(i, 6u, f32(th.prim));
    set_f(i, 7u, f32(h.prim));
    set_f(i, 8u, f32(tc.balance));
    set_f(i, 9u, tc.length);
    set_f(i, 10u, tc.fresnel_t);
    set_f(i, 11u, c.fresnel_t);
}

/// In: a point at 0..3 (scene geometry and distance grid bound). Out: the grid radius,
/// the candidate lists' exact distance (-1 without a list) and the BVH search's distance
/// at 0, 1, 2.
@compute @workgroup_size(WORKGROUP)
fn probe_grid(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    stack_base = li * STACK_STRIDE;
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let p = item_v3(i, 0u);
    let r = grid_radius(p);
    let exact = grid_exact_distance(p);
    let searched = surface_distance(p, 1e30);
    clear_item(i);
    set_f(i, 0u, r);
    set_f(i, 1u, exact);
    set_f(i, 2u, searched);
}

/// In: a segment's origin at 0..3, direction at 4..7, length at 8 (scene geometry and
/// distance grid bound). Out: whether the origin's cell list answered it (1/0) at 0; its
/// hit found (1/0), t and triangle at 1, 2, 3; the BVH's at 4, 5, 6.
@compute @workgroup_size(WORKGROUP)
fn probe_local_hit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    stack_base = li * STACK_STRIDE;
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let o = item_v3(i, 0u);
    let d = item_v3(i, 1u);
    let tmax = item_f(i, 8u);
    var local = Hit(0.0, 0u, false);
    let answered = grid_local_hit(o, d, tmax, &local);
    let full = intersect(o, d, tmax);
    clear_item(i);
    set_f(i, 0u, select(0.0, 1.0, answered));
    set_f(i, 1u, select(0.0, 1.0, local.found));
    set_f(i, 2u, local.t);
    set_f(i, 3u, f32(local.prim));
    set_f(i, 4u, select(0.0, 1.0, full.found));
    set_f(i, 5u, full.t);
    set_f(i, 6u, f32(full.prim));
}

/// In: a shadow ray's origin at 0..3 and direction at 4..7 (scene bound, its medium and
/// boundary in params). Out: nee.wgsl's transmittance in channels 0, 1, 2 at 0..2;
/// whether the origin is in the medium (scene.wgsl, in_union, for meshes whose pieces
/// overlap) at 3; whether the ray crossed more faces than the sorted list holds (u_more)
/// at 4; nee.wgsl's shadow (refracted where it leaves a dielectric, the beam's r
/// included) at 5, in the channel given at 3. One refracted shadow ray an item: on
/// lavapipe (Mesa 22.3.6) the third in a row came out wrong for ~25 of 4,000 rays, only
/// in 8-lane groups whose rays diverge (each such ray alone, or its first two calls,
/// gave the CPU's value; with the traversal stack in workgroup or private memory alike).
@compute @workgroup_size(WORKGROUP)
fn probe_shadow(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    stack_base = li * STACK_STRIDE;
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let o = item_v3(i, 0u);
    let d = item_v3(i, 1u);
    // (Read before transmittance: its ordered walk's in_union traversals reset u_more.)
    _ = crossings(o, d);
    let more = u_more;
    var t = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        t[c] = transmittance(o, d, c);
    }
    let inside = overlapping() && in_union(o, d);
    let refracted = shadow(o, d, u32(item_f(i, 3u)));
    clear_item(i);
    set_f(i, 0u, t.x);
    set_f(i, 1u, t.y);
    set_f(i, 2u, t.z);
    set_f(i, 3u, select(0.0, 1.0, inside));
    set_f(i, 4u, select(0.0, 1.0, more));
    set_f(i, 5u, refracted);
}

/// In: an event's position at 0..3 and direction at 4..7, the channel at 3, its grid
/// ball's radius at 7, its step's free ball (centre at 8..11, radius at 11). Out:
/// nee_proxy (the path-level reservoirs' proxy; nee.rs, proxy) at 0.
@compute @workgroup_size(WORKGROUP)
fn probe_proxy(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let x = item_v3(i, 0u);
    let w = item_v3(i, 1u);
    let c = item_v3(i, 2u);
    let q = nee_proxy(x, w, item_f(i, 7u), c, item_f(i, 11u), u32(item_f(i, 3u)));
    clear_item(i);
    set_f(i, 0u, q);
}

/// In: WalkFeatures (tau feature, g, log prior, relative log N) at 0..3; exit (cos θ, α,
/// β) at 4..6; an RNG seed at 8. The test gives a learned-mode model (model.flags.x = 0),
/// so the exact mode's centre event never comes up.
/// Out: the noise of a fresh EventGen draw at 0..10 and of its mirrored partner at 11..21
/// (DEC_LATENT_2 + DEC_OUT_2 = 11 for the shipped model); the partner's event X at
/// 22..24 and W at 25..27.
@compute @workgroup_size(WORKGROUP)
fn probe_event_pair(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let wf = WalkFeatures(item_f(i, 0u), item_f(i, 1u), item_f(i, 2u), item_f(i, 3u));
    let e = Exit(item_f(i, 4u), item_f(i, 5u), item_f(i, 6u));
    rng_seed(u32(item_f(i, 8u)), 0u, i, 0u);
    let n = min(DEC_LATENT_2 + DEC_OUT_2, 11u);
    clear_item(i);
    let first = sample_event(wf, 0u, 2.0, e, false);
    for (var k = 0u; k < n; k++) {
        set_f(i, k, dec_noise[k]);
    }
    let second = sample_event(wf, 0u, 2.0, e, true);
    for (var k = 0u; k < n; k++) {
        set_f(i, 11u + k, dec_noise[k]);
    }
    for (var k = 0u; k < 3u; k++) {
        set_f(i, 22u + k, second.x[k]);
        set_f(i, 25u + k, second.w[k]);
    }
}

/// In: WalkFeatures (tau feature, g, log prior, relative log N) at 0..3; an RNG seed at
/// 8. Out: LengthGen's N at 0 and the normals it drew at 1..11 (DEC_LATENT_0 + DEC_OUT_0
/// of them, at most 11); PathGen's exit (cos θ, α, β) for the given relative log N at
/// 12..14 and its normals at 16..31 (at most 16).
@compute @workgroup_size(WORKGROUP)
fn probe_length_path(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let wf = WalkFeatures(item_f(i, 0u), item_f(i, 1u), item_f(i, 2u), item_f(i, 3u));
    rng_seed(u32(item_f(i, 8u)), 0u, i, 0u);
    clear_item(i);
    set_f(i, 0u, sample_multiple_n(wf));
    for (var k = 0u; k < min(DEC_LATENT_0 + DEC_OUT_0, 11u); k++) {
        set_f(i, 1u + k, dec_noise[k]);
    }
    let e = sample_exit(wf);
    set_f(i, 12u, e.cos_theta);
    set_f(i, 13u, e.alpha);
    set_f(i, 14u, e.beta);
    for (var k = 0u; k < min(DEC_LATENT_1 + DEC_OUT_1, 16u); k++) {
        set_f(i, 16u + k, dec_noise[k]);
    }
}

/// In: τ at 0, g at 1. Out: walk_features' τ feature and log prior (the conditioning
/// every sphere step computes, decoder.wgsl) at 0, 1.
@compute @workgroup_size(WORKGROUP)
fn probe_features(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let wf = walk_features(item_f(i, 0u), item_f(i, 1u));
    clear_item(i);
    set_f(i, 0u, wf.tau);
    set_f(i, 1u, wf.log_prior);
}

/// In: loop iterations n at 0, loop-limit probe passes at 1. Out: the iterations that ran
/// at 0 (fewer than n where llvmpipe's loop limit cut the loop), 1 at 1 if the probe then
/// saw the limit run out. No clear_item: after a cut-off its loop would run one pass.
@compute @workgroup_size(WORKGROUP)
fn probe_loop_limit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    let n = u32(item_f(i, 0u));
    let passes = u32(item_f(i, 1u));
    var k = 0u;
    var x = item_f(i, 2u);
    loop {
        if k >= n {
            break;
        }
        x = x * 0.5 + 1.0;
        k += 1u;
    }
    let cut = loop_limit_ran_out(passes);
    set_f(i, 0u, f32(k));
    set_f(i, 1u, select(0.0, 1.0, cut));
    set_f(i, 2u, x);
}

/// In: the path counters' counts (u32 bits) at 0..PATH_COUNTERS. Adds them to the counters as a
/// path slot adds its own (path.wgsl, add_stats); items past the count leave their lanes
/// inactive, as finished slots do.
@compute @workgroup_size(WORKGROUP)
fn probe_counters(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.image.x {
        return;
    }
    for (var k = 0u; k < PATH_COUNTERS; k++) {
        stats[k] = bitcast<u32>(item_f(i, k));
    }
    add_stats();
}
