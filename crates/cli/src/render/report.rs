//! What a finished render reports: the JSON beside the image and the lines printed at
//! its end.

use render_gpu::integrator::{IntegratorSettings, PathStats};
use serde::Serialize;

use crate::device::Engine;
use crate::progress;

use super::{Args, Prepared};

#[derive(Serialize)]
pub(super) struct Report<'a> {
    /// The stcvae version that rendered it.
    version: &'static str,
    scene: String,
    integrator: &'static str,
    nee: bool,
    model: Option<String>,
    /// FNV-1a 64 of the model (hex): tells a replaced model file apart.
    model_hash: Option<String>,
    /// Samples per pixel rendered: fewer than `spp_requested` when a time budget or Ctrl-C
    /// stopped the render.
    spp: u32,
    /// None under a time budget without --spp: the budget alone ends the render.
    spp_requested: Option<u32>,
    /// `--time-budget` in seconds.
    time_budget: Option<f64>,
    /// Whether Ctrl-C, SIGTERM or a closed output pipe cut the render short (a time budget's stop is not an interruption).
    interrupted: bool,
    /// The seed, and the same as text: JSON readers that hold numbers as doubles (jq,
    /// JavaScript) round seeds above 2^53.
    seed: u64,
    seed_text: String,
    /// `--exposure`, the factor the PNG was scaled by (the EXR is not).
    exposure: f32,
    width: u32,
    height: u32,
    seconds: f64,
    /// The GPU driver's compilation of the kernel, before `seconds` started (null on the
    /// CPU).
    kernel_compile_seconds: Option<f64>,
    /// Kernel dispatches, those redone after a software adapter's loop limit cut them off,
    /// the bands of rows and the final bounces per dispatch (null on the CPU).
    gpu_dispatch: Option<render_gpu::render::DispatchStats>,
    paths_per_second: f64,
    /// PT: scattering events per path. ST-CVAE: the thin-region PT fallbacks per path.
    mean_pt_events_per_path: f64,
    mean_sphere_steps_per_path: f64,
    /// ST-CVAE's settings; null for PT, which reads none of them.
    min_tau: Option<f64>,
    max_tau: Option<f64>,
    /// Sphere steps below this optical radius simulate their walk exactly; null when all
    /// do (|g| above render_gpu::scene::MODEL_MAX_G).
    exact_tau: Option<f64>,
    /// NEE events per model-drawn and per exactly simulated sphere step (null without
    /// NEE).
    nee_samples: Option<u32>,
    exact_nee_samples: Option<u32>,
    /// ST-CVAE's shadow rays per path (0: one at every NEE event).
    path_nee_rays: Option<u32>,
    grid_resolution: Option<u32>,
    scene_hash: String,
    /// The scene without its integrator settings, model and build (what `bench error`
    /// compares), as in the EXR's tag.
    view_hash: String,
    /// Where it ran: "cpu (N threads, CPU model)" or "gpu: adapter (backend, type)", with
    /// "on CPU model" after a software adapter.
    device: String,
    /// Mean of the image per channel (a quick comparison between renders).
    mean_rgb: [f64; 3],
    /// With --variance: the variance image's file name (beside the JSON), and the square
    /// root of its mean per channel over all pixels (a constant background, whose variance
    /// is 0, included).
    variance_file: Option<String>,
    rms_standard_error_rgb: Option<[f64; 3]>,
    stats: &'a PathStats,
}

/// The render's JSON report.
pub(super) fn report<'o>(
    a: &Args,
    p: &Prepared,
    set: &IntegratorSettings,
    engine: &Engine,
    out: &'o render_gpu::render::RenderOutput,
    spp_cap: Option<u32>,
    interrupted: bool,
) -> Report<'o> {
    let r = &p.file.render;
    let hash = p.data.hash;
    let paths = out.stats.paths.max(1) as f64;
    let stcvae = p.model.is_some();
    let stcvae_nee = stcvae && r.nee;
    Report {
        version: env!("CARGO_PKG_VERSION"),
        scene: a.scene.display().to_string(),
        integrator: r.integrator.name(),
        nee: r.nee,
        model: p.model_path.as_ref().map(|m| m.display().to_string()),
        model_hash: p.model_hash.map(|h| format!("{h:016x}")),
        spp: out.spp,
        spp_requested: spp_cap,
        time_budget: a.time_budget,
        interrupted,
        seed: r.seed,
        seed_text: r.seed.to_string(),
        exposure: a.exposure,
        width: p.file.camera.width,
        height: p.file.camera.height,
        seconds: out.seconds,
        kernel_compile_seconds: engine.is_gpu().then_some(out.compile_seconds),
        gpu_dispatch: engine.is_gpu().then_some(out.dispatch),
        paths_per_second: out.paths_per_second(),
        mean_pt_events_per_path: out.stats.events as f64 / paths,
        mean_sphere_steps_per_path: out.stats.steps as f64 / paths,
        min_tau: stcvae.then_some(set.min_tau as f64),
        max_tau: stcvae.then_some(p.max_tau as f64),
        exact_tau: (stcvae && p.models_trusted()).then_some(set.exact_tau as f64),
        nee_samples: stcvae_nee.then_some(set.nee_samples),
        exact_nee_samples: stcvae_nee.then_some(set.exact_nee_samples),
        path_nee_rays: stcvae_nee.then_some(set.path_nee_rays),
        grid_resolution: stcvae.then_some(r.grid_resolution),
        scene_hash: format!("{hash:016x}"),
        view_hash: format!("{:016x}", p.data.view_hash),
        device: engine.describe(),
        mean_rgb: mean_rgb(&out.image),
        // The bare name: the file sits beside the JSON, and a path relative to the
        // render's working directory misled a reader resolving it from the JSON's folder.
        variance_file: out.variance.as_ref().map(|_| {
            crate::merge::image_out(&a.out, "var.exr")
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
        }),
        rms_standard_error_rgb: out.variance.as_ref().map(|v| mean_rgb(v).map(f64::sqrt)),
        stats: &out.stats,
    }
}

/// The line that ends a render: its speed, its work per path, and where it went.
pub(super) fn print_summary(a: &Args, out: &render_gpu::render::RenderOutput, report: &Report) {
    eprintln!(
        "{} spp in {:.1} s ({} paths/s; {:.1} PT events, {:.1} sphere steps per path{}{}) -> {}.{{exr,png,json{}}}",
        out.spp,
        out.seconds,
        progress::si(report.paths_per_second),
        report.mean_pt_events_per_path,
        report.mean_sphere_steps_per_path,
        // The work an exact step hides: its walk, simulated event by event.
        if out.stats.exact_steps > 0 {
            let per = |n: u64| n as f64 / out.stats.paths.max(1) as f64;
            format!(
                ", {:.1} of them exact, whose walks simulate {:.1} events a path",
                per(out.stats.exact_steps),
                per(out.stats.exact_events)
            )
        } else {
            String::new()
        },
        // A driver that compiles at the first dispatch (lavapipe: seconds on a cold cache)
        // is timed apart, so that paths/s measure rendering.
        if out.compile_seconds >= 0.1 {
            format!(
                "; plus {:.1} s compiling the kernel first",
                out.compile_seconds
            )
        } else {
            String::new()
        },
        crate::paths::shown(&crate::merge::out_stem(&a.out)),
        if out.variance.is_some() {
            ",var.exr"
        } else {
            ""
        }
    );
}

/// Why a render ran well past its time budget, which it stops only after the pass in
/// which the budget ran out: a budget shorter than the first pass (a GPU's renders one
/// sample for each of a pixel's path slots, 16 spp of a small image on lavapipe) gets
/// that pass whole. None where it kept to twice the budget, or went past its first pass
/// (a later pass that ran long is the machine's doing, not the budget's).
pub(super) fn budget_overrun_note(
    budget: Option<f64>,
    out: &render_gpu::render::RenderOutput,
    gpu: bool,
) -> Option<String> {
    let b = budget?;
    let first = if gpu { out.dispatch.first_chunk_spp } else { 1 };
    (out.seconds > 2.0 * b && out.spp == first).then(|| {
        let pass = if gpu {
            format!("the GPU's first renders {first} spp here, one sample per path slot of a pixel")
        } else {
            "the first is 1 spp".to_string()
        };
        format!(
            "note: the render took {} s of a {} s budget: it stops only after a whole pass \
             ({pass})",
            progress::significant4(out.seconds),
            scatter_sim::ranges::num(b)
        )
    })
}

/// The lane profile (`STCVAE_GPU_PROFILE=1`): per phase, its share of all subgroup passes
/// and the share of its SIMD lanes that did work.
pub(super) fn print_lanes(lanes: &render_gpu::render::LaneProfile) {
    let passes: u64 = lanes.phases.iter().map(|p| p.capacity).sum();
    let size = lanes.phases[0].capacity / lanes.phases[0].passes.max(1);
    eprintln!(
        "SIMD lanes busy per phase of the kernel (subgroups of {size} lanes; STCVAE_GPU_PROFILE):"
    );
    eprintln!(
        "  {:<38} {:>14} {:>12}",
        "phase", "lane share", "lanes busy"
    );
    for p in &lanes.phases {
        let busy = p
            .efficiency()
            .map_or("-".to_string(), |e| format!("{:.1} %", 100.0 * e));
        let share = 100.0 * p.capacity as f64 / passes.max(1) as f64;
        eprintln!("  {:<38} {:>12.1} % {:>12}", p.phase, share, busy);
    }
}

/// The image's mean per channel (the JSON's `mean_rgb`).
pub(crate) fn mean_rgb(image: &render_gpu::image_io::RgbImage) -> [f64; 3] {
    let n = image.pixels.len().max(1) as f64;
    [0, 1, 2].map(|c| image.pixels.iter().map(|p| p[c] as f64).sum::<f64>() / n)
}

/// Says how often paths were found outside the medium while believing themselves inside:
/// a flight from a sphere exit met the surface from outside, or a collision fell outside
/// the mesh (f32 precision at features thinner than the surface offset, or a mesh folded
/// through itself). The path continued from there as outside. Counted in the JSON as
/// `leaks`; `what` names the render where a command renders several.
pub(crate) fn leak_note(stats: &render_gpu::integrator::PathStats, what: &str) {
    if stats.leaks > 0 {
        let rate = stats.leaks as f64 / stats.paths.max(1) as f64;
        // Rounding leaks a path in 10⁵ or fewer; a mesh folded through itself (a single
        // closed piece is not checked for that) leaks in most paths, and the image is wrong.
        let cause = if rate > 1e-3 {
            "; this many mean the mesh most likely intersects itself, and the image is wrong \
             there: repair the mesh"
        } else {
            ""
        };
        eprintln!(
            "note: {what}{} times (over {} paths, {rate:.1e} a path) a path was found outside \
             the mesh while it believed itself inside; each continued from there as \
             outside{cause}",
            stats.leaks, stats.paths,
        );
    }
}
