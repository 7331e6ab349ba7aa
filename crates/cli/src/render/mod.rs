//! `stcvae render`: a scene file to EXR + PNG + JSON.

mod args;
mod outputs;
mod prepare;
mod report;

use anyhow::{Result, anyhow, bail};
use render_gpu::image_io::RenderTag;
use render_gpu::integrator::IntegratorSettings;
use render_gpu::render::RenderOptions;
use render_gpu::scene::SceneFile;

use crate::device::Engine;
use crate::{interrupt, progress};

pub(crate) use args::parse_exposure;
pub use args::{Args, parse_seed};
pub(crate) use outputs::check_out_stem;
pub use outputs::scene_inputs;
use outputs::{check_outputs, render_inputs};
use prepare::prepared_notes;
pub use prepare::{Prepared, note_lights, prepare};
pub(crate) use prepare::{outside_training_warning, software_gpu_memory};
use report::{budget_overrun_note, print_lanes, print_summary, report};
pub(crate) use report::{leak_note, mean_rgb};

pub const DEFAULT_SCENE: &str = "configs/scenes/bunny.toml";

pub fn run(mut a: Args) -> Result<()> {
    if let Some(p) = a.scene_file.take() {
        a.scene = p;
    }
    check_out_stem(&a.out)?;
    let variance_bytes = if a.variance {
        render_gpu::render::VARIANCE_BYTES_PER_PIXEL
    } else {
        0
    };
    let size = requested_size(&a, variance_bytes)?;
    let p = prepare(&a.scene, a.integrator, a.nee, a.model.as_deref(), |f| {
        if let Some(s) = a.spp {
            f.render.spp = s;
        }
        if let Some(s) = a.seed {
            f.render.seed = s;
        }
        if let Some((w, h)) = size {
            f.camera.width = w;
            f.camera.height = h;
        }
    })?;
    let r = &p.file.render;
    // A budget alone renders until it is spent: the scene's spp (64 in bunny_sun.toml)
    // stopped "30 s of PT" after a few seconds.
    let spp_cap = (a.time_budget.is_none() || a.spp.is_some()).then_some(r.spp);
    check_variance_spp(&a, spp_cap)?;
    prepared_notes(&a, &p);
    let inputs = render_inputs(&a, &p);
    check_outputs(&a, &inputs)?;
    let engine = Engine::open(a.device)?;
    let set = p.settings();
    if engine.is_gpu() && !engine.is_hardware_gpu() {
        let (w, h) = (p.file.camera.width, p.file.camera.height);
        // (variance_bytes holds the CPU's f64 squares too, which the GPU keeps in its
        // slots instead: a little more than it needs.)
        software_gpu_memory(w, h, &set, a.variance, variance_bytes)
            .map_err(|e| size_error(&a, size.is_some(), w, h, e))?;
    }
    print_start(&a, &p, spp_cap, engine.is_gpu());
    let opts = RenderOptions {
        spp: spp_cap.unwrap_or(u32::MAX),
        seed: r.seed,
        time_budget: a.time_budget,
        variance: a.variance,
    };
    let out = render_with_progress(&a, &p, &engine, &set, &opts, spp_cap)?;
    if out.spp == 0 {
        bail!("interrupted before the first pass finished: nothing written");
    }
    // A stop that came after the last pass cut nothing short: the files are complete.
    let interrupted = interrupt::requested() && out.spp < opts.spp;
    let hash = p.data.hash;
    let tag = RenderTag {
        spp: out.spp as u64,
        scene_hash: hash,
        seeds: vec![r.seed],
        partial: false,
        unknown_digests: Vec::new(),
        view_hash: Some(p.data.view_hash),
    };
    let report = report(&a, &p, &set, &engine, &out, spp_cap, interrupted);
    if a.variance && out.variance.is_none() {
        eprintln!(
            "note: no variance image: {} spp is below the {} it needs (2 samples a channel)",
            out.spp,
            render_gpu::render::MIN_VARIANCE_SPP
        );
    }
    crate::merge::write_image_set_with(
        &a.out,
        &out.image,
        Some(&tag),
        a.exposure,
        Some(&serde_json::to_vec_pretty(&report)?),
        out.variance.as_ref(),
        &inputs,
    )?;
    if out.stats.capped > 0 || out.stats.non_finite > 0 {
        eprintln!(
            "warning: {} stopped by the iteration cap, {} replaced by 0",
            progress::count(out.stats.capped, "path"),
            progress::count(out.stats.non_finite, "non-finite estimate")
        );
    }
    leak_note(&out.stats, "");
    print_summary(&a, &out, &report);
    if let Some(lanes) = &out.dispatch.lanes {
        print_lanes(lanes);
    }
    if let Some(note) = budget_overrun_note(a.time_budget, &out, engine.is_gpu()) {
        eprintln!("{note}");
    }
    if interrupted {
        // Written, but cut short: exit 128 + the stop signal (130 for Ctrl-C) as
        // `generate` and `train` do, so that scripts can tell it from a complete render.
        bail!(
            "interrupted: the files hold the {} spp finished before the stop{}",
            out.spp,
            spp_cap.map_or(String::new(), |n| format!(" ({n} asked)"))
        );
    }
    Ok(())
}

/// The line that says what is about to be rendered, and where.
fn print_start(a: &Args, p: &Prepared, spp_cap: Option<u32>, gpu: bool) {
    eprintln!(
        "rendering {} ({}x{}, {}, {}{}) on the {}",
        a.scene.display(),
        p.file.camera.width,
        p.file.camera.height,
        match (spp_cap, a.time_budget) {
            (Some(n), None) => format!("{n} spp"),
            (Some(n), Some(b)) => format!("{} s, at most {n} spp", scatter_sim::ranges::num(b)),
            (None, Some(b)) => format!("{} s, no spp limit", scatter_sim::ranges::num(b)),
            (None, None) => unreachable!("an spp cap is lifted only by a time budget"),
        },
        p.file.render.integrator.name(),
        if p.file.render.nee { ", NEE" } else { "" },
        if gpu { "GPU" } else { "CPU" }
    );
}

/// Renders with a progress bar (of samples, or of time under a budget alone) and the
/// Ctrl-C handler; a scene beyond the GPU's limits is named in the error.
fn render_with_progress(
    a: &Args,
    p: &Prepared,
    engine: &Engine,
    set: &IntegratorSettings,
    opts: &RenderOptions,
    spp_cap: Option<u32>,
) -> Result<render_gpu::render::RenderOutput> {
    let pixels = p.file.camera.width as u64 * p.file.camera.height as u64;
    let pb = if spp_cap.is_some() {
        progress::bar(pixels * opts.spp as u64, "samples")
    } else {
        progress::render_bar("rendering", pixels, opts)
    };
    let cancel = interrupt::flag();
    let out = engine
        .render(&p.data, set, opts, &|done, _| pb.set_position(done), cancel)
        .map_err(|e| {
            // A scene beyond the GPU's limits (lights, mesh, image) is named: what to
            // change is in its file.
            match e.downcast_ref::<render_gpu::error::RenderError>() {
                Some(render_gpu::error::RenderError::SceneBeyondGpu(why)) => {
                    anyhow!("{}: {why}", a.scene.display())
                }
                _ => e,
            }
        })?;
    pb.finish_and_clear();
    Ok(out)
}

/// The image size `--width`/`--height` ask for (None: the camera's), with the image's
/// memory checked against it before `prepare` builds the mesh, BVH and distance grid.
fn requested_size(a: &Args, variance_bytes: u64) -> Result<Option<(u32, u32)>> {
    // (Building a large grid takes about a minute.) The camera's size is in the file
    // alone. A file that does not load is left to `prepare`, whose errors say why.
    // Unvalidated: `prepare` validates after the overrides (an ST-CVAE scene with max_tau
    // below min_tau renders with --integrator pt, and was not checked here).
    let mut size = None;
    if let Ok(f) = SceneFile::load_unvalidated(&a.scene) {
        f.check_overridable()
            .map_err(|e| anyhow::anyhow!("{}: {e}", a.scene.display()))?;
        size = image_size(&f.camera, a.width, a.height)
            .map_err(|e| anyhow::anyhow!("{}: {e}", a.scene.display()))?;
        let (w, h) = size.unwrap_or((f.camera.width, f.camera.height));
        render_gpu::render::check_image_memory_with(w, h, variance_bytes)
            .map_err(|e| size_error(a, size.is_some(), w, h, e))?;
    }
    Ok(size)
}

/// An image-size refusal, blamed on --width/--height where they set the size, else on
/// the scene's camera.
fn size_error(a: &Args, flags: bool, w: u32, h: u32, e: impl std::fmt::Display) -> anyhow::Error {
    if flags {
        anyhow!("--width/--height {w} x {h}: {e}")
    } else {
        anyhow!("{}: camera.width/height: {e}", a.scene.display())
    }
}

/// The image size `--width`/`--height` ask for, or None to keep the camera's. One alone
/// keeps the camera's aspect (rounded, at least 1 pixel); a derived side beyond the
/// largest image is refused naming both flags.
fn image_size(
    camera: &render_gpu::scene::CameraDesc,
    width: Option<u32>,
    height: Option<u32>,
) -> Result<Option<(u32, u32)>> {
    let (w0, h0) = (camera.width as f64, camera.height as f64);
    // The camera's sides are in range (`check_overridable`, before this).
    let derive = |given: u32, from: f64, to: f64, flag: &str, other: &str| -> Result<u32> {
        let v = (given as f64 * to / from).round().max(1.0);
        let max = render_gpu::scene::MAX_IMAGE_SIDE;
        if v > max as f64 {
            bail!(
                "--{flag} {given} with the camera's aspect ({} x {}) gives a {other} of {v}, \
                 beyond the largest {max}: give --{other} too",
                camera.width,
                camera.height
            );
        }
        Ok(v as u32)
    };
    Ok(match (width, height) {
        (None, None) => None,
        (Some(w), Some(h)) => Some((w, h)),
        (Some(w), None) => Some((w, derive(w, w0, h0, "width", "height")?)),
        (None, Some(h)) => Some((derive(h, h0, w0, "height", "width")?, h)),
    })
}

/// Known before the render: --variance with fewer spp than it needs wrote no variance
/// image and exited 0 after the work. (Under a time budget alone it is told after.)
fn check_variance_spp(a: &Args, spp_cap: Option<u32>) -> Result<()> {
    if let Some(n) = spp_cap
        && a.variance
        && n < render_gpu::render::MIN_VARIANCE_SPP
    {
        bail!(
            "--variance needs at least {} spp (2 samples a channel); this render has {n} \
             ({}): raise --spp",
            render_gpu::render::MIN_VARIANCE_SPP,
            if a.spp.is_some() {
                "--spp"
            } else {
                "the scene's render.spp"
            }
        );
    }
    Ok(())
}
