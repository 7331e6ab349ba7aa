// Shared include: the path loop of both integrators (crates/render-gpu/src/integrator/
// mod.rs) and the render entry point. The kernel file included before this one defines
// `scatter_at(channel)`, what happens at a real collision: a PT event (pt.wgsl) or a
// sphere step (stcvae.wgsl); it returns true after a sphere step.

// RR_THRESHOLD and MAX_ITERATIONS are the CPU integrator's (prepended by gpu/kernels.rs).

// Counter slots (pairs lo/hi): the path counters C_PATHS, C_EVENTS, C_STEPS, C_LEAKS,
// C_CAPPED, C_NON_FINITE, C_PENDING, C_TRUNCATED, C_EXACT, C_EXACT_EVENTS (numbered in
// gpu/resources.rs, slot, and prepended by gpu/kernels.rs); then, from slot
// PATH_COUNTERS, three per lane-profile phase (active lanes, capacity, passes:
// gpu/kernels.rs, profile_wgsl).

var<private> stats: array<u32, PATH_COUNTERS>;

struct PathState {
    pos: vec3<f32>,
    dir: vec3<f32>,
    beta: f32,
    radiance: f32,
    scattered: bool,
    alive: bool,
    // Lower bound on the distance to the surface (0: unknown); set by sphere steps, saved
    // with the path between dispatches. See PathState::free on the CPU. Negative in a
    // path just spawned inside: minus the medium its spawn passed (PathState::skip),
    // taken off its next flight.
    free: f32,
}

var<private> ps: PathState;
/// The triangle the path has just left the surface through, outward (NO_TRI: none); a
/// direction in its escape cone (cos θ in the triangle's n.w) escapes without a cast
/// (escape_cone.rs). Not saved between the single kernel's dispatches: NO_TRI is always
/// safe (the staged render keeps it).
const NO_TRI: u32 = 0xffffffffu;
var<private> p_left_through: u32;

fn roulette() -> bool {
    if ps.beta >= RR_THRESHOLD {
        return true;
    }
    if ps.beta <= 0.0 {
        return false;
    }
    if rand() * RR_THRESHOLD < ps.beta {
        ps.beta = RR_THRESHOLD;
        return true;
    }
    return false;
}

/// An ordinary PT scattering event at ps.pos (a real collision).
fn pt_event(channel: u32) {
    stats[C_EVENTS] += 1u;
    let albedo = params.albedo[channel];
    if NEE {
        ps.radiance += ps.beta * albedo * nee_direct(ps.pos, ps.dir, ps.free, ps.pos, 0.0, channel, true);
    }
    ps.beta *= albedo;
    if !roulette() {
        ps.alive = false;
        return;
    }
    ps.dir = hg_sample_direction(params.consts.x, ps.dir);
    ps.scattered = true;
}

fn escape_radiance(dir: vec3<f32>, channel: u32, with_sun: bool) -> f32 {
    var l = env_lookup(dir, channel);
    if with_sun {
        for (var i = 0u; i < LIGHTS; i++) {
            l += light_radiance_toward(i, dir, channel);
        }
    }
    return l;
}

// The rest of a path's state between bounces (private: one path per invocation).
var<private> p_channel: u32;
var<private> p_inside: bool;
var<private> p_from_step: bool;
var<private> p_iterations: u32;
// Path-level NEE after the path's last bounce: how many shadow rays are left (ray r =
// PATH_NEE_M·lights − left is reservoir r / lights toward light r % lights; > 0 only for
// an ended path), Σ_k (Σ_i T·f)/q_k over the reservoirs done and Σ_i T·f of the one under
// way (PathNee::finish, summed in its order).
var<private> p_nee_left: u32;
var<private> p_nee_sum: f32;
var<private> p_nee_light: f32;

fn start_path(origin: vec3<f32>, dir: vec3<f32>, channel: u32) {
    stats[C_PATHS] += 1u;
    ps = PathState(origin, dir, 1.0, 0.0, false, true, 0.0);
    p_channel = channel;
    p_inside = false;
    p_from_step = false;
    p_left_through = NO_TRI;
    p_iterations = 0u;
    path_nee_reset();
    p_nee_left = 0u;
}

/// Whether `q`, spawned eps inside the surface at a hit whose outward normal is `n`, lies
/// beyond a sliver of medium thinner than eps, i.e. outside (Geometry::beyond_sliver):
/// the way back toward the hit meets a surface from outside first.
fn beyond_sliver(q: vec3<f32>, n: vec3<f32>) -> bool {
    let reach = params.consts.z * SLIVER_REACH_OF_EPS;
    var back: Hit;
    if !grid_local_hit(q, n, reach, &back) {
        back = intersect(q, n, reach);
    }
    return back.found && dot(tri_normal(back.prim), n) < 0.0;
}

/// A bounce's one ray query, between its start (bounce_begin) and its end (bounce_end):
/// in the one-kernel render the two run back to back; in the staged render (stage_main,
/// trace_main) a queue of these is traced by its own dispatch in between.
struct Query {
    o: vec3<f32>,
    tmax: f32,
    d: vec3<f32>,
    // The flight's sampled length (inside).
    t: f32,
    // A shadow ray's light weight, its reservoir, and whether it is the last light's.
    weight: f32,
    k: u32,
    last_light: bool,
    // A finished path's shadow ray (every crossing), else a closest-hit query.
    shadow: bool,
    // Whether a ray is traced at all (a flight inside a known free ball, a direction in
    // the escape cone, or a dark light's shadow ray: not).
    query: bool,
    // A flight inside: its grid cell's list may answer it.
    local: bool,
    // The bounce has already ended (the path hit the iteration cap).
    ended: bool,
}

/// One iteration of the CPU path loop; sets ps.alive = false when the path ends. The
/// kernel interleaves paths through this (path regeneration): an invocation whose path
/// ended starts its next sample instead of idling until the longest path of its SIMD
/// group is done — path lengths are heavy-tailed, so this is most of the speed. After the
/// path's end, each call casts one of its path-level NEE shadow rays instead
/// (p_nee_left > 0).
fn bounce() {
    let q = bounce_begin();
    if q.ended {
        return;
    }
    var h = answer_query(q, p_channel);
    var tr = 0.0;
    if q.shadow && q.query {
        tr = shadow_of(tr_cross, q.o, q.d, p_channel);
        h = refraction_hit();
    }
    bounce_end(q, h, tr);
}

/// The bounce up to its ray query. One ray query for every lane, outside (unbounded) or
/// inside (up to the sampled flight, skipped inside a known free ball, answered from the
/// grid cell's list near the surface), or a finished path's shadow ray: lanes in
/// different phases share one traversal instead of running two or three in turn.
/// (PATH_NEE_M is a constant: without path-level NEE, PT's kernel among them, the
/// compiler is left a closest-hit query, as fast as before this was shared.)
fn bounce_begin() -> Query {
    prof(0u);
    let nee_ray = PATH_NEE_M > 0u && p_nee_left > 0u;
    var q = Query(ps.pos, 1e30, ps.dir, 0.0, 0.0, 0u, false, nee_ray, true, false, false);
    if nee_ray {
        // nee_direct(x, w, 0, x, 0, channel, false) of reservoir k toward one light, its
        // random numbers drawn in the same order.
        let nl = max(LIGHTS, 1u);
        let r = PATH_NEE_M * nl - p_nee_left;
        q.k = r / nl;
        q.last_light = r % nl == nl - 1u;
        q.o = pn_x[q.k];
        let ray = nee_light_ray(r % nl, q.o, pn_w[q.k], 0.0, q.o, 0.0, p_channel, false);
        q.d = ray.dir;
        q.weight = ray.weight;
        q.query = ray.casts;
        return q;
    }
    p_iterations += 1u;
    if p_iterations > MAX_ITERATIONS {
        stats[C_CAPPED] += 1u;
        ps.alive = false;
        q.ended = true;
        return q;
    }
    if p_inside {
        let skip = max(-ps.free, 0.0);
        let drawn = -log(1.0 - rand()) / params.sigma_t[p_channel];
        if drawn < skip {
            // A collision within the way the spawn passed, at its own depth unless the
            // way back crosses a face (integrator/mod.rs).
            let back = min(skip - drawn, SKIP_BACK * skip);
            if !intersect(ps.pos, -ps.dir, back + SKIP_CLEAR_OF_EPS * params.consts.z).found {
                ps.pos -= ps.dir * back;
                q.o = ps.pos;
            }
        }
        q.t = max(drawn - skip, 0.0);
        // The query looks just past the collision (integrator/mod.rs: a collision rounded
        // to the far side of a surface would leave the path outside); flight_end keeps a
        // face found only there from being reached.
        q.tmax = q.t + params.consts.z * FLIGHT_MARGIN_OF_EPS;
        // A flight shorter than the known free distance cannot reach the surface.
        q.query = q.t >= ps.free;
        q.local = true;
    }
    if !p_inside && p_left_through != NO_TRI {
        let left = tris[p_left_through].n;
        q.query = dot(ps.dir, left.xyz) < left.w;
    }
    p_left_through = NO_TRI;
    return q;
}

/// The query's answer: the closest hit, or (a shadow ray) none, with every crossing left
/// in tr_cross. A flight inside near the surface is answered from its grid cell's list
/// (ST-CVAE; PT renders have no grid), as on the CPU (integrator/mod.rs, short_cast).
fn answer_query(q: Query, channel: u32) -> Hit {
    var h = Hit(0.0, 0u, false);
    if q.shadow && overlapping() {
        // Its crossings are gathered by transmittance_union (nee.wgsl).
        return h;
    }
    if q.query && !(q.local && grid_local_hit(q.o, q.d, q.tmax, &h)) {
        if PATH_NEE_M > 0u {
            h = trace(q.o, q.d, q.tmax, q.shadow);
        } else {
            h = intersect(q.o, q.d, q.tmax);
        }
    }
    return h;
}

/// Where the last shadow ray of shadow_of refracted, as a hit (none: it stayed
/// straight), for bounce_end's phase ratio.
fn refraction_hit() -> Hit {
    return Hit(sh_first_t, sh_first_prim, sh_first_t < 1e29);
}

/// The bounce after its ray query: `h` its hit (a shadow ray's nearest crossing), `tr` a
/// shadow ray's transmittance.
fn bounce_end(q: Query, h: Hit, tr: f32) {
    if q.shadow {
        if q.query {
            let first_t = select(1e30, h.t, h.found);
            p_nee_light += tr * q.weight * refracted_phase_ratio(first_t, h.prim, q.d, pn_w[q.k]);
        }
        if q.last_light {
            p_nee_sum += p_nee_light / pn_q[q.k];
            p_nee_light = 0.0;
        }
        p_nee_left -= 1u;
        return;
    }
    if flight_end(q.t, h) {
        prof(6u);
        p_from_step = scatter_at(p_channel);
    }
}

/// A flight of length `t` (inside) or to the surface (outside) that met `h`: the surface
/// crossed, reflected or refracted, or the collision reached. True when the path is at a
/// collision inside, for its sphere step or PT event.
fn flight_end(t: f32, h: Hit) -> bool {
    let channel = p_channel;
    let dielectric = DIELECTRIC; // a constant (kernels.rs, SceneSwitches)
    let ior = params.consts.y;
    let nee = NEE;
    if !p_inside {
        if !h.found {
            ps.radiance += ps.beta * escape_radiance(ps.dir, channel, !(nee && ps.scattered));
            ps.alive = false;
            return false;
        }
        let p = ps.pos + ps.dir * h.t;
        var n = tri_normal(h.prim);
        var turned = false;
        if overlapping() {
            let past = spawn(p, n, ps.dir);
            if !in_union(past, ps.dir) {
                // A face crossed in air (within a cavity's piece): no boundary
                // (integrator/mod.rs).
                ps.pos = past;
                return false;
            }
            // Into the medium: its boundary's normal faces the air the path is in.
            if dot(ps.dir, n) > 0.0 {
                n = -n;
                turned = true;
            }
        }
        if dot(ps.dir, n) > 0.0 {
            // Met a surface from inside while believed outside: spawned across a gap
            // thinner than eps into a touching part; enter it here (integrator/mod.rs).
            p_inside = true;
            return false;
        }
        let incoming = ps.dir;
        if dielectric {
            let f = fresnel(abs(dot(ps.dir, n)), 1.0, ior);
            if rand() < f {
                ps.dir = reflect_dir(ps.dir, n);
                // Light the path meets from here on is not NEE's (integrator/mod.rs).
                ps.scattered = false;
                // (A turned normal is not the one the triangle's escape cone is about.)
                p_left_through = select(h.prim, NO_TRI, turned);
            } else {
                ps.dir = refract_dir(ps.dir, n, 1.0, ior);
                p_inside = true;
            }
        } else {
            p_inside = true;
        }
        ps.pos = spawn(p, n, ps.dir);
        if p_inside && beyond_sliver(ps.pos, n) {
            // Pass the sliver in the direction the path came (integrator/mod.rs).
            p_inside = false;
            ps.dir = incoming;
        }
        if p_inside {
            ps.free = -spawn_skip(n, ps.dir);
        }
        return false;
    }
    // A face found only thanks to the flight margin (beyond t) is not reached: the
    // collision stands, the margin short of the face (Geometry::flight_end). Met from
    // outside (a leak), it is still the face.
    var reached = h.found;
    var t_end = t;
    if h.found && h.t > t && (overlapping() || dot(ps.dir, tri_normal(h.prim)) >= 0.0) {
        reached = false;
        t_end = min(t, max(h.t - params.consts.z * FLIGHT_MARGIN_OF_EPS, 0.0));
    }
    if reached {
        ps.free = 0.0;
        let p = ps.pos + ps.dir * h.t;
        var n = tri_normal(h.prim);
        var turned = false;
        if overlapping() {
            let past = spawn(p, n, ps.dir);
            if in_union(past, ps.dir) {
                // A face within the union of overlapping pieces: no boundary; the flight
                // goes on, its rest redrawn from the face (integrator/mod.rs).
                ps.pos = past;
                ps.free = -spawn_skip(n, ps.dir);
                p_from_step = false;
                return false;
            }
            // Out of the medium: its boundary's normal faces the air ahead.
            if dot(ps.dir, n) < 0.0 {
                n = -n;
                turned = true;
            }
        }
        if dot(ps.dir, n) < 0.0 {
            // Met the surface from outside while believed inside: after a sphere step
            // the exit was not inside after all. Count it; as on the CPU (integrator/mod.rs)
            // the path goes on past the surface believed outside, and the touching-parts
            // rule takes it in at the next cast.
            if p_from_step {
                stats[C_LEAKS] += 1u;
            }
            p_inside = false;
            ps.pos = spawn(p, n, ps.dir);
            p_from_step = false;
            return false;
        }
        if dielectric {
            let f = fresnel(abs(dot(ps.dir, n)), ior, 1.0);
            if rand() < f {
                ps.dir = reflect_dir(ps.dir, n);
                ps.scattered = false; // (as above)
            } else {
                ps.dir = refract_dir(ps.dir, n, ior, 1.0);
                p_inside = false;
            }
        } else {
            p_inside = false;
        }
        if !p_inside && !turned {
            p_left_through = h.prim;
        }
        ps.pos = spawn(p, n, ps.dir);
        if p_inside && beyond_sliver(ps.pos, n) {
            // Reflected back inside where the medium is thinner than the offset.
            p_inside = false;
        }
        if p_inside {
            ps.free = -spawn_skip(n, ps.dir);
        }
        p_from_step = false;
        return false;
    }
    ps.pos += ps.dir * t_end;
    ps.free = max(ps.free - t_end, 0.0);
    let pad = params.consts.z; // eps, as in Geometry::within_bounds
    if any(ps.pos < mesh_bounds(false) - pad) || any(ps.pos > mesh_bounds(true) + pad) {
        // Outside the mesh's bounding box grown by eps: not inside after all (the CPU's
        // safety net, integrator/mod.rs).
        stats[C_LEAKS] += 1u;
        p_inside = false;
        ps.free = 0.0;
        p_from_step = false;
        return false;
    }
    return true;
}

/// The finished path's estimate (non-finite ones counted and dropped).
fn path_result() -> f32 {
    if is_finite(ps.radiance) {
        return ps.radiance;
    }
    stats[C_NON_FINITE] += 1u;
    return 0.0;
}

fn add_counter(slot: u32, v: u32) {
    if v == 0u {
        return;
    }
    let old = atomicAdd(&counters[2u * slot], v);
    if old + v < old {
        atomicAdd(&counters[2u * slot + 1u], 1u);
    }
}

// C_PENDING counts the invocations that still have work after this dispatch;
// C_TRUNCATED those whose bounce loop ended early (a driver loop limit: see below).

/// A path between dispatches, one per (pixel, lane), in `accum` as SLOT = 7 + 2·PATH_NEE_M
/// (+ 3 with VARIANCE) vec4s (prepended by kernels.rs): position and β (once the path has
/// ended and its NEE rays are under way, p_nee_sum and p_nee_light instead); direction and
/// radiance; the RNG state; channel (bits 0–7) | flags (8–15) | NEE rays left (16–),
/// iterations, samples finished, the free distance (f32 bits; the current sample follows
/// from the samples finished); the accumulated RGB + finished-sample count of the whole
/// render (ACC); then per path-level NEE reservoir its event's (X, q) and (W, A); with
/// VARIANCE the squared sums (below); the rounding ACC's RGB lost (ACC_LO = SLOT − 2,
/// add_sample), with the slot's PT events + sphere steps in w (the work map, slot_end);
/// last ACC as the chunk began, its lost rounding added back (COMMITTED = SLOT − 1: what a
/// render stopped mid-chunk keeps, gpu/readout.rs).
// ACC, ACC_LO and COMMITTED (SLOT − 2 and SLOT − 1) are prepended from kernels.rs
// (ACC_VEC4, acc_lo_vec4, committed_vec4), the one layout the host reads back. With
// VARIANCE (`render --variance`) three vec4s before ACC_LO hold the sums of the squared
// values ACC adds, per channel, what their f32 additions rounded off, and those sums as
// the chunk began (ACC_SQ, ACC_SQ_LO, SQ_COMMITTED: kernels.rs, acc_sq_vec4 and the two
// after it, prepended too); without it they are not in the slot and never read.
const F_ALIVE: u32 = 1u;
const F_SCATTERED: u32 = 2u;
const F_INSIDE: u32 = 4u;
const F_FROM_STEP: u32 = 8u;
const F_DONE: u32 = 16u;

fn save_path(base: u32, j: u32, done: bool) {
    var flags = 0u;
    if ps.alive { flags |= F_ALIVE; }
    if ps.scattered { flags |= F_SCATTERED; }
    if p_inside { flags |= F_INSIDE; }
    if p_from_step { flags |= F_FROM_STEP; }
    if done { flags |= F_DONE; }
    // An ended path's position and β are not needed again: its NEE sums take their place
    // while its rays are under way (an ended path is saved only then, or done).
    accum[base] = select(vec4<f32>(ps.pos, ps.beta), vec4<f32>(p_nee_sum, p_nee_light, 0.0, 0.0), p_nee_left > 0u);
    accum[base + 1u] = vec4<f32>(ps.dir, ps.radiance);
    accum[base + 2u] = bitcast<vec4<f32>>(rng_s);
    accum[base + 3u] = bitcast<vec4<f32>>(vec4<u32>(p_channel | (flags << 8u) | (p_nee_left << 16u), p_iterations, j, bitcast<u32>(ps.free)));
    for (var i = 0u; i < PATH_NEE_M; i++) {
        accum[base + 5u + 2u * i] = vec4<f32>(pn_x[i], pn_q[i]);
        accum[base + 6u + 2u * i] = vec4<f32>(pn_w[i], pn_total);
    }
}

/// The path-level NEE reservoirs saved by save_path.
fn load_path_nee(base: u32) {
    path_nee_reset();
    for (var i = 0u; i < PATH_NEE_M; i++) {
        let a = accum[base + 5u + 2u * i];
        let b = accum[base + 6u + 2u * i];
        pn_x[i] = a.xyz;
        pn_q[i] = a.w;
        pn_w[i] = b.xyz;
        pn_total = b.w;
    }
}

/// (a·b) mod n without overflow for a, b < n < 2^32 (double-and-add).
fn mul_mod(a: u32, b: u32, n: u32) -> u32 {
    var r = 0u;
    var x = a % n;
    var y = b % n;
    loop {
        if y == 0u {
            break;
        }
        if (y & 1u) != 0u {
            r = add_mod(r, x, n);
        }
        x = add_mod(x, x, n);
        y = y >> 1u;
    }
    return r;
}

/// (a + b) mod n for a, b < n.
fn add_mod(a: u32, b: u32, n: u32) -> u32 {
    let s = a + b;
    if s < a || s >= n {
        return s - n;
    }
    return s;
}

/// Whether llvmpipe's loop limit has run out in this invocation. Once it has, every loop
/// stops after its first pass (Mesa's gallivm decrements one counter per invocation at
/// each loop's end and continues only while it is positive), so a loop of `passes` ≥ 2
/// passes runs only one. `passes` must come from a uniform or a buffer so that the
/// compiler cannot unroll the loop away (params.consts3.z = LOOP_PROBE_PASSES). A limit
/// that runs out exactly in this loop reads as cut off too: a harmless redo.
fn loop_limit_ran_out(passes: u32) -> bool {
    var probe = 0u;
    loop {
        probe += 1u;
        if probe >= passes {
            break;
        }
    }
    return probe < passes;
}

// The invocation's path slot and the samples it renders this chunk (slot_begin), shared
// by the one-kernel render (render_main) and the staged one (stage_main).
var<private> sl_base: u32;
var<private> sl_pixel_id: u32;
var<private> sl_px: u32;
var<private> sl_py: u32;
var<private> sl_offset: u32;
var<private> sl_first: u32;
var<private> sl_count: u32;
// Samples finished this chunk (the current one is sl_first + lanes · sl_j), whether all
// are, and the slot's accumulated RGB + finished-sample count.
var<private> sl_j: u32;
var<private> sl_done: bool;
var<private> sl_acc: vec4<f32>;
var<private> sl_lo: vec3<f32>;
// The slot's PT events + sphere steps over the render (ACC_LO.w): the per-pixel work map.
var<private> sl_work: f32;
// With VARIANCE: the sums of the squared values added to sl_acc, and what they rounded off.
var<private> sl_sq: vec3<f32>;
var<private> sl_sq_lo: vec3<f32>;

// The staged render's sphere steps (stcvae.wgsl, scatter_at; staged.wgsl, STAGED_STEPS):
// whether stage_main parks them for step_main, which runs each whole, whether this one was
// parked, and its optical radius if exact (its queue; −1 for a model step). Both flags stay
// false in the single kernel and in step_main.
var<private> park_steps: bool;
var<private> step_parked: bool;
var<private> step_tau: f32;

/// The path slot of invocation `gid`, or NO_SLOT.
const NO_SLOT: u32 = 0xffffffffu;
fn slot_of(gid: vec3<u32>) -> u32 {
    // Workgroups take tiles of WORKGROUP consecutive slots in a scattered order (w·P mod n, P
    // coprime with n: params.consts2.w), so that any contiguous range of workgroups — what
    // a CPU driver such as lavapipe hands one thread — covers the whole image, not its
    // cheap background rows or its expensive object rows alone. Within a workgroup the
    // slots stay neighbouring pixels, whose paths run alike in SIMD.
    let n_groups = (params.image.x * params.image.y * params.image.z + WORKGROUP - 1u) / WORKGROUP;
    let w = gid.x / WORKGROUP + gid.y * DISPATCH_ROW;
    if w >= n_groups {
        return NO_SLOT;
    }
    let tile = mul_mod(w, u32(params.consts2.w), n_groups);
    return tile * WORKGROUP + gid.x % WORKGROUP;
}

/// Slot `idx` and its state: a chunk's first dispatch (`kind` 1; 2: also the render's
/// first, which clears the accumulator) starts its first path, a later one (`kind` 0)
/// resumes the saved path. False when the slot is outside the image.
fn slot_begin(idx: u32, kind: u32) -> bool {
    let width = params.image.x;
    let lanes = params.image.z;
    let pixel = idx / lanes;
    let lane = idx % lanes;
    if pixel >= width * params.image.y {
        return false;
    }
    for (var i = 0u; i < PATH_COUNTERS; i++) {
        stats[i] = 0u;
    }
    sl_base = idx * SLOT;
    // An image too large for one accumulation binding is rendered in bands of rows
    // (gpu/bands.rs); `pixel` counts within the band, the seeds use the image's index.
    let row0 = u32(params.cam_right.w);
    sl_px = pixel % width;
    sl_py = pixel / width + row0;
    sl_pixel_id = pixel + row0 * width;
    if UNWRITTEN_PIXEL != 0xffffffffu && sl_pixel_id == UNWRITTEN_PIXEL {
        // A test hook (kernels.rs, KernelShape::unwritten_pixel): this pixel's slots stay
        // as the host poisoned them.
        return false;
    }
    sl_offset = channel_offset(params.sampling.z, params.sampling.w, sl_pixel_id);
    sl_first = params.sampling.x + lane;
    sl_count = 0u;
    if sl_first < params.sampling.y {
        // ⌈(end − first) / lanes⌉ without the sum that wraps near 2^32 samples.
        sl_count = min(params.image.w, (params.sampling.y - sl_first - 1u) / lanes + 1u);
    }
    sl_acc = accum[sl_base + ACC];
    let lo = accum[sl_base + ACC_LO];
    sl_lo = lo.xyz;
    sl_work = lo.w;
    if VARIANCE {
        sl_sq = accum[sl_base + ACC_SQ].xyz;
        sl_sq_lo = accum[sl_base + ACC_SQ_LO].xyz;
    }
    if kind == 2u {
        // First dispatch of the render: clear the accumulator (it was poisoned with NaN,
        // so a slot never reached shows on the host).
        sl_acc = vec4<f32>(0.0);
        sl_lo = vec3<f32>(0.0);
        sl_work = 0.0;
        sl_sq = vec3<f32>(0.0);
        sl_sq_lo = vec3<f32>(0.0);
    }
    if kind != 0u {
        // The whole chunks so far, kept apart while this one adds to ACC: a render stopped
        // mid-chunk returns them (as the CPU drops an unfinished pass), rounded once.
        accum[sl_base + COMMITTED] = vec4<f32>(sl_acc.xyz + sl_lo, sl_acc.w);
        if VARIANCE {
            accum[sl_base + SQ_COMMITTED] = vec4<f32>(sl_sq + sl_sq_lo, 0.0);
        }
    }
    sl_j = 0u;
    sl_done = sl_count == 0u;
    if kind != 0u {
        // First dispatch of a chunk of samples: start this invocation's first path.
        if !sl_done {
            start_sample();
        }
    } else {
        let base = sl_base;
        let st = bitcast<vec4<u32>>(accum[base + 3u]);
        let flags = (st.x >> 8u) & 0xffu;
        sl_done = (flags & F_DONE) != 0u;
        if !sl_done {
            let a = accum[base];
            let b = accum[base + 1u];
            ps = PathState(a.xyz, b.xyz, a.w, b.w, (flags & F_SCATTERED) != 0u, (flags & F_ALIVE) != 0u, bitcast<f32>(st.w));
            rng_s = bitcast<vec4<u32>>(accum[base + 2u]);
            p_channel = st.x & 0xffu;
            p_inside = (flags & F_INSIDE) != 0u;
            p_from_step = (flags & F_FROM_STEP) != 0u;
            p_left_through = NO_TRI;
            p_iterations = st.y;
            p_nee_left = st.x >> 16u;
            p_nee_sum = a.x;
            p_nee_light = a.y;
            sl_j = st.z;
            load_path_nee(base);
        }
    }
    return true;
}

/// Starts the slot's current sample (sl_j of this chunk): its seed, camera ray and channel.
fn start_sample() {
    let s = sl_first + params.image.z * sl_j;
    rng_seed(params.sampling.z, params.sampling.w, sl_pixel_id, s);
    let dir = camera_dir(f32(sl_px) + rand(), f32(sl_py) + rand());
    start_path(params.cam_origin.xyz + dir * params.consts3.w, dir, (s % 3u + sl_offset) % 3u);
}

/// After a bounce (`casting`: it cast one of an ended path's NEE rays): a bounce that
/// leaves the path ended was its last, and its path-level NEE rays follow, one per bounce;
/// after the last of them the sample is added and the next one started.
fn bounce_done(casting: bool) {
    if !ps.alive && !casting {
        p_nee_left = path_nee_rays();
        p_nee_sum = 0.0;
        p_nee_light = 0.0;
    }
    if !ps.alive && p_nee_left == 0u {
        if PATH_NEE_M > 0u && pn_total > 0.0 {
            ps.radiance += p_nee_sum * pn_total / f32(PATH_NEE_M);
        }
        add_sample(p_channel, path_result());
        sl_j += 1u;
        if sl_j >= sl_count {
            sl_done = true;
        } else {
            start_sample();
        }
    }
}

/// Adds a finished sample's estimate `l` to channel `c` of the slot's sum, times 3 (the
/// hero channel's weight, integrator/mod.rs), and counts it; with VARIANCE also the square
/// of that same f32 value 3·l to the squared sums (the host divides them by 9 for
/// render.rs's pixel_variance, which reads Σl²). Squaring the value the RGB sum adds, and
/// exactly (`exact_square`), keeps a constant pixel's variance at 0 to rounding: squares
/// rounded to f32 left one 1.1–1.4·10⁻⁹ (tests/gpu/agreement.rs, the furnace at 0.9).
/// Each sum keeps what the f32 addition rounded off (Neumaier's compensated sum,
/// `compensated_add`): a plain f32 sum of many equal samples rounds the same way at every
/// addition and drifted 1.2·10⁻⁴ of the mean (8.3·10⁻⁵ of 0.7) at 65,536 samples a slot
/// (`long_slot_sums_do_not_drift`). The host adds each sum and its rounding in f64. The
/// count is exact up to 2^24 (MAX_SLOT_SAMPLES).
fn add_sample(c: u32, l: f32) {
    let x = 3.0 * l;
    let a = compensated_add(sl_acc[c], x);
    sl_acc[c] = a.x;
    sl_lo[c] += a.y;
    sl_acc.w += 1.0;
    if VARIANCE {
        let sq = exact_square(x);
        let q = compensated_add(sl_sq[c], sq.x);
        sl_sq[c] = q.x;
        sl_sq_lo[c] += q.y + sq.y;
    }
}

/// x² as the unevaluated sum p + e, exactly (Dekker's product over Veltkamp's split of x
/// into halves of 12 significant bits, whose products f32 holds exactly): WGSL's fma may
/// be computed unfused, so it cannot give e. A compiler that simplified t − (t − x) to x
/// would give e = 0 (or an fma's exact e): the rounded square, no worse.
fn exact_square(x: f32) -> vec2<f32> {
    let p = x * x;
    let t = 4097.0 * x;
    let hi = t - (t - x);
    let lo = x - hi;
    return vec2<f32>(p, ((hi * hi - p) + 2.0 * hi * lo) + lo * lo);
}

/// s + x in f32 and what that addition rounded off (Neumaier). A compiler that
/// reassociated (s − t) + x to x − x would give 0 for the rounding: the plain sum, no
/// worse.
fn compensated_add(s: f32, x: f32) -> vec2<f32> {
    let t = s + x;
    if abs(s) >= abs(x) {
        return vec2<f32>(t, (s - t) + x);
    }
    return vec2<f32>(t, (x - t) + s);
}

/// The slot's state saved (`was_done`: it was done when the dispatch began; then only a
/// chunk's first dispatch marks it so), its accumulator written and the counters added,
/// with the slot counted as pending if it is and `count_pending` (the staged render counts
/// its running queue instead).
fn slot_end(was_done: bool, count_pending: bool) {
    if !was_done || params.misc.w != 0u {
        save_path(sl_base, sl_j, sl_done);
    }
    if !sl_done && count_pending {
        stats[C_PENDING] = 1u;
    }
    accum[sl_base + ACC] = sl_acc;
    // This visit's events and steps (its counters began at 0 in slot_begin), as the CPU
    // renderer's work map counts them (render.rs: events + steps a path).
    sl_work += f32(stats[C_EVENTS] + stats[C_STEPS]);
    accum[sl_base + ACC_LO] = vec4<f32>(sl_lo, sl_work);
    if VARIANCE {
        accum[sl_base + ACC_SQ] = vec4<f32>(sl_sq, 0.0);
        accum[sl_base + ACC_SQ_LO] = vec4<f32>(sl_sq_lo, 0.0);
    }
    add_stats();
    prof_end();
}

/// The invocation's counts added to the counters: once per subgroup, by its first active
/// lane, where the kernel aggregates (gpu/kernels.rs, aggregate_wgsl). The staged render
/// adds them at every turn, and every invocation adding to the same ten words would
/// queue up on them. A sum is taken in 16-bit halves, which no subgroup of up to 2^16
/// lanes can overflow.
fn add_stats() {
    let leader = sg_rank() == 0u;
    for (var i = 0u; i < PATH_COUNTERS; i++) {
        let lo = sg_sum(stats[i] & 0xffffu);
        let hi = sg_sum(stats[i] >> 16u);
        if leader {
            add_counter_wide(i, lo, hi);
        }
    }
}

/// Adds lo + hi·2^16 to counter pair `slot`: its low 32 bits through add_counter, the
/// rest straight to the high word.
fn add_counter_wide(slot: u32, lo: u32, hi: u32) {
    let shifted = hi << 16u;
    let v = lo + shifted;
    add_counter(slot, v);
    let carry = (hi >> 16u) + select(0u, 1u, v < shifted);
    if carry != 0u {
        atomicAdd(&counters[2u * slot + 1u], carry);
    }
}

/// Renders samples first + lane + lanes·j (j < count) of a pixel, at most
/// `params.consts2.z` bounces per dispatch (a path-level NEE ray after a path's end counts
/// as one), resuming where the
/// previous dispatch stopped. llvmpipe (lavapipe) stops every loop of an invocation once
/// 65,535 loop iterations have run in total (one shared counter, BVH traversal and
/// decoder loops included), so the work of one dispatch must stay bounded; a dispatch in
/// which the limit ran out is counted (C_TRUNCATED), and the host redoes it with fewer
/// bounces (gpu/switches.rs, bounce_budget) or reports it.
@compute @workgroup_size(WORKGROUP)
fn render_main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    prof_begin(li);
    stack_base = li * STACK_STRIDE;
    let idx = slot_of(gid);
    if idx == NO_SLOT || !slot_begin(idx, params.misc.w) {
        return;
    }
    let was_done = sl_done;
    if !sl_done {
        let budget = u32(params.consts2.z);
        var b = 0u;
        for (; b < budget && !sl_done; b++) {
            let casting = p_nee_left > 0u;
            bounce();
            bounce_done(casting);
        }
        // A limit that runs out inside the last bounce ends that bounce's inner loops (BVH
        // traversal, an exact walk) early without shortening the bounce loop: the probe
        // sees that case too.
        if (b < budget && !sl_done) || loop_limit_ran_out(u32(params.consts3.z)) {
            stats[C_TRUNCATED] = 1u;
        }
    }
    slot_end(was_done, true);
}
