// Shared include: the path loop of both integrators (crates/render-gpu/src/integrator/
// mod.rs) and the render entry point. The kernel file included before this one defines
// `scatter_at(channel)`, what happens at a real collision: a PT event (pt.wgsl) or a
// sphere step (stcvae.wgsl); it returns true after a sphere step.

const RR_THRESHOLD: f32 = 0.25;
const MAX_ITERATIONS: u32 = 50000000u;

// Counter slots (pairs lo/hi): paths, events, steps, leaks, capped, non-finite.
const C_PATHS: u32 = 0u;
const C_EVENTS: u32 = 1u;
const C_STEPS: u32 = 2u;
const C_LEAKS: u32 = 3u;
const C_CAPPED: u32 = 4u;
const C_NON_FINITE: u32 = 5u;

var<private> stats: array<u32, 6>;

struct PathState {
    pos: vec3<f32>,
    dir: vec3<f32>,
    beta: f32,
    radiance: f32,
    scattered: bool,
    alive: bool,
}

var<private> ps: PathState;

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
    if params.flags.y != 0u {
        ps.radiance += ps.beta * albedo * nee_direct(ps.pos, ps.dir, channel);
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
        for (var i = 0u; i < params.flags.x; i++) {
            l += light_radiance_toward(i, dir, channel);
        }
    }
    return l;
}

fn trace(origin: vec3<f32>, dir: vec3<f32>, channel: u32) -> f32 {
    stats[C_PATHS] += 1u;
    let sigma = params.sigma_t[channel];
    let dielectric = params.flags.z != 0u;
    let ior = params.consts.y;
    let nee = params.flags.y != 0u;
    ps = PathState(origin, dir, 1.0, 0.0, false, true);
    var inside = false;
    var from_step = false;
    var iterations = 0u;
    while ps.alive {
        iterations += 1u;
        if iterations > MAX_ITERATIONS {
            stats[C_CAPPED] += 1u;
            break;
        }
        if !inside {
            let h = intersect(ps.pos, ps.dir, 1e30);
            if !h.found {
                ps.radiance += ps.beta * escape_radiance(ps.dir, channel, !(nee && ps.scattered));
                break;
            }
            let p = ps.pos + ps.dir * h.t;
            let n = tri_normal(h.prim);
            if dielectric {
                let f = fresnel(abs(dot(ps.dir, n)), 1.0, ior);
                if rand() < f {
                    ps.dir = reflect_dir(ps.dir, n);
                } else {
                    ps.dir = refract_dir(ps.dir, n, 1.0, ior);
                    inside = true;
                }
            } else {
                inside = true;
            }
            ps.pos = spawn(p, n, ps.dir);
            continue;
        }
        let t = -log(1.0 - rand()) / sigma;
        let h = intersect(ps.pos, ps.dir, t);
        if h.found {
            let p = ps.pos + ps.dir * h.t;
            let n = tri_normal(h.prim);
            if dot(ps.dir, n) < 0.0 {
                // Met the surface from outside while believed inside: after a sphere step
                // the exit was not inside after all. Count it and leave, never enter.
                if from_step {
                    stats[C_LEAKS] += 1u;
                }
                inside = false;
                ps.pos = spawn(p, n, ps.dir);
                from_step = false;
                continue;
            }
            if dielectric {
                let f = fresnel(abs(dot(ps.dir, n)), ior, 1.0);
                if rand() < f {
                    ps.dir = reflect_dir(ps.dir, n);
                } else {
                    ps.dir = refract_dir(ps.dir, n, ior, 1.0);
                    inside = false;
                }
            } else {
                inside = false;
            }
            ps.pos = spawn(p, n, ps.dir);
            from_step = false;
            continue;
        }
        ps.pos += ps.dir * t;
        from_step = scatter_at(channel);
    }
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

/// One invocation per (pixel, lane): lane l renders samples first + l + lanes·j of its
/// pixel and writes (or adds) their sum to accum[pixel · lanes + l].
@compute @workgroup_size(64)
fn render_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.image.x;
    let lanes = params.image.z;
    let idx = gid.x + gid.y * 65535u * 64u;
    let pixel = idx / lanes;
    let lane = idx % lanes;
    if pixel >= width * params.image.y {
        return;
    }
    for (var i = 0u; i < 6u; i++) {
        stats[i] = 0u;
    }
    let px = pixel % width;
    let py = pixel / width;
    let offset = mix32(pixel * 0x9e3779b9u) % 3u;
    var acc = vec3<f32>(0.0);
    for (var j = 0u; j < params.image.w; j++) {
        let s = params.sampling.x + lane + lanes * j;
        if s >= params.sampling.y {
            break;
        }
        rng_seed(params.sampling.z, params.sampling.w, pixel, s);
        let channel = (s + offset) % 3u;
        let jx = rand();
        let jy = rand();
        let dir = camera_dir(f32(px) + jx, f32(py) + jy);
        let l = 3.0 * trace(params.cam_origin.xyz, dir, channel);
        acc[channel] += l;
    }
    if params.misc.w != 0u {
        accum[idx] = vec4<f32>(acc, 0.0);
    } else {
        accum[idx] += vec4<f32>(acc, 0.0);
    }
    for (var i = 0u; i < 6u; i++) {
        add_counter(i, stats[i]);
    }
}
