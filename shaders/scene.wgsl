// Shared include: the bindings every kernel sees and the scene queries (camera, BVH
// closest hit and nearest-triangle distance, distance grid, dielectric optics, lights,
// environment). Host mirror: crates/render-gpu/src/gpu/scene_buffers.rs.

struct Light {
    // xyz: unit vector toward the light; w: 1 − cos of the disk's angular radius, computed
    // accurately on the host (0: delta; light.rs, DirectionalLight::one_minus_cos).
    to_light: vec4<f32>,
    // Irradiance per channel (rgb).
    irradiance: vec4<f32>,
    // Radiance of the disk per channel (rgb); 0 for a delta light. w: sin² of the disk's
    // angular radius, its edge for light_radiance_toward.
    radiance: vec4<f32>,
}

struct Params {
    cam_origin: vec4<f32>,      // w: tan(fov/2)
    cam_forward: vec4<f32>,     // w: the image's height in pixels
    cam_right: vec4<f32>,       // w: the first row of the band being rendered
    cam_up: vec4<f32>,
    sigma_t: vec4<f32>,
    albedo: vec4<f32>,
    ln_albedo: vec4<f32>,       // ln φ, computed in f64 on the host
    one_minus_albedo: vec4<f32>,// 1 − φ, computed in f64 on the host
    albedo_feature: vec4<f32>,  // (1 − φ)^(1/6), EventGen's input
    env_radiance: vec4<f32>,
    grid_lo: vec4<f32>,         // w: cell size
    grid_dims: vec4<u32>,       // w: 1 if a grid is bound
    lights: array<Light, MAX_LIGHTS>,
    image: vec4<u32>,           // width, height, lanes, samples per lane
    sampling: vec4<u32>,        // first sample, end sample, seed lo, seed hi
    flags: vec4<u32>,           // light count, nee, dielectric, stcvae (the kernels read the
                                // constants LIGHTS, NEE and DIELECTRIC instead: kernels.rs)
    misc: vec4<u32>,            // env map width, height, nee samples (model steps), dispatch kind
                                // (2: first of the render, 1: first of a chunk, 0: resume)
    consts: vec4<f32>,          // g, ior, eps, min_tau
    consts2: vec4<f32>,         // max_tau, near_surface, bounces per dispatch, tile stride
    consts3: vec4<f32>,         // exact_tau, exact_nee_samples (integral), loop-probe passes,
                                // camera rays' start (Camera::start)
    consts4: vec4<f32>,         // NEE's radiance factor (Boundary::nee_scale: 1/ior² or 1), 0, 0, 0
    // Where the mesh's pieces overlap, per nesting depth d (entry d / 4, component d % 4)
    // the bits of the pieces at it (geometry/mod.rs, Pieces); all 0 without overlaps.
    pieces: array<vec4<u32>, 4>,
}

// A BVH node as the traversals use it. `nodes` holds it packed in 16 bytes
// (scene_buffers::GpuNode: the box as six f16 rounded outward, then first <<
// NODE_COUNT_BITS | count), half the 32 of f32 boxes: lavapipe loads every word lane by
// lane, and PT ran 18 % faster on Mesa 22 for it (docs/BENCHMARKS.md); `node_at` unpacks
// it.
struct Node {
    lo: vec3<f32>,
    first: u32,
    hi: vec3<f32>,
    count: u32,
}

// The mesh's exact bounds, stored after the nodes as f32 bits: the inside-the-bounds check
// uses them as the CPU does (Geometry::within_bounds), not the f16 root box.
fn mesh_bounds(hi: bool) -> vec3<f32> {
    return bitcast<vec3<f32>>(nodes[arrayLength(&nodes) - select(2u, 1u, hi)].xyz);
}

fn node_at(i: u32) -> Node {
    let q = nodes[i];
    let a = unpack2x16float(q.x);
    let b = unpack2x16float(q.y);
    let c = unpack2x16float(q.z);
    let count = q.w & ((1u << NODE_COUNT_BITS) - 1u);
    return Node(vec3<f32>(a, b.x), q.w >> NODE_COUNT_BITS, vec3<f32>(b.y, c), count);
}

struct Tri {
    v0: vec4<f32>, // w: 1 + its piece's number where pieces overlap, else 0 (piece_bit)
    v1: vec4<f32>,
    v2: vec4<f32>,
    n: vec4<f32>,  // outward unit normal; w: cos θ of its escape cone (escape_cone.rs)
}

struct ModelParams {
    flags: vec4<u32>,  // single scattering exact, n_min, EventGen radial map (1: version 3), 0
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read_write> accum: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> counters: array<atomic<u32>, COUNTER_WORDS>;
@group(0) @binding(3) var<storage, read> tris: array<Tri>;
@group(0) @binding(4) var<storage, read> nodes: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read> env_map: array<vec4<f32>>;
// The distance grid (scene_buffers::grid_buffer): per cell [d(c) bits, start of its
// candidate list] for the n cells plus a closing entry, then the candidate lists.
@group(0) @binding(6) var<storage, read> grid: array<u32>;
@group(0) @binding(7) var<uniform> model: ModelParams;

// ---- camera (Mitsuba's orientation; row 0 at the top) ----

fn camera_dir(x: f32, y: f32) -> vec3<f32> {
    let w = f32(params.image.x);
    let h = params.cam_forward.w;
    let th = params.cam_origin.w;
    let u = (2.0 * x / w - 1.0) * th;
    let v = (1.0 - 2.0 * y / h) * th * h / w;
    return normalize(params.cam_forward.xyz + params.cam_right.xyz * u + params.cam_up.xyz * v);
}

// ---- BVH2 traversal ----

struct Hit {
    t: f32,
    prim: u32,
    found: bool,
}

// Watertight ray–triangle intersection (Woop, Benthin and Wald 2013; mirrors
// crates/render-gpu/src/watertight.rs): one shear per ray, and edge functions computed
// from the shared vertices, so a ray through an edge shared by two triangles hits one of
// them instead of slipping through (Möller–Trumbore leaves such cracks, and a path that
// leaves the medium unnoticed sphere-steps in the air and sees the light unoccluded).
// The shear as three rows (watertight.rs: RayShear): sheared(v) = rows · (v − o).
struct Shear {
    o: vec3<f32>,
    mx: vec3<f32>,
    my: vec3<f32>,
    mz: vec3<f32>,
    d: vec3<f32>,
}

fn axis(k: u32) -> vec3<f32> {
    return vec3<f32>(f32(k == 0u), f32(k == 1u), f32(k == 2u));
}

fn ray_shear(o: vec3<f32>, d: vec3<f32>) -> Shear {
    let a = abs(d);
    var kz = 2u;
    if a.x >= a.y && a.x >= a.z {
        kz = 0u;
    } else if a.y >= a.z {
        kz = 1u;
    }
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let t = kx;
        kx = ky;
        ky = t;
    }
    let ez = axis(kz);
    return Shear(o, axis(kx) - ez * (d[kx] / d[kz]), axis(ky) - ez * (d[ky] / d[kz]), ez * (1.0 / d[kz]), d);
}

fn sheared(sh: Shear, v: vec3<f32>) -> vec3<f32> {
    let p = v - sh.o;
    return vec3<f32>(dot(sh.mx, p), dot(sh.my, p), dot(sh.mz, p));
}

// The edge function p.x·q.y − p.y·q.x of two sheared vertices. Watertightness needs
// edge(q, p) = −edge(p, q) exactly, so that two triangles sharing an edge see one value
// with opposite signs. Evaluated as written that holds only without fused multiply-adds:
// a driver that fuses one product rounds the other (NVIDIA's does: 81 of 20,000 rays aimed
// at the bunny's vertices and edges slipped through on an H200). So the pair is put in one
// canonical order first, and both triangles evaluate the very same expression. (This
// assumes the compiler treats the expression, and `sheared` before it, alike at all three
// call sites; it did on NVIDIA's driver and lavapipe.) Two vertices that coincide in
// projection (an edge along the ray) give 0 exactly: p.x·p.y − p.y·p.x with one product
// fused is the other's rounding error, of one sign for both triangles.
fn edge(p: vec3<f32>, q: vec3<f32>) -> f32 {
    if p.x == q.x && p.y == q.y {
        return 0.0;
    }
    let swap = p.x > q.x || (p.x == q.x && p.y > q.y);
    let lo = select(p, q, swap);
    let hi = select(q, p, swap);
    let e = lo.x * hi.y - lo.y * hi.x;
    return select(e, -e, swap);
}

fn tri_intersect(sh: Shear, tri: Tri, tmax: f32) -> f32 {
    let a = sheared(sh, tri.v0.xyz);
    let b = sheared(sh, tri.v1.xyz);
    let c = sheared(sh, tri.v2.xyz);
    let u = edge(c, b);
    let v = edge(a, c);
    let w = edge(b, a);
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return 1e30;
    }
    let det = u + v + w;
    if det == 0.0 {
        return 1e30;
    }
    // The distance from the triangle's plane, as watertight.rs (RayShear::hit) explains:
    // Woop's interpolated depth is off the plane by up to 10x the flight margin on long
    // thin triangles. Through the vertex of largest weight, bounded by the vertices'
    // sheared depths (grazing rays); a non-finite one (n.d = 0) keeps Woop's t.
    let au = abs(u);
    let av = abs(v);
    let aw = abs(w);
    var nearest = tri.v2.xyz;
    if au >= av && au >= aw {
        nearest = tri.v0.xyz;
    } else if av >= aw {
        nearest = tri.v1.xyz;
    }
    let nd = dot(tri.n.xyz, sh.d);
    var t = (u * a.z + v * b.z + w * c.z) / det;
    if nd != 0.0 {
        // Finite only (WGSL may not keep NaN or ∞ apart), as the CPU's is_finite.
        let planar = dot(tri.n.xyz, nearest - sh.o) / nd;
        if abs(planar) <= 3.4e38 {
            t = min(max(planar, min(min(a.z, b.z), c.z)), max(max(a.z, b.z), c.z));
        }
    }
    if t >= 0.0 && t <= tmax {
        return t;
    }
    return 1e30;
}

fn box_entry(lo: vec3<f32>, hi: vec3<f32>, o: vec3<f32>, inv_d: vec3<f32>, tmax: f32) -> f32 {
    let t0 = (lo - o) * inv_d;
    let t1 = (hi - o) * inv_d;
    let tn = max(max(min(t0.x, t1.x), min(t0.y, t1.y)), max(min(t0.z, t1.z), 0.0));
    let tf = min(min(max(t0.x, t1.x), max(t0.y, t1.y)), min(max(t0.z, t1.z), tmax));
    return select(1e30, tn, tn <= tf);
}

// BVH traversal stacks (`trav_stack`, STACK_DEPTH entries per invocation from stack_base,
// which each entry point sets to its local invocation index × STACK_STRIDE; both defined
// by gpu/kernels.rs, KernelShape). By default they live in workgroup memory: a private
// array indexed at run time once cost llvmpipe ~25 % of PT's time (apparently per-access
// branch ladders: a 64-entry private stack was that much slower than a 16-entry one); on
// today's kernels the two are within lavapipe's noise. With STCVAE_GPU_STACK=private the
// array is private and the stride 0. The host refuses a BVH
// deeper than the stack. No traversal runs inside another, so all share it.
var<private> stack_base: u32;

/// Whether a triangle hit at t (≤ best.t, tri_intersect's bound) replaces `best`: the
/// nearer, and of two at the same distance (a ray through a shared edge) the lower index,
/// so the hit does not depend on the order the triangles are tested in (the BVH's or a
/// grid cell's list: `grid_local_hit`).
fn closer(t: f32, prim: u32, best: Hit) -> bool {
    return !best.found || t < best.t || prim < best.prim;
}

/// Fresnel transmittance of one crossing of a straight shadow ray (1 when index-matched),
/// `cos` being the ray's angle, the light's in air, at either crossing (nee.rs:
/// crossing_transmittance).
fn crossing_transmittance(cos: f32) -> f32 {
    if !DIELECTRIC {
        return 1.0;
    }
    return 1.0 - fresnel(cos, 1.0, params.consts.y);
}

/// Every surface crossing of a ray, unordered (Geometry::inside_length on the CPU): for a
/// closed mesh the length inside is Σ t(exits) − Σ t(entries); `balance` = exits −
/// entries is 1 for an origin inside.
struct Crossings {
    length: f32,
    fresnel_t: f32,
    balance: i32,
    // The pieces crossed an odd number of times (those around the origin) where pieces
    // overlap (union_medium); `crossings` only (trace's shadow rays have no use for it:
    // with overlaps NEE walks its crossings in order).
    pieces: u32,
    // The nearest crossing (the lower triangle on a tie, as Geometry::crossed), where a
    // dielectric's NEE refracts (nee.wgsl, shadow_of); first_t 1e30 if none. Kept only
    // with a dielectric boundary (DIELECTRIC is a constant).
    first_t: f32,
    first_prim: u32,
}

/// `c` with its nearest crossing updated by one at distance t of triangle k.
fn nearer_crossing(c: Crossings, t: f32, k: u32) -> Crossings {
    var n = c;
    if DIELECTRIC && (t < c.first_t || (t == c.first_t && k < c.first_prim)) {
        n.first_t = t;
        n.first_prim = k;
    }
    return n;
}

/// Whether the mesh's pieces overlap (geometry/mod.rs, Geometry::pieces): the object is
/// their union, and paths ask past each face whether they are in it (in_union).
fn overlapping() -> bool {
    // A constant (kernels.rs, SceneSwitches): kernels for other meshes carry none of
    // that code.
    return OVERLAPS;
}

/// Triangle k's piece as a bit (0 without overlaps).
fn piece_bit(k: u32) -> u32 {
    let w = u32(tris[k].v0.w);
    return select(0u, 1u << (w - 1u), w > 0u);
}

/// Whether a point inside exactly the pieces of `around` is in the medium: the most deeply
/// nested of them is a solid (even depth; geometry/mod.rs, Pieces::medium).
fn union_medium(around: u32) -> bool {
    for (var d = 15i; d >= 0; d--) {
        if (around & params.pieces[d / 4][d % 4]) != 0u {
            return (d & 1) == 0;
        }
    }
    return false;
}

/// Whether `p` is in the medium where pieces overlap, from the pieces crossed an odd
/// number of times along p + t·d (Geometry::in_union: robust to faces in shared planes).
fn in_union(p: vec3<f32>, d: vec3<f32>) -> bool {
    return union_medium(crossings(p, d).pieces);
}

/// The crossings of the last `trace` with `all` set.
var<private> tr_cross: Crossings;

/// Where pieces overlap, `crossings` also keeps up to UNION_CROSSINGS crossings sorted by t
/// (their triangles with them), for the shadow rays' walk (nee.wgsl, transmittance_union;
/// the CPU's Geometry::union_inside_length): u_count of them, or more than that (u_more).
/// 16 where the CPU sorts 64 (geometry/mod.rs, MAX_UNION_CROSSINGS), for private memory:
/// past 16 crossings the in-medium test takes the pieces' raw parity without dropping a
/// face met twice at one point, so a ray through a shared edge (a set of measure zero) can
/// count a piece twice there and not on the CPU. Shadow rays past 16 walk their crossings
/// in order.
const UNION_CROSSINGS: u32 = 16u;
var<private> u_t: array<f32, UNION_CROSSINGS>;
var<private> u_tri: array<u32, UNION_CROSSINGS>;
var<private> u_count: u32;
var<private> u_more: bool;

/// Drops each face met twice at one point from the sorted list and returns the pieces
/// crossed an odd number of times (geometry/rays.rs, union_crossings: a ray through the
/// edge two triangles of one face share hits both; twice = the same piece, the same side
/// and t within a hundredth of the spawn offset over |cos|).
fn union_dedupe(d: vec3<f32>) -> u32 {
    let tol = params.consts.z * CROSSING_TOL_OF_EPS;
    var kept = 0u;
    var around = 0u;
    for (var i = 0u; i < u_count; i++) {
        let t = u_t[i];
        let k = u_tri[i];
        let bit = piece_bit(k);
        let cosn = dot(d, tri_normal(k));
        let exiting = cosn > 0.0;
        let reach = tol / max(abs(cosn), GRAZING_COS_FLOOR);
        var twice = false;
        var j = kept;
        loop {
            if j == 0u || t - u_t[j - 1u] > reach {
                break;
            }
            j -= 1u;
            let o = u_tri[j];
            if piece_bit(o) == bit && (dot(d, tri_normal(o)) > 0.0) == exiting {
                twice = true;
                break;
            }
        }
        if !twice {
            u_t[kept] = t;
            u_tri[kept] = k;
            kept += 1u;
            around ^= bit;
        }
    }
    u_count = kept;
    return around;
}

/// Inserts a crossing into the sorted list (overlapping pieces only).
fn union_keep(t: f32, k: u32) {
    if u_count == UNION_CROSSINGS {
        u_more = true;
        return;
    }
    var i = u_count;
    loop {
        if i == 0u || u_t[i - 1u] <= t {
            break;
        }
        u_t[i] = u_t[i - 1u];
        u_tri[i] = u_tri[i - 1u];
        i -= 1u;
    }
    u_t[i] = t;
    u_tri[i] = k;
    u_count += 1u;
}

/// One BVH traversal for both kinds of query: the closest hit along o + t·d, t ∈ [0,
/// tmax0] (`intersect`), or with `all` every crossing for t ∈ [0, tmax0] (`crossings`
/// with tmax0 = 1e30, into tr_cross; the returned hit is then none). The path loop's one query site uses it
/// (path.wgsl, bounce) so that lanes of a subgroup needing either kind step through one
/// loop together instead of one loop after the other (ST-CVAE on an H100, 2026-11-27:
/// +10 % paths/s at k = 1). The other call sites keep their specialised loops: with all
/// traversals going through this one, PT lost 5 % on the H100. In `all` mode the
/// children are visited in `crossings`' order (b before a) whatever their distances, so
/// the sums come out the same bit for bit.
fn trace(o: vec3<f32>, d: vec3<f32>, tmax0: f32, all: bool) -> Hit {
    var best = Hit(tmax0, 0u, false);
    tr_cross = Crossings(0.0, 1.0, 0, 0u, 1e30, 0u);
    // Exact zeros would make 0·∞ = NaN in the slab test.
    let inv_d = 1.0 / (d + select(vec3<f32>(0.0), vec3<f32>(1e-30), d == vec3<f32>(0.0)));
    let sh = ray_shear(o, d);
    // A pass shared by both kinds counts under the kind of the subgroup's first active lane.
    let phase = select(1u, 2u, all);
    var top = 1u;
    trav_stack[stack_base] = 0u;
    loop {
        if top == 0u {
            break;
        }
        top -= 1u;
        prof(phase);
        let index = trav_stack[stack_base + top];
        let node = node_at(index);
        // A child's box was tested when it was pushed; the closest hit may have come
        // nearer since, while `all` has no bound that shrinks: only its root is left.
        if (!all || index == 0u) && box_entry(node.lo, node.hi, o, inv_d, best.t) >= 1e29 {
            continue;
        }
        if node.count > 0u {
            for (var k = node.first; k < node.first + node.count; k++) {
                let t = tri_intersect(sh, tris[k], best.t);
                if t < 1e29 {
                    if all {
                        let cosn = dot(d, tris[k].n.xyz);
                        let exiting = cosn > 0.0;
                        tr_cross.length += select(-t, t, exiting);
                        tr_cross.balance += select(-1, 1, exiting);
                        tr_cross.fresnel_t *= crossing_transmittance(abs(cosn));
                        tr_cross = nearer_crossing(tr_cross, t, k);
                    } else if closer(t, k, best) {
                        best = Hit(t, k, true);
                    }
                }
            }
        } else {
            let a = node.first;
            let b = node.first + 1u;
            let na = node_at(a);
            let nb = node_at(b);
            let ta = box_entry(na.lo, na.hi, o, inv_d, best.t);
            let tb = box_entry(nb.lo, nb.hi, o, inv_d, best.t);
            // Push the farther child first so the nearer one is visited next (closest hit
            // only: `all` has no distance to prune by).
            if ta < 1e29 && tb < 1e29 && top + 2u <= STACK_DEPTH {
                if ta < tb && !all {
                    trav_stack[stack_base + top] = b;
                    trav_stack[stack_base + top + 1u] = a;
                } else {
                    trav_stack[stack_base + top] = a;
                    trav_stack[stack_base + top + 1u] = b;
                }
                top += 2u;
            } else if ta < 1e29 && top < STACK_DEPTH {
                trav_stack[stack_base + top] = a;
                top += 1u;
            } else if tb < 1e29 && top < STACK_DEPTH {
                trav_stack[stack_base + top] = b;
                top += 1u;
            }
        }
    }
    if all {
        best.found = false;
    }
    return best;
}

/// Closest hit along o + t·d, t ∈ [0, tmax].
fn intersect(o: vec3<f32>, d: vec3<f32>, tmax0: f32) -> Hit {
    var best = Hit(tmax0, 0u, false);
    // Exact zeros would make 0·∞ = NaN in the slab test.
    let inv_d = 1.0 / (d + select(vec3<f32>(0.0), vec3<f32>(1e-30), d == vec3<f32>(0.0)));
    let sh = ray_shear(o, d);
    var top = 1u;
    trav_stack[stack_base] = 0u;
    loop {
        if top == 0u {
            break;
        }
        top -= 1u;
        prof(1u);
        let node = node_at(trav_stack[stack_base + top]);
        if box_entry(node.lo, node.hi, o, inv_d, best.t) >= 1e29 {
            continue;
        }
        if node.count > 0u {
            for (var k = node.first; k < node.first + node.count; k++) {
                let t = tri_intersect(sh, tris[k], best.t);
                if t < 1e29 && closer(t, k, best) {
                    best = Hit(t, k, true);
                }
            }
        } else {
            let a = node.first;
            let b = node.first + 1u;
            let na = node_at(a);
            let nb = node_at(b);
            let ta = box_entry(na.lo, na.hi, o, inv_d, best.t);
            let tb = box_entry(nb.lo, nb.hi, o, inv_d, best.t);
            // Push the farther child first so the nearer one is visited next.
            if ta < 1e29 && tb < 1e29 && top + 2u <= STACK_DEPTH {
                if ta < tb {
                    trav_stack[stack_base + top] = b;
                    trav_stack[stack_base + top + 1u] = a;
                } else {
                    trav_stack[stack_base + top] = a;
                    trav_stack[stack_base + top + 1u] = b;
                }
                top += 2u;
            } else if ta < 1e29 && top < STACK_DEPTH {
                trav_stack[stack_base + top] = a;
                top += 1u;
            } else if tb < 1e29 && top < STACK_DEPTH {
                trav_stack[stack_base + top] = b;
                top += 1u;
            }
        }
    }
    return best;
}

/// Every surface crossing of the line o + t·d, t ≥ 0, in one BVH traversal.
fn crossings(o: vec3<f32>, d: vec3<f32>) -> Crossings {
    var c = Crossings(0.0, 1.0, 0, 0u, 1e30, 0u);
    if overlapping() {
        u_count = 0u;
        u_more = false;
    }
    let inv_d = 1.0 / (d + select(vec3<f32>(0.0), vec3<f32>(1e-30), d == vec3<f32>(0.0)));
    let sh = ray_shear(o, d);
    let root = node_at(0u);
    if box_entry(root.lo, root.hi, o, inv_d, 1e30) >= 1e29 {
        return c;
    }
    var top = 1u;
    trav_stack[stack_base] = 0u;
    loop {
        if top == 0u {
            break;
        }
        top -= 1u;
        prof(2u);
        let node = node_at(trav_stack[stack_base + top]);
        if node.count > 0u {
            for (var k = node.first; k < node.first + node.count; k++) {
                let t = tri_intersect(sh, tris[k], 1e30);
                if t < 1e29 {
                    let cosn = dot(d, tris[k].n.xyz);
                    let exiting = cosn > 0.0;
                    c.length += select(-t, t, exiting);
                    c.balance += select(-1, 1, exiting);
                    c.fresnel_t *= crossing_transmittance(abs(cosn));
                    c = nearer_crossing(c, t, k);
                    if overlapping() {
                        c.pieces ^= piece_bit(k);
                        union_keep(t, k);
                    }
                }
            }
        } else {
            // No closest hit to prune by: every child the ray crosses is visited, in any
            // order.
            let a = node.first;
            let b = node.first + 1u;
            let na = node_at(a);
            if box_entry(na.lo, na.hi, o, inv_d, 1e30) < 1e29 && top < STACK_DEPTH {
                trav_stack[stack_base + top] = a;
                top += 1u;
            }
            let nb = node_at(b);
            if box_entry(nb.lo, nb.hi, o, inv_d, 1e30) < 1e29 && top < STACK_DEPTH {
                trav_stack[stack_base + top] = b;
                top += 1u;
            }
        }
    }
    if overlapping() && !u_more {
        c.pieces = union_dedupe(d);
    }
    return c;
}

fn tri_normal(prim: u32) -> vec3<f32> {
    return tris[prim].n.xyz;
}

/// The medium passed by a path spawned inside heading dir (Geometry::spawn_skip).
fn spawn_skip(n: vec3<f32>, dir: vec3<f32>) -> f32 {
    return params.consts.z / max(abs(dot(dir, n)), SKIP_MIN_COS);
}

/// A point just off the surface at p, on the side dir points to.
fn spawn(p: vec3<f32>, n: vec3<f32>, dir: vec3<f32>) -> vec3<f32> {
    let side = select(-1.0, 1.0, dot(dir, n) >= 0.0);
    return p + n * (side * params.consts.z);
}

/// Squared distance from p to triangle (a, b, c) with unit normal n: the plane's distance
/// over the face, the nearest edge's beside it, decided by edge functions that stay exact
/// on long thin triangles (geometry/distance.rs, point_triangle_d2).
fn point_triangle_d2(p: vec3<f32>, a: vec3<f32>, b: vec3<f32>, c: vec3<f32>, n: vec3<f32>) -> f32 {
    let ab = b - a;
    let bc = c - b;
    let ca = a - c;
    let ap = p - a;
    let bp = p - b;
    let cp = p - c;
    let sa = edge_side(ap, ab, n);
    let sb = edge_side(bp, bc, n);
    let sc = edge_side(cp, ca, n);
    if sa.x && sb.x && sc.x {
        let h = dot(n, ap);
        return h * h;
    }
    // Beside the face: the nearest point is on an edge whose line the point is beyond or
    // within the tolerance of.
    var best = 3.4e38;
    if sa.y { best = edge_d2(ap, ab); }
    if sb.y { best = min(best, edge_d2(bp, bc)); }
    if sc.y { best = min(best, edge_d2(cp, ca)); }
    return best;
}

/// For a point vp from an edge's start: whether it lies on the face's side of edge e
/// (within EDGE_TOLERANCE, erring towards the face), and whether beyond its line or
/// within the tolerance of it (geometry/distance.rs, point_triangle_d2).
fn edge_side(vp: vec3<f32>, e: vec3<f32>, n: vec3<f32>) -> vec2<bool> {
    let s = dot(n, cross(e, vp));
    let near = s * s <= EDGE_TOLERANCE * EDGE_TOLERANCE * dot(e, e) * dot(vp, vp);
    return vec2<bool>(s >= 0.0 || near, s < 0.0 || near);
}

/// Squared distance from a point vp from segment e's start to the segment.
fn edge_d2(vp: vec3<f32>, e: vec3<f32>) -> f32 {
    let t = clamp(dot(vp, e) / max(dot(e, e), 1.17549435e-38), 0.0, 1.0);
    let q = vp - e * t;
    return dot(q, q);
}

fn box_d2(p: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let q = clamp(p, lo, hi) - p;
    return dot(q, q);
}

/// min(exact unsigned distance from p to the surface, limit): a nearest-triangle BVH
/// search that skips every node beyond `limit` (Geometry::distance_within on the CPU).
fn surface_distance(p: vec3<f32>, limit: f32) -> f32 {
    var best = limit * limit;
    var top = 1u;
    trav_stack[stack_base] = 0u;
    loop {
        if top == 0u {
            break;
        }
        top -= 1u;
        prof(3u);
        let node = node_at(trav_stack[stack_base + top]);
        if box_d2(p, node.lo, node.hi) >= best {
            continue;
        }
        if node.count > 0u {
            for (var k = node.first; k < node.first + node.count; k++) {
                let t = tris[k];
                best = min(best, point_triangle_d2(p, t.v0.xyz, t.v1.xyz, t.v2.xyz, t.n.xyz));
            }
        } else {
            let a = node.first;
            let b = node.first + 1u;
            let na = node_at(a);
            let da = box_d2(p, na.lo, na.hi);
            let nb = node_at(b);
            let db = box_d2(p, nb.lo, nb.hi);
            if top + 2u > STACK_DEPTH {
                // A bound below the distance from both children's boxes and every pending
                // node's (Geometry::distance_within). Unreached: the renderer refuses BVHs
                // deeper than the stack.
                var floor = min(da, db);
                for (var j = 0u; j < top; j++) {
                    let nj = node_at(trav_stack[stack_base + j]);
                    floor = min(floor, box_d2(p, nj.lo, nj.hi));
                }
                return sqrt(min(best, floor));
            }
            if da < db {
                trav_stack[stack_base + top] = b;
                trav_stack[stack_base + top + 1u] = a;
            } else {
                trav_stack[stack_base + top] = a;
                trav_stack[stack_base + top + 1u] = b;
            }
            top += 2u;
        }
    }
    return sqrt(best);
}

// ---- the conservative distance grid (crates/render-gpu/src/distance_grid.rs) ----

/// p in units of grid cells from the grid's corner (a multiplication by 1/cell, as
/// DistanceGrid::cell_of does: a point that rounding puts into the neighbouring cell
/// still gets a valid bound from that cell).
fn grid_q(p: vec3<f32>) -> vec3<f32> {
    return (p - params.grid_lo.xyz) * (1.0 / params.grid_lo.w);
}

/// The index of the grid cell at q (grid_q), or -1 outside the grid (or without one).
fn grid_cell_at(q: vec3<f32>) -> i32 {
    if params.grid_dims.w == 0u {
        return -1;
    }
    if !(q.x >= 0.0 && q.y >= 0.0 && q.z >= 0.0) {
        return -1;
    }
    let c = vec3<u32>(q);
    let dims = params.grid_dims.xyz;
    if c.x >= dims.x || c.y >= dims.y || c.z >= dims.z {
        return -1;
    }
    return i32(c.x + dims.x * (c.y + dims.y * c.z));
}

/// The centre of the cell at q (grid_q).
fn grid_cell_centre(q: vec3<f32>) -> vec3<f32> {
    return params.grid_lo.xyz + (vec3<f32>(vec3<u32>(q)) + 0.5) * params.grid_lo.w;
}

/// Cell i's candidate list as a range [x, y) of the lists' entries (empty: no list).
fn grid_list(i: i32) -> vec2<u32> {
    return vec2<u32>(grid[2u * u32(i) + 1u], grid[2u * u32(i) + 3u]);
}

/// Entry k of the candidate lists: a triangle's index (in BVH leaf order), after the n
/// cells' pairs and the closing one.
fn grid_candidate(k: u32) -> u32 {
    let dims = params.grid_dims.xyz;
    return grid[2u * (dims.x * dims.y * dims.z + 1u) + k];
}

fn grid_radius(p: vec3<f32>) -> f32 {
    let q = grid_q(p);
    let i = grid_cell_at(q);
    if i < 0 {
        return 0.0;
    }
    return max(bitcast<f32>(grid[2u * u32(i)]) - length(p - grid_cell_centre(q)), 0.0);
}

/// The exact distance from p to the surface from its cell's candidate triangles
/// (DistanceGrid::exact_distance), or -1 where the cell has none.
fn grid_exact_distance(p: vec3<f32>) -> f32 {
    let i = grid_cell_at(grid_q(p));
    if i < 0 {
        return -1.0;
    }
    let list = grid_list(i);
    if list.y <= list.x {
        return -1.0;
    }
    var best = 3.4e38;
    for (var k = list.x; k < list.y; k++) {
        let t = tris[grid_candidate(k)];
        best = min(best, point_triangle_d2(p, t.v0.xyz, t.v1.xyz, t.v2.xyz, t.n.xyz));
    }
    return sqrt(best);
}

/// The closest hit along o + t·d, t ∈ [0, tmax], from the candidate list of o's grid cell
/// instead of a BVH traversal (DistanceGrid::local_hit, which says why it is the same
/// hit), written to *hit; false where the list cannot be trusted to hold every triangle
/// the segment can meet (no grid, no list, a segment reaching beyond it), and the caller
/// traverses the BVH. Flights near the surface are short, and a dozen triangle tests
/// after a plane cull cost far less than a traversal from the root, whose lanes also
/// diverge more.
fn grid_local_hit(o: vec3<f32>, d: vec3<f32>, tmax: f32, hit: ptr<function, Hit>) -> bool {
    let q = grid_q(o);
    let i = grid_cell_at(q);
    if i < 0 {
        return false;
    }
    let list = grid_list(i);
    if list.y <= list.x {
        return false;
    }
    // The coverage in f32, shrunk by far more than its rounding (consts2.y: near_surface).
    let reach = (bitcast<f32>(grid[2u * u32(i)]) + params.consts2.y * 0.5) * LOCAL_REACH_SHRINK;
    if length(o - grid_cell_centre(q)) + tmax > reach {
        return false;
    }
    let sh = ray_shear(o, d);
    // A segment with both ends beyond this distance on one side of a triangle's plane
    // cannot meet it (Geometry::closest_of's cull; consts.z: eps).
    let slack = params.consts.z * PLANE_SLACK_OF_EPS;
    var best = Hit(tmax, 0u, false);
    for (var k = list.x; k < list.y; k++) {
        prof(7u);
        let prim = grid_candidate(k);
        let tri = tris[prim];
        let s0 = dot(tri.n.xyz, o) - dot(tri.n.xyz, tri.v0.xyz);
        let s1 = s0 + best.t * dot(tri.n.xyz, d);
        if (s0 > slack && s1 > slack) || (s0 < -slack && s1 < -slack) {
            continue;
        }
        let t = tri_intersect(sh, tri, best.t);
        if t < 1e29 && closer(t, prim, best) {
            best = Hit(t, prim, true);
        }
    }
    *hit = best;
    return true;
}

/// An upper bound on the true distance at a point of grid radius r: r + √3·cell plus
/// slack (DistanceGrid::distance_upper_bound; consts2.y holds near_surface = 2√3·cell).
fn grid_distance_upper_bound(r: f32) -> f32 {
    return r + 0.5 * params.consts2.y * UPPER_BOUND_SLACK;
}

// ---- dielectric boundary ----

fn fresnel(cos_i0: f32, n_i: f32, n_t: f32) -> f32 {
    let cos_i = clamp(cos_i0, 0.0, 1.0);
    let eta = n_i / n_t;
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = sqrt(1.0 - sin2_t);
    let rs = (n_i * cos_i - n_t * cos_t) / (n_i * cos_i + n_t * cos_t);
    let rp = (n_t * cos_i - n_i * cos_t) / (n_t * cos_i + n_i * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

fn reflect_dir(d: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return d - n * (2.0 * dot(d, n));
}

/// Refraction from n_i into n_t; returns d unchanged under total internal reflection
/// (the caller has already chosen refraction with probability 1 − F, and F = 1 there).
fn refract_dir(d: vec3<f32>, n0: vec3<f32>, n_i: f32, n_t: f32) -> vec3<f32> {
    let n = select(n0, -n0, dot(d, n0) > 0.0);
    let cos_i = -dot(d, n);
    let eta = n_i / n_t;
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return d;
    }
    let cos_t = sqrt(1.0 - sin2_t);
    return normalize(d * eta + n * (eta * cos_i - cos_t));
}

// ---- lights and environment (crates/render-gpu/src/light.rs) ----

struct LightSample {
    dir: vec3<f32>,
    factor: f32,
}

/// A direction toward light i for NEE and its factor: E, or L·Ω of a disk, times NEE's
/// radiance factor (params.consts4.x; nee.rs, light_sample).
fn light_sample(i: u32, u1: f32, u2: f32, channel: u32) -> LightSample {
    let l = params.lights[i];
    let one_minus_cos = l.to_light.w;
    let scale = params.consts4.x;
    if one_minus_cos <= 0.0 {
        return LightSample(l.to_light.xyz, l.irradiance[channel] * scale);
    }
    // As light.rs: 1 − cos θ uniform, sin θ = √(v(2 − v)) without 1 − cos² cancelling.
    let v = u1 * one_minus_cos;
    let c = 1.0 - v;
    let s = sqrt(max(v * (2.0 - v), 0.0));
    let phi = TWO_PI * u2;
    let n = l.to_light.xyz;
    let dir = normalize(basis_t(n) * (s * cos(phi)) + basis_b(n) * (s * sin(phi)) + n * c);
    let solid_angle = TWO_PI * one_minus_cos;
    return LightSample(dir, l.radiance[channel] * solid_angle * scale);
}

/// light.rs, DirectionalLight::phase_share: the share of NEE's directions drawn from the
/// phase function where its lobe is narrower than the disk (0 for a delta light).
fn light_phase_share(i: u32, g: f32) -> f32 {
    let one_minus_g = 1.0 - abs(g);
    let lobe = PI * one_minus_g * one_minus_g;
    return select(0.0, PHASE_SHARE, TWO_PI * params.lights[i].to_light.w > lobe);
}

/// light.rs, DirectionalLight::extreme_cos: the cosine with `w` of the disk's direction
/// where the phase function of `g` is largest.
fn light_extreme_cos(i: u32, w: vec3<f32>, g: f32) -> f32 {
    let l = params.lights[i];
    let centre = acos(clamp(dot(w, l.to_light.xyz), -1.0, 1.0));
    let radius = 2.0 * asin(sqrt(0.5 * l.to_light.w));
    let angle = select(min(centre + radius, PI), max(centre - radius, 0.0), g >= 0.0);
    return cos(angle);
}

fn light_radiance_toward(i: u32, dir: vec3<f32>, channel: u32) -> f32 {
    let l = params.lights[i];
    // light.rs, radiance_toward: in front and sin²θ = |dir × to_light|² ≤ sin²θ_max.
    let x = cross(dir, l.to_light.xyz);
    if l.to_light.w > 0.0 && dot(dir, l.to_light.xyz) > 0.0 && dot(x, x) <= l.radiance.w {
        return l.radiance[channel];
    }
    return 0.0;
}

fn env_lookup(dir: vec3<f32>, channel: u32) -> f32 {
    let base = params.env_radiance[channel];
    let w = params.misc.x;
    let h = params.misc.y;
    // ENV_MAP: a constant (kernels.rs, SceneSwitches); w = 0 would be no map too.
    if !ENV_MAP || w == 0u {
        return base;
    }
    // light.rs, Environment::lookup: Mitsuba 3's u = atan2(x, −z)/2π mod 1.
    let a = atan2(dir.x, -dir.z) / TWO_PI;
    let u = a - floor(a);
    let v = acos(clamp(dir.y, -1.0, 1.0)) / PI;
    let x = min(u32(max(u * f32(w), 0.0)), w - 1u);
    let y = min(u32(max(v * f32(h), 0.0)), h - 1u);
    return base * env_map[y * w + x][channel];
}
