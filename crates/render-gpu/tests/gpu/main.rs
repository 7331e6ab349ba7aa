//! The wgpu renderer on Vulkan (Mesa's lavapipe in CI): WGSL building blocks equal the
//! Rust ones, the white furnace holds, every pixel is written and finite, and CPU and GPU
//! converge to the same image. Without a Vulkan adapter these tests print why and pass,
//! except under CI (CI=true), where a missing adapter is a failure.

mod agreement;
mod bands_and_stops;
#[path = "../common/mod.rs"]
mod common;
mod dispatches;
mod hard_geometry;
mod wgsl_blocks;

use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, OnceLock};

use glam::DVec3;
use render_gpu::RenderError;
use render_gpu::gpu::kernels::StackMemory;
use render_gpu::gpu::probe::{Item, run_probe};
use render_gpu::gpu::{AdapterChoice, GpuContext, render_gpu};
use render_gpu::integrator::{IntegratorKind, IntegratorSettings};
use render_gpu::render::{RenderOptions, RenderOutput, render};
use render_gpu::setup::SceneData;
use scatter_sim::WalkRng;
use scatter_sim::frame::{CanonicalExit, WalkFrame, from_canonical};
use scatter_sim::phase::{hg_pdf, hg_sample_cos, orthonormal_basis};

/// One device for all tests of this file; tests share it one at a time (lavapipe uses
/// every core for one dispatch anyway). None, with the reason printed for each test that
/// asks, only where no Vulkan adapter exists and not under CI; an adapter that exists but
/// cannot be opened fails every test.
fn gpu() -> Option<&'static Mutex<GpuContext>> {
    static CTX: OnceLock<Result<Mutex<GpuContext>, String>> = OnceLock::new();
    let ctx = CTX.get_or_init(|| {
        match GpuContext::with_backends(AdapterChoice::Any, Some(wgpu::Backends::VULKAN)) {
            Ok(c) => {
                eprintln!("GPU tests on {}", c.adapter);
                Ok(Mutex::new(c))
            }
            Err(RenderError::NoAdapter(e)) => {
                assert!(
                    std::env::var_os("CI").is_none(),
                    "CI must have a Vulkan adapter (mesa-vulkan-drivers): {e}"
                );
                Err(e)
            }
            Err(e) => panic!("a Vulkan adapter exists but cannot be used: {e}"),
        }
    });
    match ctx {
        Ok(c) => Some(c),
        Err(reason) => {
            let test = std::thread::current()
                .name()
                .unwrap_or("a GPU test")
                .to_owned();
            common::skip(&format!("{test}: {reason}"));
            None
        }
    }
}

fn model() -> &'static cvae::ModelSet {
    static M: OnceLock<cvae::ModelSet> = OnceLock::new();
    M.get_or_init(common::load_model)
}

fn settings(kind: IntegratorKind, nee: bool) -> IntegratorSettings<'static> {
    let m = (kind == IntegratorKind::Stcvae).then(model);
    IntegratorSettings {
        kind,
        nee,
        model: m,
        min_tau: 1.0,
        max_tau: m.map_or(300.0, |m| m.training.tau_range[1] as f32),
        exact_tau: 0.0,
        nee_samples: 2,
        exact_nee_samples: 1,
        path_nee_rays: 1,
    }
}

fn opts(spp: u32, seed: u64) -> RenderOptions {
    RenderOptions {
        spp,
        seed,
        time_budget: None,
        variance: false,
    }
}

/// Environment variables set until this is dropped, and removed then even where a test
/// panics: the tests after it take the context's lock past the poisoning, and would read
/// them.
struct EnvVars<'a>(&'a [(&'a str, &'a str)]);

impl<'a> EnvVars<'a> {
    /// The caller holds the context's lock, as every render of this binary does, so no
    /// render reads the variables while they change.
    fn set(vars: &'a [(&'a str, &'a str)]) -> Self {
        for (name, value) in vars {
            // SAFETY: as above; nothing else in this binary reads the environment meanwhile.
            unsafe { std::env::set_var(name, value) };
        }
        Self(vars)
    }
}

impl Drop for EnvVars<'_> {
    fn drop(&mut self) {
        for (name, _) in self.0 {
            // SAFETY: as in `EnvVars::set`.
            unsafe { std::env::remove_var(name) };
        }
    }
}

/// The context with its limits (and largest subgroup) to be lowered or pretended, restored
/// when this is dropped, even where a test panics: the tests after it take the context's
/// lock past the poisoning, and would render under the changed limits.
struct Limits<'a> {
    ctx: &'a mut GpuContext,
    // Named apart from the context's own fields: `guard.limits` must reach the context's
    // (through DerefMut), not the copy kept for the restore.
    saved_limits: wgpu::Limits,
    saved_subgroup_max_size: u32,
}

impl<'a> Limits<'a> {
    fn new(ctx: &'a mut GpuContext) -> Self {
        Self {
            saved_limits: ctx.limits.clone(),
            saved_subgroup_max_size: ctx.subgroup_max_size,
            ctx,
        }
    }
}

impl Deref for Limits<'_> {
    type Target = GpuContext;
    fn deref(&self) -> &GpuContext {
        self.ctx
    }
}

impl DerefMut for Limits<'_> {
    fn deref_mut(&mut self) -> &mut GpuContext {
        self.ctx
    }
}

impl Drop for Limits<'_> {
    fn drop(&mut self) {
        self.ctx.limits = self.saved_limits.clone();
        self.ctx.subgroup_max_size = self.saved_subgroup_max_size;
    }
}

/// `render_gpu` with the environment variables `vars` set for this render only.
fn render_gpu_with_env(
    ctx: &GpuContext,
    s: &SceneData,
    set: &IntegratorSettings,
    o: &RenderOptions,
    vars: &[(&str, &str)],
) -> Result<RenderOutput, RenderError> {
    let _env = EnvVars::set(vars);
    render_gpu(ctx, s, set, o, &|_, _| {}, &AtomicBool::new(false))
}

/// Two renders that must have taken the same paths: equal counters, equal pixels.
fn assert_same_render(base: &RenderOutput, out: &RenderOutput, what: &str) {
    assert_eq!(
        (out.stats.paths, out.stats.events),
        (base.stats.paths, base.stats.events),
        "{what}: other paths"
    );
    let differ = differing_pixels(base, out);
    assert_eq!(differ, 0, "{what}: {differ} pixels differ");
}

/// Pixels whose values differ at all between two renders of one size.
fn differing_pixels(a: &RenderOutput, b: &RenderOutput) -> usize {
    assert_eq!(a.image.pixels.len(), b.image.pixels.len());
    let pairs = a.image.pixels.iter().zip(&b.image.pixels);
    pairs.filter(|(p, q)| p != q).count()
}

/// The largest difference between two images' channels relative to the larger of the two
/// values (0 where both are equal, infinite where either is NaN and they differ): how far
/// apart two renders that should agree are.
fn largest_relative_difference(a: &RenderOutput, b: &RenderOutput) -> f32 {
    let channels = a
        .image
        .pixels
        .iter()
        .flatten()
        .zip(b.image.pixels.iter().flatten());
    channels
        .map(|(&x, &y)| {
            let relative = (x - y).abs() / x.abs().max(y.abs());
            if x == y {
                0.0
            } else if relative.is_nan() {
                f32::INFINITY
            } else {
                relative
            }
        })
        .fold(0.0, f32::max)
}

fn on_gpu(
    ctx: &GpuContext,
    s: &SceneData,
    set: &IntegratorSettings,
    o: &RenderOptions,
) -> RenderOutput {
    render_gpu(ctx, s, set, o, &|_, _| {}, &AtomicBool::new(false)).unwrap()
}

fn on_cpu(s: &SceneData, set: &IntegratorSettings, o: &RenderOptions) -> RenderOutput {
    render(s, set, o, &|_, _| {}, &AtomicBool::new(false))
}

/// Per-channel block means over K renders with different seeds: (mean, variance of the
/// mean, q) with the variance from the spread of the K renders (K − 1 degrees of freedom
/// per pixel) and q = Σ (its pixels' terms)²/(K − 1), so that Welch–Satterthwaite gives
/// the degrees of freedom of a sum of such variances as (Σ v)²/Σ q.
fn blocks(r: &[RenderOutput], size: usize) -> Vec<(f64, f64, f64)> {
    let w = r[0].image.width;
    let h = r[0].image.height;
    let k = r.len() as f64;
    let mut out = Vec::new();
    for by in (0..h).step_by(size) {
        for bx in (0..w).step_by(size) {
            for c in 0..3 {
                let (mut m, mut v, mut q, mut n) = (0.0, 0.0, 0.0, 0.0);
                for y in by..(by + size).min(h) {
                    for x in bx..(bx + size).min(w) {
                        let vals: Vec<f64> = r
                            .iter()
                            .map(|o| o.image.pixels[y * w + x][c] as f64)
                            .collect();
                        let mean = vals.iter().sum::<f64>() / k;
                        let var =
                            vals.iter().map(|q| (q - mean) * (q - mean)).sum::<f64>() / (k - 1.0);
                        m += mean;
                        v += var / k;
                        q += (var / k) * (var / k) / (k - 1.0);
                        n += 1.0;
                    }
                }
                out.push((m / n, v / (n * n), q / (n * n * n * n)));
            }
        }
    }
    out
}

/// Fewest Welch degrees of freedom of a block's noise estimate for its z to count. A block
/// at the silhouette whose noise comes from one pixel has 2·(K − 1) = 6: its z is t₆,
/// beyond 6.5 with probability 6e-4, and its z² has mean ν/(ν − 2) = 1.5 and variance
/// 2ν²(ν − 1)/((ν − 2)²(ν − 4)) = 11.25. At ν ≥ 20, P(|t| > 6.5) < 3e-6 and z² has mean
/// ≤ 1.11 and variance ≤ 2.93.
const MIN_BLOCK_DOF: f64 = 20.0;

/// CPU and GPU converge to the same image: block-mean differences divided by their
/// estimated noise are z-scores, each a t-variable with the block's Welch degrees of
/// freedom ν (up to 16 pixels × 3 per device); blocks with ν < MIN_BLOCK_DOF are left
/// out. Under noise alone E z² ≤ 1.11 and the mean of z² over k blocks has sd ≤ √(2.93/k)
/// (more with the heavy tails of paths that find the sun disk). A wrong estimator (a
/// missed Fresnel factor, a lost NEE term, a wrong Λ(N)) shifts whole regions by many σ;
/// the thresholds (mean z² < 1.5 + 4√(2/k): (0.39 + 4√(2/k))/√(2.93/k) ≥ 4.5 sd above the
/// null for k ≥ 30, ≥ 5 sd for k ≥ 56, and max
/// |z| < 6.5) fail it while noise alone passes with a wide margin.
///
/// Across the file (counted 2026-12-07): 44 render comparisons at 24² or 32² (at most 64
/// blocks × 3 channels each) and three work maps at 48² (144 blocks, channel 0 only), at
/// most ~8,900 block z's in all. At the floor ν = 20 each passes 6.5 with probability
/// 2.5e-6 (≈ 2 % over the file if every block sat there); most blocks have ν near 90
/// (16 pixels × 3 per device), where it is 4e-9. The seeds are fixed, so that is the chance that a reseed or a change that only
/// redraws the random numbers trips it, not a flaky run.
///
/// Those two see a difference's size, not its sign, so a small bias of the same sign in
/// every block (δ block-σ) raises mean z² only by δ² and passes them up to δ ≈ 1.0–1.2.
/// The signed sum catches it: the blocks are disjoint and a path adds to one channel, so
/// the z are independent (nearly: on the CPU a pixel's three channels share their jitters,
/// which correlates them where the image changes within a pixel, at silhouettes); CPU and GPU run the same estimator, so each z is symmetric
/// about 0 (swapping the devices flips its sign). S = Σz / √(k·s²), with s² the z's
/// spread about their mean floored at the t-variance bound 1.11, is then about N(0, 1)
/// for k ≥ 30, and |S| < 4.5 is a false alarm with probability ~7·10⁻⁶; a shift δ makes
/// S ≈ δ√k/1.05, failing from δ ≈ 0.86 at k = 30 and δ ≈ 0.45 at k = 108. Measured on
/// lavapipe (2026-11-28): S from −0.81 to 1.40 over the 18 comparisons the file made then.
fn assert_same_image(name: &str, cpu: &[RenderOutput], gpu: &[RenderOutput]) {
    let a = blocks(cpu, 4);
    let b = blocks(gpu, 4);
    let mut z2 = 0.0;
    let mut zsum = 0.0;
    let mut k = 0.0;
    let mut zmax: f64 = 0.0;
    for (&(ma, va, qa), &(mb, vb, qb)) in a.iter().zip(&b) {
        // Background blocks are noiseless up to rounding (the GPU sums in f32, the CPU in
        // f64): a relative 1e-5 floor on the deviation keeps rounding from counting as noise.
        let v = va + vb;
        let floor = 1e-5 * ma.abs().max(mb.abs());
        if v <= floor * floor {
            assert!(
                (ma - mb).abs() < 1e-5,
                "{name}: noiseless block differs: {ma} vs {mb}"
            );
            continue;
        }
        if v * v / (qa + qb) < MIN_BLOCK_DOF {
            continue;
        }
        let z = (ma - mb) / v.sqrt();
        z2 += z * z;
        zsum += z;
        zmax = zmax.max(z.abs());
        k += 1.0;
    }
    assert!(
        k >= 30.0,
        "{name}: only {k} blocks with enough noise estimate"
    );
    let mean_z2 = z2 / k;
    let spread = ((z2 - zsum * zsum / k) / (k - 1.0)).max(1.11);
    let signed = zsum / (k * spread).sqrt();
    let mean = |o: &[RenderOutput]| {
        let n = o[0].image.pixels.len() as f64 * o.len() as f64;
        [0, 1, 2].map(|c| {
            o.iter()
                .flat_map(|r| r.image.pixels.iter().map(move |p| p[c] as f64))
                .sum::<f64>()
                / n
        })
    };
    eprintln!(
        "{name}: {k} blocks, mean z² {mean_z2:.2}, max |z| {zmax:.2}, signed sum {signed:.2}; \
         image mean CPU {:?} GPU {:?}",
        mean(cpu),
        mean(gpu)
    );
    assert!(
        mean_z2 < 1.5 + 4.0 * (2.0 / k).sqrt() && zmax < 6.5 && signed.abs() < 4.5,
        "{name}: CPU and GPU images differ beyond noise (mean z² {mean_z2:.2}, max |z| \
         {zmax:.2}, signed sum {signed:.2})"
    );
    for o in gpu {
        assert_eq!(
            o.stats.capped + o.stats.non_finite,
            0,
            "{name}: {:?}",
            o.stats
        );
    }
}

fn sphere_scene(boundary: &str) -> String {
    format!(
        r#"
[camera]
origin = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
fov_deg = 22.0
width = 24
height = 24
[object]
shape = "sphere"
radius = 0.5
[medium]
sigma_t = [8.0, 15.0, 30.0]
albedo = [0.99, 0.95, 0.9]
g = 0.5
[boundary]
{boundary}
{SPHERE_SCENE_DISK}[environment]
radiance = [0.1, 0.1, 0.1]
[render]
grid_resolution = 64
"#
    )
}

/// `sphere_scene`'s one light (tests replace it in the text).
const SPHERE_SCENE_DISK: &str = "[[light]]\nkind = \"directional\"\n\
    direction = [-0.5, -0.6, -0.62]\nirradiance = [2.0, 2.0, 2.0]\nangular_diameter_deg = 40.0\n";

/// `text` (a `sphere_scene`) with another extinction and albedo.
fn with_medium(text: String, sigma_t: &str, albedo: &str) -> String {
    text.replace(
        "sigma_t = [8.0, 15.0, 30.0]",
        &format!("sigma_t = {sigma_t}"),
    )
    .replace("albedo = [0.99, 0.95, 0.9]", &format!("albedo = {albedo}"))
}

fn compare_devices(name: &str, text: &str, kind: IntegratorKind, nee: bool, spp: u32) {
    compare_devices_with(name, text, &settings(kind, nee), spp);
}

/// Returns the GPU renders (None where the tests are skipped).
fn compare_devices_with(
    name: &str,
    text: &str,
    set: &IntegratorSettings,
    spp: u32,
) -> Option<Vec<RenderOutput>> {
    let ctx = gpu()?;
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(text, set.kind == IntegratorKind::Stcvae);
    let set = *set;
    // `STCVAE_GPU_TEST_SPP` (undocumented, for looking closer by hand) may only raise the
    // spp each comparison was sized for: fewer samples would weaken it unseen.
    let spp = match std::env::var("STCVAE_GPU_TEST_SPP") {
        Ok(v) => {
            let more: u32 = v.parse().expect("STCVAE_GPU_TEST_SPP: a whole number");
            assert!(
                more >= spp,
                "STCVAE_GPU_TEST_SPP {more} is below {name}'s {spp}"
            );
            more
        }
        Err(_) => spp,
    };
    let cpu: Vec<_> = (1..=4)
        .map(|seed| on_cpu(&s, &set, &opts(spp, seed)))
        .collect();
    let gpu: Vec<_> = (5..=8)
        .map(|seed| on_gpu(&ctx, &s, &set, &opts(spp, seed)))
        .collect();
    for o in &gpu {
        assert_eq!(o.stats.paths, (o.image.pixels.len() as u64) * spp as u64);
    }
    assert_same_image(name, &cpu, &gpu);
    Some(gpu)
}

/// A 16×8 environment map with pixel (x, y) = `f(x, y)`, written as `sky.exr` in `d`.
fn sky(d: &tempfile::TempDir, f: impl Fn(usize, usize) -> [f32; 3]) -> std::path::PathBuf {
    use render_gpu::image_io::{RenderTag, RgbImage, write_exr};
    let mut map = RgbImage::new(16, 8);
    for (i, p) in map.pixels.iter_mut().enumerate() {
        *p = f(i % 16, i / 16);
    }
    let path = d.path().join("sky.exr");
    let tag = RenderTag {
        spp: 1,
        scene_hash: 0,
        seeds: Vec::new(),
        partial: false,
        unknown_digests: Vec::new(),
        view_hash: None,
    };
    write_exr(&path, &map, &tag).unwrap();
    path
}

/// `sphere_scene` under six lights instead of its one disk: delta lights and disks, one dark
/// in G, from every side (three travel toward the camera, lighting mostly the sphere's far
/// side).
fn six_lights_scene(boundary: &str) -> String {
    let lights: String = [
        ([-0.5, -0.6, -0.62], [0.6, 0.6, 0.6], 40.0),
        ([0.7, 0.2, -0.3], [0.5, 0.0, 0.3], 20.0),
        ([0.0, 0.0, -1.0], [0.3, 0.4, 0.5], 0.0),
        ([0.3, -0.9, 0.2], [0.4, 0.4, 0.2], 10.0),
        ([-0.8, 0.3, 0.4], [0.2, 0.3, 0.4], 0.0),
        ([0.1, 0.6, 0.7], [0.5, 0.5, 0.5], 30.0),
    ]
    .iter()
    .map(|(d, e, disk)| {
        format!(
            "[[light]]\nkind = \"directional\"\ndirection = {d:?}\nirradiance = {e:?}\n\
             angular_diameter_deg = {disk:?}\n"
        )
    })
    .collect();
    let disk = SPHERE_SCENE_DISK;
    let text = sphere_scene(boundary);
    assert!(text.contains(disk));
    text.replace(disk, &lights)
}

/// Eleven slabs stacked up a cube, each overlapping the next by half, lit from above: a
/// shadow ray toward the sun from low in the cube crosses up to 22 faces, beyond the 16
/// crossings the GPU sorts (scene.wgsl, union_keep), so its answers there come from the
/// walk past each crossing (and in_union's every-hit-flips fallback); the CPU's list
/// holds 64. The medium is thinner than the other scenes', so that the deep shadow rays
/// carry weight (with σ_t = 4 to 40 a halved answer beyond 16 crossings went unseen).
/// The OBJ is written into `dir`.
fn slabs_scene(dir: &std::path::Path, boundary: &str) -> String {
    let slabs: Vec<([f32; 3], [f32; 3])> = (0..11)
        .map(|k| {
            let y = -0.5 + k as f32 / 12.0;
            // (0.17 tall, not 2/12: a slab's top corners on the next but one's bottom
            // corners would weld into edges of four faces.)
            ([-0.5, y, -0.5], [0.5, y + 0.17, 0.5])
        })
        .collect();
    let obj = dir.join("slabs.obj");
    std::fs::write(&obj, common::boxes_obj(&slabs)).unwrap();
    common::overlapping_parts_scenes(dir, boundary)[0]
        .2
        .replace(
            &dir.join("cube2.obj").display().to_string(),
            &obj.display().to_string(),
        )
        .replace("sigma_t = [4.0, 12.0, 40.0]", "sigma_t = [1.0, 2.0, 3.0]")
}
