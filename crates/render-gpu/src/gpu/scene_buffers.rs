//! Host mirrors of the structs in `shaders/scene.wgsl` (storage `Params`, storage `Node`
//! and `Tri`): `#[repr(C)]` + bytemuck, every field a 16-byte group so the WGSL uniform
//! and storage layouts match without hidden padding.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::distance_grid::DistanceGrid;
use crate::error::RenderError;
use crate::geometry::Geometry;
use crate::integrator::{IntegratorKind, IntegratorSettings};
use crate::setup::SceneData;

/// Lights the kernels read (`Params` holds a fixed array). 64 rather than the CPU's
/// unbounded list: 48 B a light is 3 KB of the params buffer, far below any binding limit,
/// while NEE casts a shadow ray per light and event, so a scene of more lights is slow
/// anywhere and renders on the CPU. The kernels loop over the scene's own count
/// (`LIGHTS`), so the unused entries cost nothing but their bytes.
pub const MAX_GPU_LIGHTS: usize = 64;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuLight {
    pub to_light: [f32; 4],
    pub irradiance: [f32; 4],
    pub radiance: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct Params {
    pub cam_origin: [f32; 4],
    pub cam_forward: [f32; 4],
    pub cam_right: [f32; 4],
    pub cam_up: [f32; 4],
    pub sigma_t: [f32; 4],
    pub albedo: [f32; 4],
    pub ln_albedo: [f32; 4],
    pub one_minus_albedo: [f32; 4],
    pub albedo_feature: [f32; 4],
    pub env_radiance: [f32; 4],
    pub grid_lo: [f32; 4],
    pub grid_dims: [u32; 4],
    pub lights: [GpuLight; MAX_GPU_LIGHTS],
    /// width, height, lanes, samples per lane.
    pub image: [u32; 4],
    /// first sample, end sample, seed lo, seed hi.
    pub sampling: [u32; 4],
    /// light count, nee, dielectric, stcvae.
    pub flags: [u32; 4],
    /// env map width, height, nee samples, dispatch kind (2: the render's first dispatch,
    /// 1: a chunk's first, 0: a resumed one).
    pub misc: [u32; 4],
    /// g, ior, eps, min_tau.
    pub consts: [f32; 4],
    /// max_tau, near_surface, bounces per dispatch, tile stride.
    pub consts2: [f32; 4],
    /// exact_tau (below it a sphere step simulates its walk), exact_nee_samples (as f32),
    /// the loop-limit probe's passes ([`LOOP_PROBE_PASSES`]), the camera rays' start
    /// ([`crate::camera::Camera::start`]).
    pub consts3: [f32; 4],
    /// NEE's radiance factor ([`crate::setup::Boundary::nee_scale`]), then unused.
    pub consts4: [f32; 4],
    /// Where the mesh's pieces overlap, per nesting depth (16 at most, 4 to an entry) the
    /// bits of the pieces at it ([`crate::geometry::Pieces::at_depth`]; each triangle's
    /// piece is in its `v0.w`); all 0 without overlaps.
    pub pieces: [[u32; 4]; 4],
}

/// All zero (the std library derives `Default` only for arrays of up to 32 lights).
impl Default for Params {
    fn default() -> Self {
        Self::zeroed()
    }
}

/// Passes of the kernel's loop-limit probe (path.wgsl, after the bounce loop): where
/// llvmpipe's loop limit has run out, every loop stops after one pass, so a probe that runs
/// fewer than two tells a dispatch whose last bounce was cut short. A uniform rather than a
/// constant so that the shader compiler cannot unroll the loop away.
pub const LOOP_PROBE_PASSES: f32 = 2.0;

/// A BVH2 node as obvhs lays it out (children of an inner node at `first`, `first + 1`;
/// a leaf's triangles at `first..first + count` of the reordered triangle buffer).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuNode {
    /// The box as six f16 (lo.xy, lo.z hi.x, hi.yz; `unpack2x16float`), each rounded
    /// outward so that the decoded box contains the exact one; then
    /// `first << COUNT_BITS | count` (`node_at` in shaders/scene.wgsl).
    pub packed: [u32; 4],
}

impl GpuNode {
    /// Bits of the fourth word that hold the leaf's triangle count (the kernels get it
    /// as `NODE_COUNT_BITS` from gpu/kernels.rs).
    pub const COUNT_BITS: u32 = 4;
    /// The largest leaf size and first index the packing holds.
    pub const MAX_COUNT: u32 = (1 << Self::COUNT_BITS) - 1;
    pub const MAX_FIRST: u32 = (1 << (32 - Self::COUNT_BITS)) - 1;

    pub fn new(lo: [f32; 3], hi: [f32; 3], first: u32, count: u32) -> Self {
        let l = lo.map(|v| f16_outward(v, false));
        let h = hi.map(|v| f16_outward(v, true));
        let pair = |a: u16, b: u16| a as u32 | (b as u32) << 16;
        Self {
            packed: [
                pair(l[0], l[1]),
                pair(l[2], h[0]),
                pair(h[1], h[2]),
                first << Self::COUNT_BITS | count,
            ],
        }
    }
}

/// f16 bits to f32 (exact).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let e = ((h >> 10) & 0x1f) as i32;
    let m = (h & 0x3ff) as f32;
    match e {
        0 => sign * m * 2f32.powi(-24),
        31 if m == 0.0 => sign * f32::INFINITY,
        31 => f32::NAN,
        _ => sign * (1.0 + m / 1024.0) * 2f32.powi(e - 15),
    }
}

/// The f16 (bits) nearest `v` on the side of +∞ (`up`) or of −∞: its value bounds `v`, so
/// a box rounded outward this way contains the exact box. Beyond f16's range the bound is
/// infinite, which culls nothing but stays correct.
pub fn f16_outward(v: f32, up: bool) -> u16 {
    let a = v.abs();
    // The largest f16 magnitude ≤ |v|: an estimate, corrected by a step or two.
    let mut mag: u16 = if !(a < 65504.0) {
        0x7bff
    } else if a < 2f32.powi(-14) {
        (a * 2f32.powi(24)) as u16
    } else {
        let e = (a.log2().floor() as i32).clamp(-14, 15);
        let m = (((a / 2f32.powi(e) - 1.0) * 1024.0) as u16).min(1023);
        (((e + 15) as u16) << 10) | m
    };
    while mag < 0x7c00 && f16_to_f32(mag + 1) <= a {
        mag += 1;
    }
    while mag > 0 && f16_to_f32(mag) > a {
        mag -= 1;
    }
    // Between two f16 magnitudes: a bound lying away from zero takes the larger.
    let away = up != v.is_sign_negative();
    let mag = mag + (away && f16_to_f32(mag) != a) as u16;
    let sign = if v.is_sign_negative() { 0x8000 } else { 0 };
    // No subnormal: a GPU may flush one to zero when it unpacks it, which would move the
    // bound inward. Below 2⁻¹⁴ a bound is zero when it lies toward zero from v, and 2⁻¹⁴
    // when it lies away.
    if mag != 0 && mag < 0x0400 {
        return sign | if away { 0x0400 } else { 0 };
    }
    sign | mag
}

/// A triangle in BVH leaf order, with its outward unit normal.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuTri {
    pub v0: [f32; 4],
    pub v1: [f32; 4],
    pub v2: [f32; 4],
    pub n: [f32; 4],
}

fn v4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}

fn c4(a: [f32; 3]) -> [f32; 4] {
    [a[0], a[1], a[2], 0.0]
}

/// Levels of the BVH2 below its root (0 for a root leaf).
pub fn bvh_depth(bvh: &obvhs::bvh2::Bvh2) -> usize {
    let mut deepest = 0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((i, d)) = stack.pop() {
        let Some(n) = bvh.nodes.get(i) else { continue };
        deepest = deepest.max(d);
        if n.prim_count == 0 {
            let f = n.first_index as usize;
            stack.push((f, d + 1));
            stack.push((f + 1, d + 1));
        }
    }
    deepest
}

/// The distance grid as the kernels read it (`grid` in shaders/scene.wgsl): the cells
/// ([`DistanceGrid::cells`], two words each, n + 1 of them), then the candidate lists
/// with each triangle given by its place in the BVH-ordered triangle buffer.
pub fn grid_buffer(grid: &DistanceGrid, geo: &Geometry) -> Vec<u32> {
    let mut place = vec![0u32; geo.tris.len()];
    for (k, &p) in geo.bvh.primitive_indices.iter().enumerate() {
        place[p as usize] = k as u32;
    }
    let mut words = Vec::with_capacity(2 * grid.cells.len() + grid.candidates.len());
    words.extend_from_slice(grid.cells.as_flattened());
    words.extend(grid.candidates.iter().map(|&p| place[p as usize]));
    words
}

/// BVH nodes and triangles in leaf order.
pub fn geometry_buffers(scene: &SceneData) -> Result<(Vec<GpuNode>, Vec<GpuTri>), RenderError> {
    let geo = &scene.geo;
    let mut nodes = Vec::with_capacity(geo.bvh.nodes.len() + 2);
    for n in &geo.bvh.nodes {
        if n.prim_count > GpuNode::MAX_COUNT || n.first_index > GpuNode::MAX_FIRST {
            return Err(RenderError::SceneBeyondGpu(format!(
                "the mesh's BVH has a node the GPU kernels cannot hold (first {}, count {}; \
                 at most {} and {}); use --device cpu",
                n.first_index,
                n.prim_count,
                GpuNode::MAX_FIRST,
                GpuNode::MAX_COUNT
            )));
        }
        nodes.push(GpuNode::new(
            n.aabb.min.into(),
            n.aabb.max.into(),
            n.first_index,
            n.prim_count,
        ));
    }
    // The mesh's exact bounds after the nodes, for the inside-the-bounds check that the
    // CPU makes with them (shaders/scene.wgsl, `mesh_bounds`).
    let bits = |v: Vec3| GpuNode {
        packed: [v.x.to_bits(), v.y.to_bits(), v.z.to_bits(), 0],
    };
    nodes.push(bits(geo.lo));
    nodes.push(bits(geo.hi));
    let tris = geo
        .bvh
        .primitive_indices
        .iter()
        .map(|&p| {
            let t = &geo.tris[p as usize];
            let n = geo.normals[p as usize];
            GpuTri {
                // w: 1 + the number of its piece where pieces overlap, else 0 (scene.wgsl,
                // piece_bit; a number, as bits would be subnormal floats).
                v0: v4(
                    Vec3::from_array(t.v0.into()),
                    geo.pieces
                        .as_ref()
                        .map_or(0.0, |q| (q.bit_of[p as usize].trailing_zeros() + 1) as f32),
                ),
                v1: c4(t.v1.into()),
                v2: c4(t.v2.into()),
                // w: cos θ of the triangle's escape cone (path.wgsl).
                n: v4(n, geo.escape_cos[p as usize]),
            }
        })
        .collect();
    Ok((nodes, tris))
}

/// The scene constants of a render; the per-dispatch fields (`image.z..w`,
/// `sampling.xy`, `misc.w`, `consts2.zw`) are filled by the renderer.
pub fn scene_params(scene: &SceneData, set: &IntegratorSettings, seed: u64) -> Params {
    let cam = &scene.camera;
    let albedo64 = scene.albedo.map(|a| a as f64);
    let ln = albedo64.map(|a| if a > 0.0 { a.ln() as f32 } else { -1e30 });
    let mut lights = [GpuLight::default(); MAX_GPU_LIGHTS];
    for (g, l) in lights.iter_mut().zip(&scene.lights) {
        *g = GpuLight {
            to_light: v4(l.to_light, l.one_minus_cos),
            irradiance: c4(l.irradiance),
            radiance: {
                let [r, g, b] = l.radiance;
                [r, g, b, l.sin2_max]
            },
        };
    }
    let (grid_lo, grid_dims, near) = match &scene.grid {
        Some(g) => (
            v4(g.lo, g.cell),
            [g.dims.x, g.dims.y, g.dims.z, 1],
            g.near_surface,
        ),
        None => ([0.0; 4], [0; 4], 0.0),
    };
    let (env_w, env_h) = scene
        .env
        .map
        .as_ref()
        .map_or((0, 0), |m| (m.width as u32, m.height as u32));
    let (dielectric, ior) = match scene.boundary.ior() {
        None => (0, 1.0),
        Some(ior) => (1, ior),
    };
    Params {
        cam_origin: v4(cam.origin, cam.tan_half()),
        // w: the image's height (camera_dir); cam_right.w, a band's first row, is set per
        // band by the renderer.
        cam_forward: v4(cam.forward(), cam.height as f32),
        cam_right: v4(cam.right(), 0.0),
        cam_up: v4(cam.up(), 0.0),
        sigma_t: c4(scene.sigma_t),
        albedo: c4(scene.albedo),
        ln_albedo: c4(ln),
        one_minus_albedo: c4(albedo64.map(|a| (1.0 - a) as f32)),
        albedo_feature: c4(albedo64.map(|a| cvae::features::albedo_feature(a) as f32)),
        env_radiance: c4(scene.env.radiance),
        grid_lo,
        grid_dims,
        lights,
        image: [cam.width, cam.height, 1, 1],
        sampling: [0, 0, seed as u32, (seed >> 32) as u32],
        flags: [
            scene.lights.len().min(MAX_GPU_LIGHTS) as u32,
            set.nee as u32,
            dielectric,
            (set.kind == IntegratorKind::Stcvae) as u32,
        ],
        misc: [env_w, env_h, set.nee_samples.max(1), 1],
        consts: [scene.g, ior, scene.geo.eps, set.min_tau],
        consts2: [set.max_tau, near, 0.0, 0.0],
        consts3: [
            set.exact_tau,
            set.exact_nee_samples as f32,
            LOOP_PROBE_PASSES,
            cam.start,
        ],
        consts4: [scene.boundary.nee_scale(), 0.0, 0.0, 0.0],
        pieces: {
            let mut a = [[0u32; 4]; 4];
            if let Some(p) = &scene.geo.pieces {
                for (d, &bits) in p.at_depth.iter().enumerate() {
                    a[d / 4][d % 4] = bits;
                }
            }
            a
        },
    }
}

/// The environment map as rgba rows (a 1-texel dummy when there is none).
pub fn env_buffer(scene: &SceneData) -> Vec<[f32; 4]> {
    match &scene.env.map {
        Some(m) => m.pixels.iter().map(|p| c4(*p)).collect(),
        None => vec![[0.0; 4]],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Geometry;

    /// The depth the GPU stack check relies on: at least log2 of the leaf count (no binary
    /// tree is shallower), and within a small factor of it for obvhs's SAH builds (a depth
    /// that counted wrongly, e.g. only one branch, would fall outside).
    #[test]
    fn bvh_depth_bounds_the_tree() {
        let geo = Geometry::new(crate::mesh::sphere(0.5));
        let depth = bvh_depth(&geo.bvh);
        let leaves = geo.bvh.nodes.iter().filter(|n| n.prim_count > 0).count();
        assert!(leaves > 1, "a sphere mesh needs more than one leaf");
        let min_depth = (leaves as f64).log2().ceil() as usize;
        assert!(
            depth >= min_depth && depth < 4 * min_depth + 8,
            "depth {depth} for {leaves} leaves"
        );
    }

    /// Every f16 bit pattern decodes as IEEE binary16 does (checked at the values whose
    /// meaning is fixed: zero, the smallest subnormal, one, the largest finite, infinity).
    #[test]
    fn f16_decodes_binary16() {
        assert_eq!(f16_to_f32(0x0000), 0.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
        assert_eq!(f16_to_f32(0x3555), 0.333_251_95);
    }

    /// A box rounded outward contains the exact one, and no tighter f16 would: for values
    /// across f16's range (subnormal, normal, beyond it), both signs and exact f16 values,
    /// the lower bound is ≤ v and the next f16 above it is > v (mirrored for the upper),
    /// subnormals left out: the bounds never are one.
    #[test]
    fn f16_outward_bounds_tightly() {
        let mut rng = scatter_sim::rng::WalkRng::from_seed(5);
        let mut values: Vec<f32> = vec![0.0, -0.0, 1.0, -1.0, 0.5, 65504.0, 7e4, -7e4, 1e-9];
        for _ in 0..20_000 {
            let e = rng.uniform() * 40.0 - 26.0;
            let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
            values.push((sign * 2f64.powf(e)) as f32);
        }
        // The f16 values next to a bound, by exhaustive search.
        let all: Vec<f32> = (0..=u16::MAX)
            .filter(|b| b & 0x7c00 != 0 || b & 0x03ff == 0)
            .map(f16_to_f32)
            .filter(|w| !w.is_nan())
            .collect();
        let above = |x: f32| {
            all.iter()
                .copied()
                .filter(|&w| w > x)
                .fold(f32::INFINITY, f32::min)
        };
        let below = |x: f32| {
            all.iter()
                .copied()
                .filter(|&w| w < x)
                .fold(f32::NEG_INFINITY, f32::max)
        };
        for (k, &v) in values.iter().enumerate() {
            let (l, h) = (f16_outward(v, false), f16_outward(v, true));
            let (lo, hi) = (f16_to_f32(l), f16_to_f32(h));
            assert!(lo <= v && v <= hi, "{v}: [{lo}, {hi}]");
            // Never a subnormal, which a GPU may flush to zero (inward).
            for b in [l, h] {
                assert!(
                    b & 0x7c00 != 0 || b & 0x03ff == 0,
                    "{v}: subnormal bound {b:#06x}"
                );
            }
            // Tightness among zero and the normal f16, on a sample (the search is slow).
            if k < 300 {
                assert!(above(lo) > v, "{v}: lower bound {lo} not tight");
                assert!(below(hi) < v, "{v}: upper bound {hi} not tight");
            }
        }
    }

    /// Both halves of the 64-bit seed reach the kernels (sampling.z = low word, sampling.w
    /// = high word): seeds that differ only above bit 31 (e.g. --seed 7 and 4294967303)
    /// must draw different samples. Every GPU test uses seeds below 2^32.
    #[test]
    fn both_halves_of_the_seed_reach_the_kernels() {
        // The scene of integrator/sphere_step.rs's `lit_sphere` (a unit test there builds it).
        let f = crate::scene::SceneFile::parse(
            std::path::Path::new("t.toml"),
            "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
             width = 8\nheight = 8\n[object]\nshape = \"sphere\"\nradius = 0.5\n\
             [medium]\nsigma_t = [2.0, 4.0, 8.0]\nalbedo = [0.9, 0.9, 0.9]\ng = 0.5\n\
             [[light]]\nkind = \"directional\"\ndirection = [0.3, -0.8, 0.5]\n\
             irradiance = [1.0, 2.5, 0.5]\n",
        )
        .unwrap();
        let scene =
            crate::setup::SceneData::build(&f, std::path::Path::new("."), false, &[]).unwrap();
        let set = crate::integrator::IntegratorSettings {
            kind: crate::integrator::IntegratorKind::Pt,
            nee: false,
            model: None,
            min_tau: 0.0,
            max_tau: 0.0,
            exact_tau: 0.0,
            nee_samples: 1,
            exact_nee_samples: 1,
            path_nee_rays: 0,
        };
        let p = scene_params(&scene, &set, 0x0123_4567_89ab_cdef);
        assert_eq!(
            [p.sampling[2], p.sampling[3]],
            [0x89ab_cdef_u32, 0x0123_4567_u32]
        );
        let low = scene_params(&scene, &set, 7).sampling;
        let high = scene_params(&scene, &set, 7 + (1u64 << 32)).sampling;
        assert_ne!(low, high);
    }

    /// bvh_depth is exactly the levels below the root (0 for a root leaf), as an
    /// independent recursive count gives them: the renderer refuses a tree when depth + 1
    /// exceeds the kernels' 48-entry stack, so one level too many refuses a tree that fits,
    /// and one too few lets a tree overflow the stack.
    #[test]
    fn bvh_depth_counts_the_levels_below_the_root_exactly() {
        fn levels(bvh: &obvhs::bvh2::Bvh2, i: usize) -> usize {
            let n = &bvh.nodes[i];
            if n.prim_count > 0 {
                0
            } else {
                let f = n.first_index as usize;
                1 + levels(bvh, f).max(levels(bvh, f + 1))
            }
        }
        for (name, mesh) in [
            ("sphere", crate::mesh::sphere(0.5)),
            ("cube", crate::mesh::cube(1.0)),
        ] {
            let geo = Geometry::new(mesh);
            assert_eq!(bvh_depth(&geo.bvh), levels(&geo.bvh, 0), "{name}");
        }
    }
}
