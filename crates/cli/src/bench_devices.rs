//! `stcvae bench devices`: the same renders on the GPU and on the CPU, side by side, and
//! their ratio (issue 5's figure: a software adapter against the CPU integrators, or a
//! hardware GPU's multiple of them).

use std::path::PathBuf;

use anyhow::{Result, bail};
use render_gpu::integrator::IntegratorKind;
use render_gpu::render::{RenderOptions, RenderOutput};

use crate::bench_render::{parse_k, reject_repeats};
use crate::device::{DeviceArg, Engine};
use crate::progress::si;
use crate::render::prepare;

#[derive(clap::Args)]
pub struct Args {
    /// Scene to render; its medium is scaled by each --k (σ_t × k), everything else kept.
    #[arg(long, default_value = crate::render::DEFAULT_SCENE,
          value_parser = crate::shipped::scene_arg(crate::render::DEFAULT_SCENE))]
    scene: PathBuf,
    /// Density multipliers of the scene's σ_t (each in [0.001, 1000]). PT's time grows with k;
    /// on a software adapter k = 8 takes minutes.
    #[arg(long, value_delimiter = ',', default_value = "1", value_parser = parse_k)]
    k: Vec<f64>,
    /// Samples per pixel of every render, 1 to 1,048,576.
    #[arg(long, allow_negative_numbers = true, default_value_t = 16,
          value_parser = crate::whole::whole::<u32>(1, 1 << 20))]
    spp: u32,
    /// Image side in pixels, 8 to 8,192. A large GPU needs ~256² or more to be full.
    #[arg(long, allow_negative_numbers = true, default_value_t = 128,
          value_parser = crate::whole::whole::<u32>(8, 8192))]
    size: u32,
    /// Model file for ST-CVAE (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    model: Option<PathBuf>,
    /// Random seed of every render.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1,
          value_parser = crate::render::parse_seed)]
    seed: u64,
}

/// One render with a progress bar (PT at k = 8 runs for minutes on a software adapter).
/// Ctrl-C stops it after its pass and the bench there: a cut-short render is never
/// compared.
fn render(
    engine: &Engine,
    p: &crate::render::Prepared,
    spp: u32,
    seed: u64,
    time_budget: Option<f64>,
) -> Result<RenderOutput> {
    let opts = RenderOptions {
        spp,
        seed,
        time_budget,
        variance: false,
    };
    let cam = &p.file.camera;
    let label = format!(
        "σ_t {:?}, {}, {}",
        p.file.medium.sigma_t,
        p.settings().kind.name(),
        if engine.is_gpu() { "GPU" } else { "CPU" }
    );
    let pb = crate::progress::render_bar(&label, cam.width as u64 * cam.height as u64, &opts);
    let out = engine.render(
        &p.data,
        &p.settings(),
        &opts,
        &|done, _| pb.set_position(done),
        crate::interrupt::flag(),
    );
    pb.finish_and_clear();
    if crate::interrupt::requested() {
        bail!("interrupted: the rows printed so far stand; nothing more was measured");
    }
    out
}

/// Seconds of untimed GPU work before each timed GPU render on a hardware adapter, which
/// has idled through the CPU render before it: on an H100 (2026-11-27) the bench without
/// it timed ST-CVAE at 512², 64 spp, at 0.57 s (29 M paths/s) where `stcvae render` of the
/// same scene, whose upload and compilation keep the GPU busy just before, took 0.40 s
/// (40–42 M). Software adapters are left alone (the adapter is the CPU, which the
/// CPU render just before kept busy).
pub(crate) const GPU_WARM_UP_SECONDS: f64 = 0.5;

/// The scene as density `k` renders it: σ_t × k at the bench's image `size`.
fn scaled(f: &mut render_gpu::scene::SceneFile, k: f64, size: u32) {
    f.medium.sigma_t = f.medium.sigma_t.map(|s| s * k);
    f.camera.width = size;
    f.camera.height = size;
}

/// Refuses an image size past memory, a scene the GPU cannot light, and a density whose
/// scaled scene is invalid, before anything is rendered.
fn check_scene(a: &Args) -> Result<()> {
    render_gpu::render::check_image_memory(a.size, a.size)
        .map_err(|e| anyhow::anyhow!("--size {}: {e}", a.size))?;
    let scene = render_gpu::scene::SceneFile::load(&a.scene)?;
    // The render's own refusal says "use --device cpu", which this bench does not take.
    crate::device::check_gpu_lights(
        &a.scene,
        scene.lights.len(),
        ", so the devices cannot be compared on this scene",
    )?;
    reject_repeats(&a.k)?;
    for &k in &a.k {
        let mut f = scene.clone();
        scaled(&mut f, k, a.size);
        if let Err(e) = f.validate() {
            bail!(
                "{e} (σ_t × {k}, set by --k, applied to {})",
                a.scene.display()
            );
        }
    }
    Ok(())
}

/// The model (ST-CVAE's rows come after PT's) and both engines, GPU and CPU.
fn open_engines(model: Option<&std::path::Path>) -> Result<(Engine, Engine)> {
    // The model too: ST-CVAE's rows come after PT's, minutes in on lavapipe.
    crate::model_cmds::load_model(model)?;
    // Both engines first, so that a missing adapter fails before any rendering; neither
    // may fall back to the other part way.
    // The adapter error's advice to use --device cpu is render's; this bench has no such
    // option, since a GPU is what it measures.
    let gpu = Engine::open(DeviceArg::Gpu)
        .map_err(|e| {
            let e = format!("{e:#}");
            anyhow::anyhow!(
                "bench devices needs a GPU adapter: {}",
                e.trim_end_matches(", or use --device cpu")
            )
        })?
        .without_fallback();
    let cpu = Engine::open(DeviceArg::Cpu)?;
    Ok((gpu, cpu))
}

pub fn run(a: Args) -> Result<()> {
    check_scene(&a)?;
    let (gpu, cpu) = open_engines(a.model.as_deref())?;
    // Every row's scene is built once before the first render, as `bench render` does:
    // the checks that need it (a density too deep for the object's surface offset, the
    // model's τ range, the distance grid) failed a later density after minutes of renders.
    // Built again when rendered (the grid from its disk cache) rather than kept: each holds
    // its own copy of the distance grid.
    let rows: Vec<(f64, IntegratorKind, &str)> =
        a.k.iter()
            .flat_map(|&k| {
                [
                    (k, IntegratorKind::Pt, "PT"),
                    (k, IntegratorKind::Stcvae, "ST-CVAE"),
                ]
            })
            .collect();
    let prepare_row = |k: f64, kind: IntegratorKind| {
        prepare(&a.scene, Some(kind), None, a.model.as_deref(), |f| {
            scaled(f, k, a.size)
        })
        .map_err(|e| anyhow::anyhow!("{e:#} (σ_t × {k}, set by --k)"))
    };
    for &(k, kind, _) in &rows {
        let p = prepare_row(k, kind)?;
        // A software adapter keeps its path state in host memory, as `render` checks.
        if !gpu.is_hardware_gpu() {
            crate::render::software_gpu_memory(a.size, a.size, &p.settings(), false, 0)
                .map_err(|e| anyhow::anyhow!("--size {}: {e}", a.size))?;
        }
    }
    // The banner and the table's head after every check: a refused --k or --size came
    // after the head, as if a row were to follow.
    println!(
        "stcvae bench devices: {} ({}x{}), σ_t × k, {} spp, seed {}\n  {}\n  {}",
        a.scene.display(),
        a.size,
        a.size,
        a.spp,
        a.seed,
        gpu.describe(),
        cpu.describe()
    );
    println!(
        "{:>6} {:>8} {:>8} {:>8} {:>12} {:>12} {:>8} {:>10}",
        "k", "", "CPU s", "GPU s", "CPU paths/s", "GPU paths/s", "GPU/CPU", "compile s"
    );
    for &(k, kind, name) in &rows {
        let p = &prepare_row(k, kind)?;
        let on_cpu = render(&cpu, p, a.spp, a.seed, None)?;
        // The warm-up compiles the kernel, so its compile time is the one to report.
        let warm_up = if gpu.is_hardware_gpu() {
            Some(render(&gpu, p, a.spp, a.seed, Some(GPU_WARM_UP_SECONDS))?)
        } else {
            None
        };
        let on_gpu = render(&gpu, p, a.spp, a.seed, None)?;
        let compile = warm_up.as_ref().unwrap_or(&on_gpu).compile_seconds;
        let (c, g) = (on_cpu.paths_per_second(), on_gpu.paths_per_second());
        println!(
            "{:>6} {:>8} {:>8} {:>8} {:>12} {:>12} {:>7.2}x {:>10.2}",
            k,
            name,
            crate::progress::significant4(on_cpu.seconds),
            crate::progress::significant4(on_gpu.seconds),
            si(c),
            si(g),
            g / c.max(1e-9),
            compile
        );
    }
    println!(
        "GPU/CPU: GPU paths/s over CPU paths/s, rendering time only (the kernel's compilation, \
         on a cold driver cache and only where no row before built the same kernel, is the \
         last column; on a hardware GPU \
         each timed render follows {GPU_WARM_UP_SECONDS} s of untimed work, which compiles it)"
    );
    Ok(())
}
