//! Scenes, the model and helpers shared by the renderer's test files.

// Each test file uses a part of this module; the rest is compiled unused there.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The shipped model, or `$STCVAE_TEST_MODEL`.
pub fn load_model() -> cvae::ModelSet {
    let p = std::env::var_os("STCVAE_TEST_MODEL")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.stcvae")
        });
    cvae::ModelSet::load(&p).unwrap()
}

/// Parses a test scene's TOML and builds it (meshes relative to this crate), with the
/// distance grid if `grid`.
pub fn build_scene(text: &str, grid: bool) -> render_gpu::setup::SceneData {
    let f = render_gpu::scene::SceneFile::parse(std::path::Path::new("test.toml"), text).unwrap();
    render_gpu::setup::SceneData::build(
        &f,
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")),
        grid,
        &[],
    )
    .unwrap()
}

/// The white furnace: the bunny with albedo 1 in a constant environment of 0.7, no lights;
/// `boundary` is the body of the [boundary] table.
pub fn furnace_scene(boundary: &str) -> String {
    format!(
        r#"
[camera]
origin = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
fov_deg = 25.0
width = 12
height = 12
[object]
mesh = "../../assets/bunny.glb"
height = 1.0
[medium]
sigma_t = [5.0, 20.0, 60.0]
albedo = [1.0, 1.0, 1.0]
g = 0.6
[boundary]
{boundary}
[environment]
radiance = [0.7, 0.7, 0.7]
[render]
grid_resolution = 64
"#
    )
}

/// The furnace seen from 10⁵ away through a lens 33,000× narrower: the same view, from
/// where a camera ray's hit computed from the camera carried rounding far beyond the
/// surface's offset (1.5 million leaks in 1,872 paths before the rays started near the
/// object, `Camera::start_before`).
pub fn far_furnace_scene(boundary: &str) -> String {
    let text = furnace_scene(boundary)
        .replace("origin = [0.0, 0.0, 3.0]", "origin = [0.0, 0.0, 100000.0]")
        .replace("fov_deg = 25.0", "fov_deg = 0.00075");
    assert!(text.contains("100000.0") && text.contains("0.00075"));
    text
}

/// A uniformly random point inside the closed mesh (rejection from its bounds).
pub fn random_interior(
    geo: &render_gpu::geometry::Geometry,
    rng: &mut scatter_sim::WalkRng,
) -> glam::Vec3 {
    loop {
        let u = glam::Vec3::new(
            rng.uniform() as f32,
            rng.uniform() as f32,
            rng.uniform() as f32,
        );
        let p = geo.lo + (geo.hi - geo.lo) * u;
        if geo.inside(p) {
            return p;
        }
    }
}

/// A direction uniform on the unit sphere.
pub fn uniform_direction(rng: &mut scatter_sim::WalkRng) -> glam::Vec3 {
    let (c, s) = rng.unit_circle();
    let z = 2.0 * rng.uniform() - 1.0;
    let q = (1.0 - z * z).sqrt();
    glam::Vec3::new((q * c) as f32, (q * s) as f32, z as f32)
}

/// A prism whose cross-section is a wedge of slope 10⁻³ (1 × 10⁻³ thick at its thick
/// end), seen from above at `x` from its sharp edge, where it is x · 10⁻³ thick: at
/// x = 3 × 10⁻³ that is 3 × 10⁻⁶, a sliver below the geometry's spawn offset (2 × 10⁻⁵ of
/// the scene's size, ~9 × 10⁻⁵); at x = 0.5 it is 5 × 10⁻⁴, well above it. A cube 3 units
/// away makes the mesh's bounding box large, so a path left outside beyond the sliver while
/// believing itself inside scatters through the air instead of leaving the box at once.
/// Albedo 1, a constant environment of 1 and a sun (NEE on): a path that passes unscattered
/// is exactly 1, one that scatters in the air adds unshadowed sunlight. The OBJ is written
/// into `dir`.
pub fn sliver_scene(dir: &Path, x: f64, sigma_t: f64) -> String {
    let obj = "\
v 0 0 -0.5\nv 1 0 -0.5\nv 1 0.001 -0.5\nv 0 0 0.5\nv 1 0 0.5\nv 1 0.001 0.5\n\
f 1 3 2\nf 4 5 6\nf 1 2 5 4\nf 2 3 6 5\nf 1 4 6 3\n\
v -3.5 -3.5 -0.5\nv -2.5 -3.5 -0.5\nv -3.5 -2.5 -0.5\nv -2.5 -2.5 -0.5\n\
v -3.5 -3.5 0.5\nv -2.5 -3.5 0.5\nv -3.5 -2.5 0.5\nv -2.5 -2.5 0.5\n\
f 7 9 10 8\nf 11 12 14 13\nf 7 8 12 11\nf 9 13 14 10\nf 7 11 13 9\nf 8 10 14 12\n";
    let mesh = dir.join("sliver.obj");
    std::fs::write(&mesh, obj).unwrap();
    format!(
        r#"
[camera]
origin = [{x}, 1.0, 0.0]
target = [{x}, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov_deg = 0.1
width = 16
height = 16
[object]
mesh = "{}"
[medium]
sigma_t = [{sigma_t}, {sigma_t}, {sigma_t}]
albedo = [1.0, 1.0, 1.0]
g = 0.0
[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = [1.0, 1.0, 1.0]
[environment]
radiance = [1.0, 1.0, 1.0]
[render]
grid_resolution = 32
"#,
        mesh.display()
    )
}

/// A dielectric boundary, to append to a scene without one: at a sliver, a path either
/// reflects off the surface or refracts in and passes the sliver, and goes on unscattered.
const DIELECTRIC: &str = "[boundary]\nkind = \"dielectric\"\nior = 1.5\n";

/// The sliver checks of one device, `render(scene, kind)` rendering 12 spp of PT or
/// ST-CVAE with NEE: at the sliver (index-matched and dielectric) every path passes
/// ([`assert_sliver_passed`]); where the wedge is thicker than the offset, paths enter
/// and scatter.
pub fn check_slivers(
    render: impl Fn(
        &render_gpu::setup::SceneData,
        render_gpu::integrator::IntegratorKind,
    ) -> render_gpu::render::RenderOutput,
) {
    use render_gpu::integrator::IntegratorKind;
    let dir = tempfile::tempdir().unwrap();
    let text = sliver_scene(dir.path(), 0.003, 1.0);
    let sliver = build_scene(&text, true);
    let dielectric = build_scene(&(text + DIELECTRIC), true);
    let thick = build_scene(&sliver_scene(dir.path(), 0.5, 1000.0), true);
    for kind in [IntegratorKind::Pt, IntegratorKind::Stcvae] {
        assert_sliver_passed(kind, &render(&sliver, kind));
        assert_sliver_passed(kind, &render(&dielectric, kind));
        let out = render(&thick, kind);
        assert!(
            out.stats.events + out.stats.steps > 100,
            "{kind:?}: {:?}",
            out.stats
        );
    }
}

/// What a render of [`sliver_scene`] at a sliver must be: no path scattered (nor was
/// found outside while believed inside), and every pixel is the environment's 1.
fn assert_sliver_passed(
    kind: render_gpu::integrator::IntegratorKind,
    out: &render_gpu::render::RenderOutput,
) {
    assert_eq!(
        (out.stats.events, out.stats.steps, out.stats.leaks),
        (0, 0, 0),
        "{kind:?}: paths scattered in the air"
    );
    for (i, p) in out.image.pixels.iter().enumerate() {
        assert!(
            p.iter().all(|v| (v - 1.0).abs() < 1e-6),
            "{kind:?} pixel {i}: {p:?}"
        );
    }
}

/// OBJ text of axis-aligned boxes (each closed, outward-facing quads).
pub fn boxes_obj(boxes: &[([f32; 3], [f32; 3])]) -> String {
    let mut s = String::new();
    for (lo, hi) in boxes {
        for k in 0..8 {
            let c = |bit: usize, i: usize| if k >> bit & 1 == 1 { hi[i] } else { lo[i] };
            s += &format!("v {} {} {}\n", c(0, 0), c(1, 1), c(2, 2));
        }
    }
    // Vertex k of a box has bits (x, y, z); faces counter-clockwise seen from outside.
    let faces = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    for b in 0..boxes.len() {
        for f in faces {
            let v = f.map(|k| 1 + 8 * b + k);
            s += &format!("f {} {} {} {}\n", v[0], v[1], v[2], v[3]);
        }
    }
    s
}

/// The scene of [`touching_parts_scenes`] and [`overlapping_parts_scenes`]: `mesh` seen
/// from above and aside under a sun, with `tables` (TOML) added.
fn lit_mesh_scene(mesh: &Path, tables: &str) -> String {
    format!(
        r#"
[camera]
origin = [1.5, 2.0, 3.0]
target = [0.0, 0.0, 0.0]
fov_deg = 30.0
width = 16
height = 16
[object]
mesh = "{}"
[medium]
sigma_t = [4.0, 12.0, 40.0]
albedo = [0.99, 0.95, 0.8]
g = 0.5
[[light]]
kind = "directional"
direction = [0.3, -1.0, -0.2]
irradiance = [1.0, 1.0, 1.0]
{tables}[render]
grid_resolution = 64
"#,
        mesh.display()
    )
}

/// A box of medium lit by a sun (NEE), as one part and as two parts stacked with a gap of
/// air of 10⁻⁶ between them — a tenth of the spawn offset (2 × 10⁻⁵ of the scene's size
/// 0.5), which is how touching parts of a mesh usually look. With an index-matched boundary
/// the two scenes are the same medium but for the gap, so they must render alike. The OBJ
/// files are written into `dir`; returns (one part, two parts).
pub fn touching_parts_scenes(dir: &Path) -> (String, String) {
    let one = dir.join("one.obj");
    let two = dir.join("two.obj");
    std::fs::write(&one, boxes_obj(&[([-0.5; 3], [0.5; 3])])).unwrap();
    let lower = ([-0.5, -0.5, -0.5], [0.5, 0.0, 0.5]);
    let upper = ([-0.5, 1e-6, -0.5], [0.5, 0.5, 0.5]);
    std::fs::write(&two, boxes_obj(&[lower, upper])).unwrap();
    let scene = |mesh: &Path| lit_mesh_scene(mesh, "");
    (scene(&one), scene(&two))
}

/// Objects made of overlapping closed pieces, each beside the same object made without
/// overlaps, lit as in [`touching_parts_scenes`] (index-matched, or with `boundary` as
/// the [boundary] table's body). Returns (what, without overlaps, with them):
/// - the cube [−0.5, 0.5]³ as one box, and as two boxes overlapping in x ∈ [−0.2, 0.2],
///   whose y and z faces share planes;
/// - a step (two boxes overlapping in a corner, z faces in shared planes), and the same
///   step as three boxes touching across gaps of 10⁻⁶ (rendered as one medium:
///   `touching_parts_render_as_one_medium`);
/// - the cube with a cubic cavity in it, as one box around a cavity and as the two
///   overlapping boxes around it (a cavity within two solids is air, not medium);
/// - the cube with a cavity across the two boxes' seam (in their union, in neither alone).
pub fn overlapping_parts_scenes(dir: &Path, boundary: &str) -> Vec<(String, String, String)> {
    let cube = ([-0.5; 3], [0.5; 3]);
    let left = ([-0.5, -0.5, -0.5], [0.2, 0.5, 0.5]);
    let right = ([-0.2, -0.5, -0.5], [0.5, 0.5, 0.5]);
    let cavity = ([-0.15; 3], [0.15; 3]);
    let seam = ([-0.35, -0.15, -0.15], [0.35, 0.15, 0.15]);
    let low = ([-0.5, -0.5, -0.5], [0.2, 0.2, 0.5]);
    let high = ([-0.2, -0.2, -0.5], [0.5, 0.5, 0.5]);
    let g = 1e-6;
    let step_parts = [
        low,
        ([-0.2, 0.2 + g, -0.5], [0.5, 0.5, 0.5]),
        ([0.2 + g, -0.2, -0.5], [0.5, 0.2, 0.5]),
    ];
    let write = |name: &str, boxes: &[([f32; 3], [f32; 3])], cavities: &[([f32; 3], [f32; 3])]| {
        let mut text = boxes_obj(boxes);
        // The cavities are written as boxes of their own; the mesh loader finds them
        // nested and turns them inward.
        let offset = 8 * boxes.len();
        for line in boxes_obj(cavities).lines() {
            text += &match line.strip_prefix("f ") {
                Some(f) => {
                    let v: Vec<usize> = f.split(' ').map(|k| k.parse().unwrap()).collect();
                    let v: Vec<String> = v.iter().map(|k| (k + offset).to_string()).collect();
                    format!("f {}\n", v.join(" "))
                }
                None => format!("{line}\n"),
            };
        }
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let tables = format!("[boundary]\n{boundary}\n[environment]\nradiance = [0.1, 0.2, 0.3]\n");
    let scene = |mesh: &Path| lit_mesh_scene(mesh, &tables);
    vec![
        (
            "cube".to_string(),
            scene(&write("cube.obj", &[cube], &[])),
            scene(&write("cube2.obj", &[left, right], &[])),
        ),
        (
            "step".to_string(),
            scene(&write("step3.obj", &step_parts, &[])),
            scene(&write("step2.obj", &[low, high], &[])),
        ),
        (
            "cube with a cavity".to_string(),
            scene(&write("hollow.obj", &[cube], &[cavity])),
            scene(&write("hollow2.obj", &[left, right], &[cavity])),
        ),
        (
            "cube with a cavity across the seam".to_string(),
            scene(&write("seam.obj", &[cube], &[seam])),
            scene(&write("seam2.obj", &[left, right], &[seam])),
        ),
    ]
}

/// The sun-in-view scenes (integrators.rs and gpu/agreement.rs,
/// `..._sun_disk_in_view_...`): a camera ray that escapes without scattering sees a 10°
/// disk of irradiance E_c = c + 1 over a sky of 0.1, so every sample of channel c is 0.1 +
/// E_c/(π sin² 5°) (L written out here, not taken from light.rs), to f32 rounding (1e-4).
/// `what` names the render.
pub fn assert_sun_disk_seen(image: &render_gpu::image_io::RgbImage, what: &str) {
    let sin = 5f64.to_radians().sin();
    for p in &image.pixels {
        for (c, &v) in p.iter().enumerate() {
            let want = 0.1 + (c + 1) as f64 / (std::f64::consts::PI * sin * sin);
            assert!(
                (v as f64 / want - 1.0).abs() < 1e-4,
                "{what}, channel {c}: {v} for {want}"
            );
        }
    }
}

/// A variance image of a render whose every sample is the same value (a white furnace):
/// 0 up to rounding in every pixel and channel, below 1e-10 (`what` names the render).
pub fn assert_noiseless(v: &render_gpu::image_io::RgbImage, what: &str) {
    assert!(
        v.pixels
            .iter()
            .flatten()
            .all(|&x| (0.0..1e-10).contains(&x)),
        "{what}: furnace variances {:?}",
        &v.pixels[..4]
    );
}

/// Says on the terminal why a test is skipped. Written to stderr directly rather than with
/// `eprintln!`, which libtest captures and shows only for failing tests: a skipped test
/// passes, so its reason would otherwise never be seen without `--nocapture`.
pub fn skip(reason: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "skipping {reason}");
}

/// A dielectric cube (ior 1.5, size 1) lit by a 10° sun disk travelling along
/// `direction`, seen 30° off its top face's normal (so the face's mirror image of the sun
/// misses the camera for the suns the tests use) through a lens of `fov_deg` aimed at the
/// face's centre, `pixels` square, its medium's phase function `g`: how NEE's shadow rays
/// refract (integrators.rs; gpu/agreement.rs,
/// `cpu_gpu_agree_on_refracted_nee_through_flat_faces`).
pub fn dielectric_cube_scene(fov_deg: f64, pixels: u32, g: f64, direction: &str) -> String {
    format!(
        r#"
[camera]
origin = [0.0, -1.5, 3.098]
target = [0.0, 0.0, 0.5]
up = [0.0, 0.0, 1.0]
fov_deg = {fov_deg:?}
width = {pixels}
height = {pixels}
[object]
shape = "cube"
size = 1.0
[medium]
sigma_t = [20.0, 30.0, 40.0]
albedo = [0.95, 0.95, 0.95]
g = {g:?}
[boundary]
kind = "dielectric"
ior = 1.5
[[light]]
kind = "directional"
direction = {direction}
irradiance = [1.0, 1.0, 1.0]
angular_diameter_deg = 10.0
[environment]
radiance = [0.0, 0.0, 0.0]
"#
    )
}

/// A right-angle prism along z (legs of 1 along x and y, depth 1, centred in z), its
/// hypotenuse facing +x+y.
pub const PRISM_OBJ: &str = "v 0 0 -0.5\nv 1 0 -0.5\nv 0 1 -0.5\nv 0 0 0.5\nv 1 0 0.5\nv 0 1 0.5\n\
                             f 1 3 2\nf 4 5 6\nf 1 2 5 4\nf 1 4 6 3\nf 2 3 6 5\n";

/// The prism of [`PRISM_OBJ`] (written into `dir`) in glass (ior 1.5, σ_t 1, albedo 1,
/// isotropic), lit along +y by a 20° sun disk that enters its bottom face and is totally
/// reflected by the hypotenuse, seen from +z through its front face, in a black sky
/// (integrators.rs, nee_counts_light_after_a_reflection).
pub fn prism_scene(dir: &Path) -> String {
    let mesh = dir.join("prism.obj");
    std::fs::write(&mesh, PRISM_OBJ).unwrap();
    format!(
        "[camera]\norigin = [0.33, 0.33, 4.0]\ntarget = [0.33, 0.33, 0.0]\nfov_deg = 4.0\n\
         width = 8\nheight = 8\n[object]\nmesh = {:?}\n[medium]\nsigma_t = [1.0, 1.0, 1.0]\n\
         albedo = [1.0, 1.0, 1.0]\ng = 0.0\n[boundary]\nkind = \"dielectric\"\nior = 1.5\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, 1.0, 0.0]\n\
         irradiance = [1.0, 1.0, 1.0]\nangular_diameter_deg = 20.0\n\
         [environment]\nradiance = [0.0, 0.0, 0.0]\n",
        mesh.display().to_string()
    )
}

/// A glass cube [−0.5, 0.5]³ (ior 1.5, σ_t 2, albedo 0.9, isotropic) above a glass floor
/// (y ∈ [−0.9, −0.7], x ∈ [−2, 10], z ∈ [−3, 3]; one mesh, written into `dir`) under a
/// 20° sun 15° above the horizon toward +x, in a black sky, seen head-on through the
/// cube's +x face. The floor's top face reflects F(75°) = 25 % of the sun onto that face
/// (the beam that meets the face climbs 15° from floor points x ∈ [1.25, 5]): light that
/// reaches the cube's events only by paths that leave the cube, meet the floor from outside
/// and are reflected into the disk — glints off a non-convex object, which NEE's shadow
/// rays (straight to the sun) never sample (gpu/hard_geometry.rs,
/// gpu_nee_counts_glints_off_the_outside).
pub fn glint_scene(dir: &Path) -> String {
    let mesh = dir.join("glint.obj");
    let cube = ([-0.5; 3], [0.5; 3]);
    let floor = ([-2.0, -0.9, -3.0], [10.0, -0.7, 3.0]);
    std::fs::write(&mesh, boxes_obj(&[cube, floor])).unwrap();
    format!(
        "[camera]\norigin = [4.0, 0.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 10.0\n\
         width = 8\nheight = 8\n[object]\nmesh = {:?}\n[medium]\nsigma_t = [2.0, 2.0, 2.0]\n\
         albedo = [0.9, 0.9, 0.9]\ng = 0.0\n[boundary]\nkind = \"dielectric\"\nior = 1.5\n\
         [[light]]\nkind = \"directional\"\ndirection = [-0.9659258, -0.2588190, 0.0]\n\
         irradiance = [1.0, 1.0, 1.0]\nangular_diameter_deg = 20.0\n\
         [environment]\nradiance = [0.0, 0.0, 0.0]\n",
        mesh.display().to_string()
    )
}

/// Fresnel's unpolarised reflectance from air into index `n` at incidence cosine `cos_i`,
/// written out here rather than taken from `optics::fresnel`, the code under test.
pub fn fresnel(cos_i: f64, n: f64) -> f64 {
    let sin_t = (1.0 - cos_i * cos_i).sqrt() / n;
    let cos_t = (1.0 - sin_t * sin_t).sqrt();
    let rs = ((cos_i - n * cos_t) / (cos_i + n * cos_t)).powi(2);
    let rp = ((n * cos_i - cos_t) / (n * cos_i + cos_t)).powi(2);
    (rs + rp) / 2.0
}

/// Appends the closed surface around the filled cells of a rectilinear grid (cell (i, j, k)
/// spans axes[0][i]..axes[0][i + 1] and so on) to `pos` and `tris`: two triangles, wound
/// outward, for each face between a filled cell and an empty one or the outside, on
/// shared grid vertices, so that cells joined through faces make one closed piece.
fn add_cells(
    pos: &mut Vec<[f32; 3]>,
    tris: &mut Vec<[usize; 3]>,
    axes: [&[f32]; 3],
    filled: impl Fn([usize; 3]) -> bool,
) {
    let n = axes.map(|a| a.len() - 1);
    let mut index = std::collections::HashMap::new();
    let mut vertex = |g: [usize; 3], pos: &mut Vec<[f32; 3]>| {
        *index.entry(g).or_insert_with(|| {
            pos.push([axes[0][g[0]], axes[1][g[1]], axes[2][g[2]]]);
            pos.len() - 1
        })
    };
    let open = |c: [isize; 3]| {
        !((0..3).all(|a| c[a] >= 0 && (c[a] as usize) < n[a]) && filled(c.map(|v| v as usize)))
    };
    for i in 0..n[0] {
        for j in 0..n[1] {
            for k in 0..n[2] {
                let c = [i, j, k];
                if !filled(c) {
                    continue;
                }
                for axis in 0..3 {
                    for side in [0, 1] {
                        let mut next = c.map(|v| v as isize);
                        next[axis] += 2 * side as isize - 1;
                        if !open(next) {
                            continue;
                        }
                        // (u, v, axis) is a right-handed cycle: the corners in this order
                        // turn about +axis, outward on the cell's + side.
                        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                        let corner = |du: usize, dv: usize| {
                            let mut g = c;
                            g[axis] += side;
                            g[u] += du;
                            g[v] += dv;
                            g
                        };
                        let q = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)]
                            .map(|g| vertex(g, pos));
                        let q = if side == 1 {
                            q
                        } else {
                            [q[0], q[3], q[2], q[1]]
                        };
                        tris.extend([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]);
                    }
                }
            }
        }
    }
}

/// Two combs, each one closed piece, their bases overlapping (so the mesh is a union of
/// pieces) and their 20 teeth interleaved, in units of the tooth pitch 2 (scaled by 1/40
/// in the OBJ): A's teeth x ∈ [2k, 2k + 1] (y ∈ [0, 4], z ∈ [1, 5]), B's [2k + 1.25,
/// 2k + 1.75] (y ∈ [0.5, 3.5], z ∈ [0.5, 5.5]), k = 0..19, overlapping in y ∈ [0.5, 3.5],
/// z ∈ [1, 5] (no face of one in a plane of the other's). A ray
/// along x through the teeth crosses up to 80 faces, beyond the 64 crossings the CPU's
/// list holds (`MAX_UNION_CROSSINGS`): `Geometry::in_union` then flips each hit's piece,
/// and shadow rays walk crossing by crossing. Returns the teeth as intervals of x.
fn combs_obj() -> (String, Vec<(f32, f32)>) {
    let (mut pos, mut tris) = (Vec::new(), Vec::new());
    let a_xs: Vec<f32> = (0..=40).map(|i| i as f32).collect();
    add_cells(
        &mut pos,
        &mut tris,
        [&a_xs, &[0.0, 4.0], &[0.0, 1.0, 5.0]],
        |c| c[2] == 0 || c[0] % 2 == 0,
    );
    let mut b_xs = vec![-0.5];
    for k in 0..20 {
        b_xs.extend([2.0 * k as f32 + 1.25, 2.0 * k as f32 + 1.75]);
    }
    b_xs.push(40.5);
    add_cells(
        &mut pos,
        &mut tris,
        [&b_xs, &[0.5, 3.5], &[-0.5, 0.5, 5.5]],
        |c| c[2] == 0 || c[0] % 2 == 1,
    );
    let mut obj = String::new();
    for p in &pos {
        obj += &format!("v {} {} {}\n", p[0] / 40.0, p[1] / 40.0, p[2] / 40.0);
    }
    for t in &tris {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let teeth = (0..20)
        .flat_map(|k| {
            let x = 2.0 * k as f32;
            [(x, x + 1.0), (x + 1.25, x + 1.75)]
        })
        .collect();
    (obj, teeth)
}

/// The combs of [`combs_obj`] (written into `dir`) as the mesh of [`lit_mesh_scene`] (σ_t
/// 4, 12, 40) with `boundary` as the [boundary] table's body and the sky of
/// [`overlapping_parts_scenes`]; returns the scene and the teeth.
pub fn combs_scene(dir: &Path, boundary: &str) -> (String, Vec<(f32, f32)>) {
    let (obj, teeth) = combs_obj();
    let path = dir.join("combs.obj");
    std::fs::write(&path, obj).unwrap();
    let tables = format!("[boundary]\n{boundary}\n[environment]\nradiance = [0.1, 0.2, 0.3]\n");
    (lit_mesh_scene(&path, &tables), teeth)
}

/// A ray through the teeth of [`combs_obj`] (in the OBJ's units): from `p` along `d`.
pub struct CombRay {
    pub p: glam::Vec3,
    pub d: glam::Vec3,
    /// Whether `p` is in a tooth (the medium).
    pub inside: bool,
    /// The teeth's faces ahead.
    pub faces: usize,
    /// The length in the teeth ahead.
    pub length: f64,
}

impl CombRay {
    /// The closed form of the shadow ray's transmittance from inside: e^(−σ·length) times,
    /// with a dielectric boundary, 1 − F(|d_x|) at each face crossed.
    pub fn transmittance(&self, sigma: f64, ior: Option<f64>) -> f64 {
        let t_fresnel = ior.map_or(1.0, |n| {
            (1.0 - fresnel(f64::from(self.d.x.abs()), n)).powi(self.faces as i32)
        });
        (-sigma * self.length).exp() * t_fresnel
    }
}

/// `n` rays through the combs of [`combs_obj`] from random points of the teeth's band, 5e-3
/// (in [`combs_obj`]'s units, half a pitch) clear of the teeth's faces (the spawn offset is
/// ~8e-4 in those units), along
/// ±x tilted by ~1e-3 so that no ray runs in a face's plane (it stays in the band).
pub fn comb_rays(teeth: &[(f32, f32)], n: usize, seed: u64) -> Vec<CombRay> {
    let mut rng = scatter_sim::WalkRng::for_walk(seed, 0);
    let mut rays = Vec::new();
    while rays.len() < n {
        let x0 = -1.0 + 42.0 * rng.uniform() as f32;
        let (y, z) = (
            0.6 + 2.8 * rng.uniform() as f32,
            1.1 + 3.8 * rng.uniform() as f32,
        );
        let sign = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
        let clear = |e: f32| (x0 - e).abs() >= 5e-3;
        if !teeth.iter().all(|&(lo, hi)| clear(lo) && clear(hi)) {
            continue;
        }
        let d = glam::Vec3::new(sign, 1e-3, 7e-4).normalize();
        let ahead = |x: f32| (x - x0) * sign > 0.0;
        let run = |&(lo, hi): &(f32, f32)| {
            let (lo, hi) = if sign > 0.0 {
                (lo.max(x0), hi)
            } else {
                (lo, hi.min(x0))
            };
            f64::from((hi - lo).max(0.0))
        };
        rays.push(CombRay {
            p: glam::Vec3::new(x0, y, z) / 40.0,
            d,
            inside: teeth.iter().any(|&(lo, hi)| lo < x0 && x0 < hi),
            faces: teeth
                .iter()
                .map(|&(lo, hi)| ahead(lo) as usize + ahead(hi) as usize)
                .sum(),
            length: teeth.iter().map(run).sum::<f64>() / 40.0 / f64::from(d.x.abs()),
        });
    }
    rays
}

/// A closed cylinder as OBJ text (radius 0.5, height 1, centred): `segments` side quads
/// and two fan caps, long thin triangles (at 1,000 segments 0.003 wide for 1 long).
pub fn cylinder_obj(segments: u32) -> String {
    let mut text = String::from("v 0 -0.5 0\nv 0 0.5 0\n");
    for k in 0..segments {
        let a = std::f64::consts::TAU * k as f64 / segments as f64;
        let (x, z) = (0.5 * a.cos(), 0.5 * a.sin());
        text += &format!("v {x} -0.5 {z}\nv {x} 0.5 {z}\n");
    }
    for k in 0..segments {
        // OBJ indices from 1: the centres are 1 and 2, ring k's vertices 3 + 2k and 4 + 2k.
        let (b0, t0) = (3 + 2 * k, 4 + 2 * k);
        let (b1, t1) = (3 + 2 * ((k + 1) % segments), 4 + 2 * ((k + 1) % segments));
        text += &format!("f {b0} {t0} {t1}\nf {b0} {t1} {b1}\nf 1 {b0} {b1}\nf 2 {t1} {t0}\n");
    }
    text
}

/// The camera of [`cylinder_scene`] that sees the cylinder's side head-on through a 1°
/// field of view: every pixel on its long thin triangles.
pub const CYLINDER_SIDE_ON: &str = "origin = [3.0, 0.2, 0.1]\ntarget = [0.5, 0.0, 0.0]\n\
                                    up = [0.0, 1.0, 0.0]\nfov_deg = 1.0";

/// The 1,000-segment cylinder of [`cylinder_obj`] (written into `dir`) at σ_t = 2,000,
/// albedo 0.999, a sun at an angle and a dim sky, 64² pixels, seen from `camera` (the
/// `[camera]` table's origin, target, up and fov_deg lines): paths bounce hundreds of
/// times just under long thin triangles.
pub fn cylinder_scene(dir: &Path, camera: &str) -> String {
    let obj = dir.join("cylinder.obj");
    std::fs::write(&obj, cylinder_obj(1000)).unwrap();
    format!(
        "[camera]\n{camera}\nwidth = 64\nheight = 64\n[object]\nmesh = {:?}\n\
         [medium]\nsigma_t = [2000.0, 2000.0, 2000.0]\nalbedo = [0.999, 0.999, 0.999]\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.5, -0.5, -1.0]\n\
         irradiance = [3.0, 3.0, 3.0]\n[environment]\nradiance = [0.05, 0.05, 0.05]\n",
        obj.display().to_string()
    )
}

/// A sphere of radius 0.5 (eps 2e-5) at `sigma`, albedo 0.9, lit head-on by a delta sun
/// along the view, filling a 32² image: a half-space to the light at any density where
/// the diffusion length is far below the radius (integrators.rs,
/// the_image_does_not_darken_with_density; gpu/hard_geometry.rs at the density bound).
pub fn dense_sphere(sigma: f64) -> String {
    format!(
        "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 10.0\n\
         width = 32\nheight = 32\n[object]\nshape = \"sphere\"\n\
         [medium]\nsigma_t = [{sigma:?}, {sigma:?}, {sigma:?}]\nalbedo = [0.9, 0.9, 0.9]\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\n\
         irradiance = [1.0, 1.0, 1.0]\n"
    )
}

/// The mean of batch means and its standard error (from their spread, n − 1 degrees of
/// freedom): for quantities whose per-path values are heavy-tailed or not kept.
pub fn batch_mean_se(batches: &[f64]) -> (f64, f64) {
    let n = batches.len() as f64;
    let mean = batches.iter().sum::<f64>() / n;
    let var = batches.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Nodes and weights of the `n`-point Gauss–Legendre rule on [0, 1] (Newton's method on
/// the Legendre polynomial from the Chebyshev guesses; exact for polynomials of degree
/// 2n − 1).
pub fn gauss_legendre_01(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 0.0;
            for _ in 0..100 {
                // P_n(x) and P_n'(x) by the three-term recurrence.
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let k = k as f64;
                    (p0, p1) = (p1, ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k);
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-15 {
                    break;
                }
            }
            let w = 2.0 / ((1.0 - x * x) * dp * dp);
            (0.5 * (1.0 - x), 0.5 * w)
        })
        .collect()
}

/// Chandrasekhar's H-function of isotropic scattering with single-scattering albedo w
/// (0 < w < 1), solved from the form
/// 1/H(μ) = √(1−w) + (w/2) ∫₀¹ μ' H(μ') / (μ + μ') dμ'
/// (Radiative Transfer, ch. V), iterated to a fixed point at 64 Gauss–Legendre nodes. An
/// independent reference for the renderer's half-space tests: it shares no code with the
/// renderer or the simulator.
pub struct HFunction {
    w: f64,
    nodes: Vec<(f64, f64)>,
    at_nodes: Vec<f64>,
}

impl HFunction {
    pub fn new(w: f64) -> Self {
        let mut h = Self {
            w,
            nodes: gauss_legendre_01(64),
            at_nodes: vec![1.0; 64],
        };
        let mut change = f64::INFINITY;
        for _ in 0..10_000 {
            let next: Vec<f64> = h.nodes.iter().map(|&(x, _)| h.at(x)).collect();
            change = next
                .iter()
                .zip(&h.at_nodes)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            h.at_nodes = next;
            if change < 1e-13 {
                break;
            }
        }
        // (Near w = 1 it converges too slowly, which is why the tests' albedos stay at 0.99
        // and below; the closed form, `chandrasekhar_h_closed`, checks the result.)
        assert!(change < 1e-13, "H at w = {w} did not converge ({change})");
        h
    }

    /// H(μ), μ in [0, 1].
    pub fn at(&self, mu: f64) -> f64 {
        let i: f64 = self
            .nodes
            .iter()
            .zip(&self.at_nodes)
            .map(|(&(x, wt), &hx)| wt * x * hx / (mu + x))
            .sum();
        1.0 / ((1.0 - self.w).sqrt() + 0.5 * self.w * i)
    }

    /// The plane albedo of a semi-infinite, index-matched medium of this albedo for light
    /// arriving at cos θ = `mu`: r(μ) = 1 − H(μ)√(1−w) (Chandrasekhar). By reciprocity it is
    /// also the radiance leaving the medium towards `mu` under a uniform sky of radiance 1,
    /// which is what a camera looking at the medium sees.
    pub fn half_space_albedo(&self, mu: f64) -> f64 {
        1.0 - self.at(mu) * (1.0 - self.w).sqrt()
    }
}

/// Chandrasekhar's closed form of the same H (Radiative Transfer, ch. V):
/// ln H(μ) = −(μ/π) ∫₀^{π/2} ln(1 − w θ cot θ) / (cos²θ + μ² sin²θ) dθ,
/// by Gauss–Legendre with `n` nodes: an independent check on [`HFunction`]'s iteration.
pub fn chandrasekhar_h_closed(w: f64, mu: f64, n: usize) -> f64 {
    let half = std::f64::consts::FRAC_PI_2;
    let integral: f64 = gauss_legendre_01(n)
        .iter()
        .map(|&(x, weight)| {
            let t = half * x;
            let t_cot = if t < 1e-6 {
                1.0 - t * t / 3.0
            } else {
                t / t.tan()
            };
            let (s, c) = t.sin_cos();
            weight * half * (1.0 - w * t_cot).ln() / (c * c + mu * mu * s * s)
        })
        .sum();
    (-mu / std::f64::consts::PI * integral).exp()
}

/// The three albedos of [`half_space_scene`], one a channel.
pub const HALF_SPACE_ALBEDOS: [f64; 3] = [0.5, 0.9, 0.99];

/// A half-space as a renderer sees it: a cube of edge 2 and σ_t = 100 (200 mean free paths
/// a side) under a uniform sky of radiance 1, isotropic scattering, index-matched, no
/// lights; seen from 40 away through a 0.6° lens, at `view_deg` from the top face's normal
/// (at most 60°), so every pixel looks at the middle of the top face, at most 0.42 from its
/// centre. Light from the other faces has to cross ≥ 58 mean free paths of a medium whose
/// diffusion length is at most 5.8 of them (albedo 0.99: 1/√(3(1 − w))), so it arrives
/// damped by e^−10 or more: the cube is a half-space to far below the tests' noise.
pub fn half_space_scene(width: u32, view_deg: f64) -> String {
    assert!((0.0..=60.0).contains(&view_deg));
    let [a, b, c] = HALF_SPACE_ALBEDOS;
    let (sin, cos) = view_deg.to_radians().sin_cos();
    // Aimed at the top face's centre (aimed at the cube's, an oblique view would meet a
    // side face first).
    let (x, z) = (40.0 * sin, 1.0 + 40.0 * cos);
    format!(
        r#"
[camera]
origin = [{x}, 0.0, {z}]
target = [0.0, 0.0, 1.0]
up = [0.0, 1.0, 0.0]
fov_deg = 0.6
width = {width}
height = {width}
[object]
shape = "cube"
size = 2.0
[medium]
sigma_t = [100.0, 100.0, 100.0]
albedo = [{a}, {b}, {c}]
g = 0.0
[boundary]
kind = "index-matched"
[environment]
radiance = [1.0, 1.0, 1.0]
[render]
grid_resolution = 32
"#
    )
}

/// Chandrasekhar's r(μ) of each channel's albedo averaged over the pixel centres' view
/// directions of `camera` (looking down at a top face with normal +z): the reference a
/// render of [`half_space_scene`] converges to, to well below the tests' noise (each pixel
/// spans 0.01°, over which r(μ) is linear to far below the noise).
pub fn half_space_reference(camera: &render_gpu::camera::Camera) -> [f64; 3] {
    HALF_SPACE_ALBEDOS.map(|w| {
        let h = HFunction::new(w);
        let (width, height) = (camera.width, camera.height);
        let mut sum = 0.0;
        for y in 0..height {
            for x in 0..width {
                let d = camera.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
                sum += h.half_space_albedo(-d.z as f64);
            }
        }
        sum / (width * height) as f64
    })
}

/// A sphere of radius `radius` at the origin, seen along −z by parallel rays, lit by a
/// uniform sky of radiance 1 (no lights): the share of light it sends back along a ray
/// through (x, y), for one channel's σ_t, albedo and HG g, with an index-matched boundary
/// (`ior` None) or a smooth dielectric of index `ior`, and an optional sun disk. An analog
/// walk written for the tests from the physics alone, in f64, sharing no code with the
/// renderer or the simulator but the simulator's random numbers (flights Exp(σ_t), survival w an event, HG by the textbook
/// inverse CDF, Fresnel's unpolarised reflectance chosen by chance at each crossing, total
/// internal reflection, Snell's law on the way out): each walk returns the sky's radiance
/// where it leaves (1, plus the sun's where it leaves into its disk), 0 when absorbed.
pub struct SphereWalk {
    pub radius: f64,
    pub sigma_t: f64,
    pub albedo: f64,
    pub g: f64,
    pub ior: Option<f64>,
    /// A sun disk in the sky: the unit direction towards its centre, the cosine of its
    /// angular radius and its radiance.
    pub sun: Option<(glam::DVec3, f64, f64)>,
}

impl SphereWalk {
    /// Fresnel's unpolarised reflectance for light meeting the surface at cos θ = `c`
    /// (> 0) from index `n1` into `n2`; 1 past the critical angle.
    fn reflectance(c: f64, n1: f64, n2: f64) -> f64 {
        let s2 = (n1 / n2).powi(2) * (1.0 - c * c);
        if s2 >= 1.0 {
            return 1.0;
        }
        let ct = (1.0 - s2).sqrt();
        let rs = (n1 * c - n2 * ct) / (n1 * c + n2 * ct);
        let rp = (n1 * ct - n2 * c) / (n1 * ct + n2 * c);
        0.5 * (rs * rs + rp * rp)
    }

    /// `d` refracted through the surface of unit normal `n` (pointing to the side `d`
    /// comes from), cos θ = `c` > 0, from `n1` into `n2` (below the critical angle).
    fn refracted(d: glam::DVec3, n: glam::DVec3, c: f64, n1: f64, n2: f64) -> glam::DVec3 {
        let eta = n1 / n2;
        let ct = (1.0 - eta * eta * (1.0 - c * c)).sqrt();
        (d * eta + n * (eta * c - ct)).normalize()
    }

    /// A direction at angle θ from `d` with cos θ drawn from HG(g), about a random azimuth.
    fn scatter(&self, d: glam::DVec3, rng: &mut scatter_sim::WalkRng) -> glam::DVec3 {
        let (u, v) = (rng.uniform(), rng.uniform());
        let g = self.g;
        let cos = if g.abs() < 1e-6 {
            1.0 - 2.0 * u
        } else {
            let f = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
            ((1.0 + g * g - f * f) / (2.0 * g)).clamp(-1.0, 1.0)
        };
        let sin = (1.0 - cos * cos).max(0.0).sqrt();
        let phi = 2.0 * std::f64::consts::PI * v;
        // Any unit vector not along d, made perpendicular to it.
        let a = if d.x.abs() < 0.6 {
            glam::DVec3::X
        } else {
            glam::DVec3::Y
        };
        let t1 = (a - d * a.dot(d)).normalize();
        let t2 = d.cross(t1);
        (d * cos + (t1 * phi.cos() + t2 * phi.sin()) * sin).normalize()
    }

    /// The sky's radiance towards unit `d`.
    fn sky(&self, d: glam::DVec3) -> f64 {
        match self.sun {
            Some((to_sun, cos_max, radiance)) if d.dot(to_sun) >= cos_max => 1.0 + radiance,
            _ => 1.0,
        }
    }

    /// One walk of the light arriving along −z at (x, y), x² + y² < radius²: the sky's
    /// radiance where it leaves, 0 if absorbed.
    pub fn walk(&self, x: f64, y: f64, rng: &mut scatter_sim::WalkRng) -> f64 {
        let r = self.radius;
        let mut p = glam::DVec3::new(x, y, (r * r - x * x - y * y).max(0.0).sqrt());
        let mut d = glam::DVec3::NEG_Z;
        if let Some(n) = self.ior {
            let normal = p / r;
            let c = -d.dot(normal);
            if rng.uniform() < Self::reflectance(c, 1.0, n) {
                return self.sky(d + normal * (2.0 * c));
            }
            d = Self::refracted(d, normal, c, 1.0, n);
        }
        loop {
            let flight = -(1.0 - rng.uniform()).ln() / self.sigma_t;
            // Where the ray from p along d leaves the sphere (p is inside or on it).
            let b = p.dot(d);
            let exit = -b + (b * b - (p.length_squared() - r * r)).max(0.0).sqrt();
            if flight < exit {
                p += d * flight;
                if rng.uniform() >= self.albedo {
                    return 0.0;
                }
                d = self.scatter(d, rng);
                continue;
            }
            p += d * exit;
            let Some(n) = self.ior else {
                return self.sky(d);
            };
            let normal = p.normalize();
            let c = d.dot(normal);
            if rng.uniform() >= Self::reflectance(c, n, 1.0) {
                return self.sky(Self::refracted(d, -normal, c, n, 1.0));
            }
            d = (d - normal * (2.0 * c)).normalize();
            // Back onto the sphere, as the walk's next flight starts from it.
            p = normal * r;
        }
    }
}

/// The sphere of [`sphere_walk_scene`]: per channel σ_t, albedo; HG g; the radius.
pub const SPHERE_WALK_SIGMA_T: [f64; 3] = [3.0, 10.0, 30.0];
pub const SPHERE_WALK_ALBEDO: [f64; 3] = [0.9, 0.99, 0.95];
pub const SPHERE_WALK_G: f64 = 0.6;
pub const SPHERE_WALK_RADIUS: f64 = 0.5;
/// Half the width the camera of [`sphere_walk_scene`] sees at the sphere's centre.
pub const SPHERE_WALK_HALF_VIEW: f64 = 0.6;
/// The sun of [`sphere_walk_scene`]: the direction its light travels, its irradiance and
/// its disk's angular diameter in degrees (wide, so the reference's analog walks find it).
pub const SPHERE_WALK_SUN: ([f64; 3], f64, f64) = ([0.3, -1.0, -0.2], 1.0, 40.0);

/// The sun of [`sphere_walk_scene`] as [`SphereWalk`] takes it: the disk's radiance from
/// its irradiance as a light's definition gives it, E = L·π sin²θ (a uniform disk of
/// angular radius θ seen face on).
pub fn sphere_walk_sun() -> (glam::DVec3, f64, f64) {
    let (dir, irradiance, diameter) = SPHERE_WALK_SUN;
    let half = (diameter / 2.0).to_radians();
    let to_sun = -glam::DVec3::from_array(dir).normalize();
    (
        to_sun,
        half.cos(),
        irradiance / (std::f64::consts::PI * half.sin().powi(2)),
    )
}

/// The sphere of [`SphereWalk`] as a scene: optical radii 1.5, 5 and 15, lit by a sky of
/// radiance 1 and [`SPHERE_WALK_SUN`], and seen from 10⁴ away, so that the camera's rays are parallel within
/// 6·10⁻⁵ rad and the view is ±0.6 wide at the centre; `boundary` is the [boundary]
/// table's body.
pub fn sphere_walk_scene(width: u32, boundary: &str) -> String {
    let [s0, s1, s2] = SPHERE_WALK_SIGMA_T;
    let [a0, a1, a2] = SPHERE_WALK_ALBEDO;
    let fov = 2.0 * (SPHERE_WALK_HALF_VIEW / 1e4).atan().to_degrees();
    let ([dx, dy, dz], irradiance, diameter) = SPHERE_WALK_SUN;
    format!(
        r#"
[camera]
origin = [0.0, 0.0, 10000.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_deg = {fov}
width = {width}
height = {width}
[object]
shape = "sphere"
radius = {SPHERE_WALK_RADIUS}
[medium]
sigma_t = [{s0}, {s1}, {s2}]
albedo = [{a0}, {a1}, {a2}]
g = {SPHERE_WALK_G}
[boundary]
{boundary}
[[light]]
kind = "directional"
direction = [{dx}, {dy}, {dz}]
irradiance = [{irradiance}, {irradiance}, {irradiance}]
angular_diameter_deg = {diameter}
[environment]
radiance = [1.0, 1.0, 1.0]
[render]
grid_resolution = 32
"#
    )
}

/// The pixels of a `width`² [`sphere_walk_scene`] wholly on the sphere (their four corners
/// inside its outline), as their lower-left corners in the plane of the sphere's centre,
/// and the pixels' edge length there.
pub fn sphere_walk_pixels(width: u32) -> (Vec<(usize, f64, f64)>, f64) {
    let edge = 2.0 * SPHERE_WALK_HALF_VIEW / width as f64;
    let r2 = SPHERE_WALK_RADIUS * SPHERE_WALK_RADIUS;
    let mut inside = Vec::new();
    for j in 0..width as usize {
        for i in 0..width as usize {
            let (x, y) = (
                -SPHERE_WALK_HALF_VIEW + edge * i as f64,
                -SPHERE_WALK_HALF_VIEW + edge * j as f64,
            );
            let far = |a: f64| a.abs().max((a + edge).abs());
            if far(x).powi(2) + far(y).powi(2) < r2 {
                // Image rows run downwards, y upwards: the set is symmetric, but the
                // index names the image's pixel.
                let row = width as usize - 1 - j;
                inside.push((row * width as usize + i, x, y));
            }
        }
    }
    (inside, edge)
}

/// The image indices of `sphere_walk_pixels(width)`.
pub fn sphere_walk_indices(width: u32) -> Vec<usize> {
    sphere_walk_pixels(width).0.iter().map(|p| p.0).collect()
}

/// Per channel, the mean of [`SphereWalk`] over `n` walks through uniformly random points
/// of the pixels `sphere_walk_pixels(width)` lists, and its standard error.
pub fn sphere_walk_reference(width: u32, ior: Option<f64>, n: u64) -> ([f64; 3], [f64; 3]) {
    use rayon::prelude::*;
    let (pixels, edge) = sphere_walk_pixels(width);
    let mut mean = [0.0; 3];
    let mut sem = [0.0; 3];
    for c in 0..3 {
        let walk = SphereWalk {
            radius: SPHERE_WALK_RADIUS,
            sigma_t: SPHERE_WALK_SIGMA_T[c],
            albedo: SPHERE_WALK_ALBEDO[c],
            g: SPHERE_WALK_G,
            ior,
            sun: Some(sphere_walk_sun()),
        };
        let (sum, sq) = (0..n)
            .into_par_iter()
            .map(|k| {
                let mut rng = scatter_sim::WalkRng::for_walk(9_000 + c as u64, k);
                let p = pixels[(rng.uniform() * pixels.len() as f64) as usize % pixels.len()];
                let (x, y) = (p.1 + edge * rng.uniform(), p.2 + edge * rng.uniform());
                let v = walk.walk(x, y, &mut rng);
                (v, v * v)
            })
            .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        let m = sum / n as f64;
        mean[c] = m;
        sem[c] = ((sq / n as f64 - m * m).max(0.0) / (n as f64 - 1.0)).sqrt();
    }
    (mean, sem)
}

/// Per channel, the mean over the pixels `indices` of two independent renders `a` and `b`
/// of one scene, and its standard error from their per-pixel differences: E(a_i − b_i)² is
/// twice a pixel's variance, so Σ(a_i − b_i)²/(4N²) estimates the variance of the mean
/// (with N − 1 degrees of freedom). The pixels' spread around their mean would count the
/// image's own contrast as noise: on the sun-lit sphere it gave 1.1–2.3× the standard
/// error this measures (a review's check against per-pixel variances).
pub fn split_mean_and_sem(
    a: &render_gpu::image_io::RgbImage,
    b: &render_gpu::image_io::RgbImage,
    indices: &[usize],
) -> ([f64; 3], [f64; 3]) {
    let n = indices.len() as f64;
    let mut mean = [0.0; 3];
    let mut sem = [0.0; 3];
    for c in 0..3 {
        let (mut sum, mut sq) = (0.0, 0.0);
        for &i in indices {
            let (x, y) = (a.pixels[i][c] as f64, b.pixels[i][c] as f64);
            sum += 0.5 * (x + y);
            sq += (x - y).powi(2);
        }
        mean[c] = sum / n;
        sem[c] = (sq / 4.0).sqrt() / n;
    }
    (mean, sem)
}

/// A render of a reference scene with given settings and seed (CPU or GPU).
pub type RenderWith<'a> = dyn Fn(
        &render_gpu::setup::SceneData,
        &render_gpu::integrator::IntegratorSettings,
        u64,
    ) -> render_gpu::render::RenderOutput
    + 'a;

/// What a reference scene's renders are held to: the pixels compared, the reference's
/// value and standard error per channel (0 for a closed form), and the sphere steps a path
/// ST-CVAE must take there.
pub struct Reference<'a> {
    pub indices: &'a [usize],
    pub value: ([f64; 3], [f64; 3]),
    pub steps_per_path: f64,
}

/// Renders `s` with `set` twice (seeds `seed` and `seed` + 1, for [`split_mean_and_sem`])
/// and checks the renders against `reference`: no path lost in either; for ST-CVAE, more
/// than `steps_per_path` sphere steps a path, exact or drawn from the models as `set` says,
/// so they carry the image; and each channel's mean over the pixels within 4.5 standard
/// errors of the difference plus `allowance` (a share of the reference).
pub fn check_against_reference(
    label: &str,
    s: &render_gpu::setup::SceneData,
    set: &render_gpu::integrator::IntegratorSettings,
    allowance: f64,
    seed: u64,
    reference: &Reference,
    render: &RenderWith,
) {
    let (a, b) = (render(s, set, seed), render(s, set, seed + 1));
    let (mean, sem) = split_mean_and_sem(&a.image, &b.image, reference.indices);
    let (rm, rs) = reference.value;
    for out in [&a, &b] {
        let st = out.stats;
        assert_eq!(st.capped + st.non_finite + st.leaks, 0, "{label}: {st:?}");
        if set.kind == render_gpu::integrator::IntegratorKind::Stcvae {
            // A case with exact steps is held to the reference without the models'
            // allowance, so none of its steps may be a model's draw.
            if set.exact_tau > 0.0 {
                assert_eq!(st.steps, st.exact_steps, "{label}: steps beyond exact_tau");
            }
            let stepped = if set.exact_tau > 0.0 {
                st.exact_steps
            } else {
                st.steps - st.exact_steps
            };
            assert!(
                stepped as f64 > reference.steps_per_path * st.paths as f64,
                "{label}: {st:?}"
            );
        }
    }
    for c in 0..3 {
        let se = (sem[c].powi(2) + rs[c].powi(2)).sqrt();
        let z = (mean[c] - rm[c]) / se;
        eprintln!(
            "{label}, channel {c}: {:.5} ± {:.5} against {:.5} ± {:.5} ({:+.2} %, z = {z:+.2})",
            mean[c],
            sem[c],
            rm[c],
            rs[c],
            100.0 * (mean[c] / rm[c] - 1.0)
        );
        assert!(
            (mean[c] - rm[c]).abs() < 4.5 * se + allowance * rm[c],
            "{label}, channel {c}: {} ± {} against the reference's {} ± {}",
            mean[c],
            sem[c],
            rm[c],
            rs[c]
        );
    }
}

/// One setting of a reference test: its label, the integrator's settings and the allowance
/// beyond the noise (a share of the reference).
pub type ReferenceCase<'a> = (&'a str, render_gpu::integrator::IntegratorSettings<'a>, f64);

/// Renders the sphere of [`sphere_walk_scene`] (64²) with each case, index-matched (`matched`) and as a
/// dielectric of index 1.5 (`dielectric`), and checks each against 2·10⁶ reference walks a
/// channel ([`check_against_reference`]).
pub fn check_sphere_walk_cases(
    device: &str,
    matched: &[ReferenceCase],
    dielectric: &[ReferenceCase],
    seed: u64,
    render: &RenderWith,
) {
    let on_sphere = sphere_walk_indices(64);
    for (name, boundary, ior, cases) in [
        ("index-matched", "kind = \"index-matched\"", None, matched),
        (
            "dielectric",
            "kind = \"dielectric\"\nior = 1.5",
            Some(1.5),
            dielectric,
        ),
    ] {
        let s = build_scene(&sphere_walk_scene(64, boundary), true);
        let reference = Reference {
            indices: &on_sphere,
            value: sphere_walk_reference(64, ior, 2_000_000),
            steps_per_path: 0.5,
        };
        for (label, set, allowance) in cases {
            let label = format!("{device}{label}, {name}");
            check_against_reference(&label, &s, set, *allowance, seed, &reference, &render);
        }
    }
}

/// Renders the half-space of [`half_space_scene`] (`width`², seen at 0° and 60°) with each
/// case and checks each
/// against Chandrasekhar's albedo ([`half_space_reference`], [`check_against_reference`]).
pub fn check_half_space_cases(
    device: &str,
    width: u32,
    cases: &[ReferenceCase],
    seed: u64,
    render: &RenderWith,
) {
    let all: Vec<usize> = (0..(width * width) as usize).collect();
    for view_deg in [0.0, 60.0] {
        let s = build_scene(&half_space_scene(width, view_deg), true);
        let reference = Reference {
            indices: &all,
            value: (half_space_reference(&s.camera), [0.0; 3]),
            steps_per_path: 1.0,
        };
        for (label, set, allowance) in cases {
            let label = format!("{device}{label}, seen at {view_deg}°");
            check_against_reference(&label, &s, set, *allowance, seed, &reference, &render);
        }
    }
}
