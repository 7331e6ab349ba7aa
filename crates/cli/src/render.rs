//! `stcvae render`: a scene file to EXR + PNG + JSON.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use render_gpu::image_io::RenderTag;
use render_gpu::integrator::{IntegratorKind, IntegratorSettings, PathStats};
use render_gpu::render::RenderOptions;
use render_gpu::scene::SceneFile;
use render_gpu::setup::SceneData;
use serde::Serialize;

use crate::device::{DeviceArg, Engine};
use crate::model_cmds::{load_model, model_path};
use crate::{interrupt, progress};

pub const DEFAULT_SCENE: &str = "configs/scenes/bunny.toml";

#[derive(clap::Args)]
#[command(
    after_help = "With no arguments renders the shipped bunny scene with the shipped \
    model to out/render.{exr,png,json}. Options given here override the scene's [render] table.\n\n\
    Example:\n  stcvae render --scene configs/scenes/sphere.toml --integrator pt --spp 256 --out out/sphere_pt\n  \
    stcvae render configs/scenes/sphere.toml --width 128 --spp 16   (a quick look: 128 pixels wide)"
)]
pub struct Args {
    /// Scene file (TOML; the format is in the README).
    #[arg(long, default_value = DEFAULT_SCENE, value_parser = crate::shipped::scene_arg(DEFAULT_SCENE))]
    pub scene: PathBuf,
    /// The scene file, given without --scene (`stcvae render S.toml`).
    #[arg(value_name = "SCENE", conflicts_with = "scene",
          value_parser = crate::shipped::scene_arg(DEFAULT_SCENE))]
    pub scene_file: Option<PathBuf>,
    /// Image width in pixels, 1 to 16384 (overrides camera.width; given alone, the height
    /// follows the camera's aspect).
    #[arg(long, allow_negative_numbers = true,
          value_parser = crate::whole::whole::<u32>(1, render_gpu::scene::MAX_IMAGE_SIDE as u64))]
    pub width: Option<u32>,
    /// Image height in pixels, 1 to 16384 (overrides camera.height; given alone, the width
    /// follows the camera's aspect).
    #[arg(long, allow_negative_numbers = true,
          value_parser = crate::whole::whole::<u32>(1, render_gpu::scene::MAX_IMAGE_SIDE as u64))]
    pub height: Option<u32>,
    /// pt (volumetric path tracing, the reference) or stcvae (sphere tracing with the CVAEs)
    /// (overrides render.integrator).
    #[arg(long, value_parser = integrator_parser())]
    pub integrator: Option<IntegratorKind>,
    /// Next-event estimation to the directional lights, true or false (overrides
    /// render.nee).
    #[arg(long)]
    pub nee: Option<bool>,
    /// Samples per pixel, 1 to 2³² − 1 (overrides render.spp).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::whole::whole::<u32>(1, u32::MAX.into()))]
    pub spp: Option<u32>,
    /// Random seed, an integer in [0, 2^64) (overrides render.seed): renders with different
    /// seeds are independent and can be averaged with `stcvae merge`.
    #[arg(long, allow_negative_numbers = true, value_parser = parse_seed)]
    pub seed: Option<u64>,
    /// Model file for stcvae (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    pub model: Option<PathBuf>,
    /// Stop after the pass during which this many seconds have passed, in (0, 1e8] (over
    /// three years; the JSON and the EXR header record the spp actually rendered; at least
    /// one pass runs).
    /// The scene's spp is then no limit; --spp given too stops at that many first.
    #[arg(long, allow_negative_numbers = true, value_parser = parse_time_budget)]
    pub time_budget: Option<f64>,
    /// Output path without extension: writes OUT.exr, OUT.png and OUT.json (a typed .exr,
    /// .png or .json is dropped: `--out a.exr` writes a.exr, a.png, a.json).
    #[arg(long, default_value = "out/render")]
    pub out: PathBuf,
    /// Where to render: auto (a hardware GPU if there is one, else the CPU), gpu (any
    /// wgpu adapter, software ones such as lavapipe included) or cpu.
    #[arg(long, value_enum, default_value_t = DeviceArg::Auto)]
    pub device: DeviceArg,
    /// Exposure multiplier of the PNG preview, > 0 (the EXR is always linear and
    /// unscaled).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.0, value_parser = parse_exposure)]
    pub exposure: f32,
    /// Also write OUT.var.exr: per pixel and channel the estimated variance of the
    /// pixel's value (its squared standard error, from the samples' own spread), on
    /// either device, from 6 spp on. A render without it removes an older OUT.var.exr, which would no
    /// longer belong to OUT.exr.
    #[arg(long)]
    pub variance: bool,
}

/// `--seed`: clap's own u64 parser said only "invalid digit found in string" for -1.
pub fn parse_seed(s: &str) -> Result<u64, String> {
    crate::whole::whole(0, u64::MAX)(s)
}

/// `--exposure`: a positive number that stays positive and finite as the f32 the PNG
/// encoder scales by. Parsed as f64 first so that the message quotes what was typed
/// (clap's own f32 parser turned 1e-300 into 0 and the message said "--exposure 0").
pub(crate) fn parse_exposure(s: &str) -> Result<f32, String> {
    let x: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    let e = x as f32;
    if x > 0.0 && e > 0.0 && e.is_finite() {
        Ok(e)
    } else {
        Err(format!(
            "{} is out of range: must be > 0 and finite as an f32, i.e. in [{:e}, {:e}]",
            s.trim(),
            f32::from_bits(1),
            f32::MAX
        ))
    }
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

/// g from which the models' own small sphere steps were measured biased (below).
const BIASED_SMALL_STEPS_G: f64 = 0.9;

/// Forward scattering at or above [`BIASED_SMALL_STEPS_G`] with exact_tau lowered below its
/// default: the models then draw the thin sphere steps that the default simulates, where
/// they were measured biased (fifty-fourth session; a sphere of radius 0.5, σ_t 300,
/// albedo (0.999, 0.99, 0.9), a 90° sun, NEE off, exact_tau 0, 16², 1,024 spp, against
/// PT): at g = 0.95 −4.0 %, −7.5 %, −29.5 % (z −4 to −9.5), at 0.9 −1.6 to −6.4 % (z to
/// −2.9), at 0.7 and 0 within 3.4 % (z ≤ 2.3); with the default exact_tau, g = 0.95 within
/// 1.6 % (z ≤ 1.5). |g| above MODEL_MAX_G takes no model steps at all.
fn forward_model_steps_warning(p: &Prepared) -> Option<String> {
    let g = p.file.medium.g;
    let exact_tau = p.file.render.exact_tau_or_default();
    (p.model.is_some()
        && p.models_trusted()
        && g >= BIASED_SMALL_STEPS_G
        && exact_tau < render_gpu::scene::DEFAULT_EXACT_TAU)
        .then(|| {
            format!(
                "render.exact_tau = {} below its default {} with medium.g = {g}: the models \
                 then draw the thin sphere steps, which at g >= {BIASED_SMALL_STEPS_G} were \
                 measured too dark in absorbing media (-4 to -30 % at g = 0.95 on a sphere of \
                 optical radius 150); the default simulates them exactly",
                scatter_sim::ranges::num(exact_tau),
                render_gpu::scene::DEFAULT_EXACT_TAU
            )
        })
}

/// `--time-budget`: clap's own f64 parser said only "invalid float literal", with no range;
/// and 1e300 was taken (a render without end, announced with 300 digits).
fn parse_time_budget(s: &str) -> Result<f64, String> {
    let b: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number of seconds"))?;
    if b > 0.0 && b <= MAX_TIME_BUDGET {
        Ok(b)
    } else {
        Err(format!(
            "{} is out of range: allowed (0, {MAX_TIME_BUDGET:e}] seconds",
            s.trim()
        ))
    }
}

/// `--integrator`: pt or stcvae (st-cvae accepted too), listed in the help.
fn integrator_parser() -> impl clap::builder::TypedValueParser<Value = IntegratorKind> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser as _};
    PossibleValuesParser::new([
        PossibleValue::new("pt"),
        PossibleValue::new("stcvae").alias("st-cvae"),
    ])
    .map(|s| match s.as_str() {
        "pt" => IntegratorKind::Pt,
        _ => IntegratorKind::Stcvae,
    })
}

#[derive(Serialize)]
struct Report<'a> {
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

/// Everything needed to render, assembled from a scene file and overrides.
pub struct Prepared {
    pub file: SceneFile,
    pub data: SceneData,
    pub model: Option<cvae::ModelSet>,
    pub model_path: Option<PathBuf>,
    /// FNV-1a 64 of the model file's bytes.
    pub model_hash: Option<u64>,
    pub max_tau: f32,
}

impl Prepared {
    /// Whether ST-CVAE may draw sphere steps from the models in this medium: not for |g|
    /// above [`render_gpu::scene::MODEL_MAX_G`], where they were measured biased.
    pub fn models_trusted(&self) -> bool {
        self.file.medium.g.abs() <= render_gpu::scene::MODEL_MAX_G
    }

    /// The integrator settings of this scene (its `[render]` table, with the overrides
    /// `prepare` applied, the defaults and the model's τ limit); the same on every device.
    pub fn settings(&self) -> IntegratorSettings<'_> {
        let r = &self.file.render;
        IntegratorSettings {
            kind: r.integrator,
            nee: r.nee,
            model: self.model.as_ref(),
            min_tau: r.min_tau_or_default() as f32,
            max_tau: self.max_tau,
            // f32::MAX rather than infinity: shading languages may assume no infinities
            // (Metal's fast math), and every step's τ ≤ max_tau is below it.
            exact_tau: if self.models_trusted() {
                r.exact_tau_or_default() as f32
            } else {
                f32::MAX
            },
            nee_samples: r.nee_samples,
            exact_nee_samples: r.exact_nee_samples,
            path_nee_rays: r.path_nee_rays,
        }
    }
}

pub fn prepare(
    scene_path: &Path,
    integrator: Option<IntegratorKind>,
    nee: Option<bool>,
    model: Option<&Path>,
    edit: impl FnOnce(&mut SceneFile),
) -> Result<Prepared> {
    if scene_path == Path::new(DEFAULT_SCENE) && !scene_path.exists() {
        bail!(
            "{DEFAULT_SCENE} not found here or in the checkout this binary was built from: run \
             from the repository root (the default scene lives there) or pass --scene FILE"
        );
    }
    // Validated below, once the overrides are in; the fields they replace are checked as
    // written first.
    let mut file = SceneFile::load_unvalidated(scene_path)?;
    file.check_overridable()
        .map_err(|e| anyhow!("{}: {e}", scene_path.display()))?;
    if let Some(i) = integrator {
        file.render.integrator = i;
    }
    if let Some(n) = nee {
        file.render.nee = n;
    }
    edit(&mut file);
    file.validate()
        .map_err(|e| anyhow!("{}: {e}", scene_path.display()))?;
    let stcvae = file.render.integrator == IntegratorKind::Stcvae;
    let (model, model_path, model_bytes) = if stcvae {
        let p = model_path(model);
        let m = load_model(model)?;
        let bytes = m.to_bytes();
        (Some(m), Some(p), bytes)
    } else {
        (None, None, Vec::new())
    };
    let dir = scene_path.parent().unwrap_or(Path::new("."));
    let spin = crate::progress::spinner(&format!(
        "preparing {} (mesh, BVH{})",
        scene_path.display(),
        if stcvae { ", distance grid" } else { "" }
    ));
    let data = SceneData::build(&file, dir, stcvae, &model_bytes).map_err(|e| match e {
        // Scene-level refusals name a field; the file is the scene's.
        render_gpu::error::RenderError::Scene(m) => anyhow!("{}: {m}", scene_path.display()),
        other => other.into(),
    });
    spin.finish_and_clear();
    let data = data?;
    for n in &data.notes {
        eprintln!("note: {}: {n}", scene_path.display());
    }
    let min_tau = file.render.min_tau_or_default();
    let max_tau = match (file.render.max_tau, &model) {
        (Some(t), Some(m)) if crate::model_cmds::beyond_trained_tau(t, m) => bail!(
            "{}: render.max_tau = {} is beyond the model's training range {}",
            scene_path.display(),
            scatter_sim::ranges::num(t),
            crate::model_cmds::training_range(m.training.tau_range)
        ),
        (Some(t), _) => t,
        (None, None) => f64::INFINITY,
        // The scene check refuses max_tau < min_tau when both are written; without max_tau
        // the cap is the model's, known only now.
        (None, Some(m)) => crate::model_cmds::default_max_tau(min_tau, m).with_context(|| {
            format!(
                "{}: {} is above the model's training maximum {max} (the default max_tau): \
                 no sphere step could be taken (allowed: min_tau <= max_tau; set \
                 render.min_tau to at most {max} in the scene)",
                scene_path.display(),
                file.render.min_tau_words(),
                max = scatter_sim::ranges::num(crate::model_cmds::trained_max_tau(m) as f32)
            )
        })?,
    } as f32;
    let mut p = Prepared {
        file,
        data,
        // Of the file's bytes (what a user can hash again), not the re-serialised model.
        model_hash: model_path
            .as_ref()
            .and_then(|p| std::fs::read(p).ok())
            .map(|bytes| {
                let mut h = render_gpu::hash::Fnv64::new();
                h.write(&bytes);
                h.finish()
            }),
        model,
        model_path,
        max_tau,
    };
    if p.model.is_some() {
        p.data.hash = thresholds_hash(p.data.hash, &p.settings());
    }
    Ok(p)
}

/// `scene_hash` with ST-CVAE's thresholds in force `s` folded in. A scene file usually
/// leaves them unset, and the code that fills them in (render_gpu::scene's defaults and
/// MODEL_MAX_G, the model's τ limit here) is not among the sources the scene hash
/// includes (render-gpu's build.rs): renders by builds that differ there converge to
/// different images and must not be merged as one scene's.
fn thresholds_hash(scene_hash: u64, s: &IntegratorSettings) -> u64 {
    let mut h = render_gpu::hash::Fnv64::new();
    h.write(&scene_hash.to_le_bytes());
    for v in [s.min_tau, s.max_tau, s.exact_tau] {
        h.write(&v.to_le_bytes());
    }
    h.finish()
}

/// The models extrapolate outside the media they were trained on (τ is kept inside by the
/// sphere steps' max_tau; g and the albedo are the scene's): the warning `render` gives,
/// and `experiment` too (another `--model` may not cover its media), with as its key the
/// scene and which parameters lie outside: an experiment says it once per key (an
/// absorption sweep varies the albedo over one scene, and printed the same warning once
/// per value).
pub(crate) fn outside_training_warning(
    p: &Prepared,
    scene_path: &Path,
) -> Option<(String, String)> {
    let m = p.model.as_ref()?;
    let t = &m.training;
    let med = &p.file.medium;
    let mut outside = Vec::new();
    let mut key = scene_path.display().to_string();
    if crate::model_cmds::outside_training(med.g, t.g_range) {
        key += ":g";
        outside.push(format!(
            "medium.g = {} (trained {})",
            med.g,
            crate::model_cmds::training_range(t.g_range)
        ));
    }
    if let Some(a) = med
        .albedo
        .iter()
        .find(|&&a| crate::model_cmds::outside_training(a, t.albedo_range))
    {
        key += ":albedo";
        outside.push(format!(
            "medium.albedo {a} (trained {})",
            crate::model_cmds::training_range(t.albedo_range)
        ));
    }
    // The models draw the sphere steps from max(min_tau, exact_tau) up (smaller ones are
    // PT or exact walks): a model trained from τ = 30 drew steps from 20 unsaid.
    let s = p.settings();
    let lowest = s.min_tau.max(s.exact_tau) as f64;
    if lowest <= s.max_tau as f64 && crate::model_cmds::outside_training(lowest, t.tau_range) {
        key += ":tau";
        outside.push(format!(
            "sphere steps from τ = {} (render.min_tau/exact_tau; trained {})",
            scatter_sim::ranges::num(lowest),
            crate::model_cmds::training_range(t.tau_range)
        ));
    }
    (!outside.is_empty()).then(|| {
        let line = format!(
            "{}: {} outside the model's training range: ST-CVAE extrapolates there",
            scene_path.display(),
            outside.join(", ")
        );
        (key, line)
    })
}

/// The image's memory with a software adapter's path state, which lives in host memory
/// (`gpu::kernels::slot_vec4s`, 16 bytes each, with `variance` its squared sums too), and
/// `extra` bytes a pixel the caller holds beside them: checked before a render on one.
pub(crate) fn software_gpu_memory(
    width: u32,
    height: u32,
    set: &IntegratorSettings,
    variance: bool,
    extra: u64,
) -> std::result::Result<(), String> {
    let slot = 16 * render_gpu::gpu::kernels::slot_vec4s(set.path_nee() as u32, variance);
    render_gpu::render::check_image_memory_with(width, height, slot + extra)
        .map_err(|e| format!("{e} (with the software GPU's path state)"))
}

/// `--out` is a path stem (OUT.exr, OUT.png, OUT.json); checked before rendering so that a
/// long render is not lost to an unwritable name.
pub(crate) fn check_out_stem(out: &Path) -> Result<()> {
    crate::paths::check_not_stdout("--out", out)?;
    let text = out.as_os_str().to_string_lossy();
    if out.file_name().is_none()
        || text.ends_with('/')
        || text.ends_with(std::path::MAIN_SEPARATOR)
        || out.is_dir()
    {
        bail!(
            "--out {}: names a directory; give a path stem such as {}/render (writes render.exr, .png, .json)",
            out.display(),
            text.trim_end_matches(['/', std::path::MAIN_SEPARATOR])
        );
    }
    for dir in out.ancestors().skip(1) {
        if dir.as_os_str().is_empty() {
            break;
        }
        if dir.exists() {
            if !dir.is_dir() {
                bail!(
                    "--out {}: {} exists and is not a directory",
                    out.display(),
                    dir.display()
                );
            }
            break;
        }
    }
    // An output name taken by a folder (or a FIFO, a device), or a place without write
    // permission, would fail only after the render.
    for ext in ["exr", "png", "json"] {
        let f = crate::merge::image_out(out, ext);
        scatter_sim::output::check_output_path(&f)
            .map_err(|e| anyhow::anyhow!("--out {}: {e}", out.display()))?;
    }
    if let Some(render) = variance_image_owner(out) {
        bail!(
            "--out {}: {} is the variance image of the render {} (its JSON names it), which \
             this image would replace: choose another --out",
            out.display(),
            crate::merge::image_out(out, "exr").display(),
            render.display()
        );
    }
    Ok(())
}

/// The render whose variance image OUT.exr is, where OUT is named like one (`q.var`) and
/// render q's report says so: `render --out q.var` replaced q's variance image without a
/// word, while the other way round (`render --out q --variance` over a render q.var) was
/// refused.
fn variance_image_owner(out: &Path) -> Option<PathBuf> {
    let stem = crate::merge::out_stem(out);
    let render = stem.with_file_name(stem.file_name()?.to_str()?.strip_suffix(".var")?);
    let exr = crate::merge::image_out(out, "exr");
    if !exr.is_file() {
        return None;
    }
    // Read as inputs are: a FIFO named q.json would have held the command up.
    let text = scatter_sim::output::read_input_to_string(&crate::merge::image_out(&render, "json"))
        .ok()?;
    let json: serde_json::Value = serde_json::from_str(&text).ok()?;
    let named = json.get("variance_file")?.as_str()?;
    (Some(std::ffi::OsStr::new(named)) == exr.file_name()).then_some(render)
}

/// The files a render reads (and `--model`, even when PT leaves it unread): none may be
/// one of its outputs.
fn render_inputs(a: &Args, p: &Prepared) -> Vec<(String, PathBuf)> {
    let mut v = scene_inputs(&a.scene, &p.file);
    v.extend(
        p.model_path
            .iter()
            .chain(&a.model)
            .map(|m| ("the model".to_string(), m.clone())),
    );
    v
}

/// The files a scene reads (the scene, its mesh and a glTF mesh's buffers, its environment
/// map), as `paths::check_not_input` takes them.
pub fn scene_inputs(scene: &Path, file: &SceneFile) -> Vec<(String, PathBuf)> {
    let dir = scene.parent().unwrap_or(Path::new("."));
    let field = |f: &str| format!("the scene's {f}");
    let mut v = vec![("--scene".to_string(), scene.to_path_buf())];
    if let Some(m) = &file.object.mesh {
        let mesh = dir.join(m);
        v.extend(
            render_gpu::mesh::gltf_buffer_files(&mesh)
                .into_iter()
                .map(|b| (field("object.mesh's buffer"), b)),
        );
        v.push((field("object.mesh"), mesh));
    }
    v.extend(
        file.environment
            .file
            .iter()
            .map(|f| (field("environment.file"), dir.join(f))),
    );
    v
}

/// Says once when the scene's lights cannot contribute: no light at all, or delta lights
/// without NEE.
pub fn note_lights(p: &Prepared) {
    // A scene without light renders black by design; say so rather than hand over a
    // black image as a result.
    let env = &p.data.env;
    let env_black = env.radiance.iter().all(|&v| v == 0.0)
        || env
            .map
            .as_ref()
            .is_some_and(|m| m.pixels.iter().all(|px| px.iter().all(|&v| v == 0.0)));
    if env_black
        && p.data
            .lights
            .iter()
            .all(|l| l.irradiance.iter().all(|&v| v == 0.0))
    {
        eprintln!(
            "warning: the scene has no light (no [[light]] with irradiance above 0 and a \
             black [environment]): the image will be black"
        );
    }
    // Counted whenever some are delta: with a disk light beside a sun, --nee false halved
    // the image without a word, since the note came only when every light was delta.
    let delta = p.data.lights.iter().filter(|l| l.is_delta()).count();
    if delta > 0 && !p.file.render.nee {
        let which = if delta == p.data.lights.len() {
            String::new()
        } else {
            format!(" ({delta} of the scene's {})", p.data.lights.len())
        };
        eprintln!(
            "note: delta lights{which} can only be reached by NEE; with --nee false they add \
             nothing"
        );
    }
    // Measured against an independent walk through a sphere (render-gpu's tests,
    // `a_sphere_matches_an_independent_walk`: −0.8 %, −0.5 %, −0.2 % on the CPU) and NEE off
    // under a sun 60° off a flat face (`nee_through_a_dielectric_refracts_toward_an_oblique_
    // sun`: within its ~1.4 % noise, where the paper's straight shadow ray read 7–12 %).
    if p.file.render.nee && !p.data.lights.is_empty() && p.data.boundary.ior().is_some() {
        eprintln!(
            "note: NEE through a dielectric boundary refracts at the plane of the face its \
             shadow ray leaves through: exact where one flat face admits the light, a little \
             dark near edges between lit faces and on curved ones (~1 % on a sphere: their \
             focusing is left out); --nee false is unbiased, and noisier"
        );
    }
}

/// Longest `--time-budget`, in seconds (over three years).
const MAX_TIME_BUDGET: f64 = 1e8;

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

/// What the user should know about the prepared render before it starts: an unused model,
/// conditions outside the model's training, steps simulated exactly, the lights.
fn prepared_notes(a: &Args, p: &Prepared) {
    if a.model.is_some() && p.model.is_none() {
        eprintln!("note: --model is not used: the PT integrator needs no model");
    }
    if let Some((_, w)) = outside_training_warning(p, &a.scene) {
        eprintln!("warning: {w}");
    }
    if p.model.is_some() && !p.models_trusted() {
        eprintln!(
            "note: |medium.g| = {} is above {}, where the models' sphere steps were measured \
             biased: every step's walk is simulated exactly (the same image as PT's, at \
             about its cost)",
            p.file.medium.g.abs(),
            render_gpu::scene::MODEL_MAX_G
        );
    }
    if let Some(w) = forward_model_steps_warning(p) {
        eprintln!("warning: {}: {w}", a.scene.display());
    }
    note_lights(p);
}

/// The output files may be written: none is an input, and the variance image replaces no
/// other image.
fn check_outputs(a: &Args, inputs: &[(String, PathBuf)]) -> Result<()> {
    let exts: &[&str] = if a.variance {
        &["exr", "png", "json", "var.exr"]
    } else {
        &["exr", "png", "json"]
    };
    for ext in exts {
        let f = crate::merge::image_out(&a.out, ext);
        crate::paths::check_not_input("--out", &f, inputs)?;
        if *ext == "var.exr" {
            scatter_sim::output::check_output_path(&f)
                .map_err(|e| anyhow::anyhow!("--out {}: {e}", a.out.display()))?;
            // A render named OUT.var had its image replaced by this one's variance.
            if crate::merge::foreign_var_exr(&a.out) {
                bail!(
                    "--out {}: {} is another image (a render or picture named {}), which \
                     the variance image would replace: choose another --out",
                    a.out.display(),
                    f.display(),
                    crate::merge::out_stem(&a.out).display().to_string() + ".var"
                );
            }
        }
    }
    Ok(())
}

/// The render's JSON report.
fn report<'o>(
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
fn print_summary(a: &Args, out: &render_gpu::render::RenderOutput, report: &Report) {
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
fn budget_overrun_note(
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
fn print_lanes(lanes: &render_gpu::render::LaneProfile) {
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

#[cfg(test)]
mod tests {
    use super::{
        IntegratorKind, IntegratorSettings, SceneData, parse_exposure, prepare, thresholds_hash,
    };

    /// The hash that `merge` and the PT cache compare holds ST-CVAE's thresholds in
    /// force, which the scene file leaves unset and code outside the hashed sources fills
    /// in: a build with another model τ limit (or default) writes renders of another hash.
    /// PT's hash, which they never touch, stays the scene's own.
    #[test]
    fn the_scene_hash_holds_the_thresholds_in_force() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let scene = root.join("configs/scenes/sphere.toml");
        let model = root.join("models/default.stcvae");
        let dir = scene.parent().unwrap();
        let st = prepare(
            &scene,
            Some(IntegratorKind::Stcvae),
            None,
            Some(&model),
            |_| {},
        )
        .unwrap();
        let bytes = st.model.as_ref().unwrap().to_bytes();
        let base = SceneData::build(&st.file, dir, false, &bytes).unwrap().hash;
        let settings = st.settings();
        assert_eq!(st.data.hash, thresholds_hash(base, &settings));
        assert_ne!(st.data.hash, base);
        let edits: [fn(&mut IntegratorSettings); 3] = [
            |s| s.max_tau = 50.0,
            |s| s.min_tau = 2.0,
            |s| s.exact_tau = 8.0,
        ];
        for edit in edits {
            let mut other = settings;
            edit(&mut other);
            assert_ne!(thresholds_hash(base, &other), st.data.hash);
        }
        let pt = prepare(&scene, Some(IntegratorKind::Pt), None, Some(&model), |_| {}).unwrap();
        let pt_base = SceneData::build(&pt.file, dir, false, &[]).unwrap().hash;
        assert_eq!(pt.data.hash, pt_base);
    }

    #[test]
    fn exposure_takes_positive_finite_f32s_and_quotes_what_was_typed() {
        for (ok, want) in [
            ("1", 1.0f32),
            (" 0.25 ", 0.25),
            ("3e38", 3e38),
            ("1e-45", 1e-45),
        ] {
            assert_eq!(parse_exposure(ok), Ok(want), "{ok}");
        }
        for bad in ["0", "-1", "NaN", "inf", "1e39", "x"] {
            assert!(parse_exposure(bad).is_err(), "{bad}");
        }
        // Below f32's smallest subnormal the f32 would be 0: refused, naming the input.
        let e = parse_exposure("1e-300").unwrap_err();
        assert!(e.starts_with("1e-300 is out of range"), "{e}");
    }

    /// An output named like a file the scene reads is refused, a glTF mesh's external
    /// buffer included: `render --out gb` wrote its gb.exr over the buffer of that name.
    #[test]
    fn outputs_naming_a_glb_buffer_or_another_scene_input_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let gltf = r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"g%20b.exr","byteLength":4}]}"#;
        std::fs::write(d.path().join("m.gltf"), gltf).unwrap();
        let scene = d.path().join("s.toml");
        let text = "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\nwidth = 8\nheight = 8\n\
                    [object]\nmesh = \"m.gltf\"\n[medium]\nsigma_t = [1.0, 1.0, 1.0]\n\
                    albedo = [0.5, 0.5, 0.5]\n[environment]\nfile = \"sky.exr\"\n";
        let file = render_gpu::scene::SceneFile::parse(&scene, text).unwrap();
        let inputs = super::scene_inputs(&scene, &file);
        for (name, what) in [
            ("g b.exr", "the scene's object.mesh's buffer"),
            ("m.gltf", "the scene's object.mesh"),
            ("sky.exr", "the scene's environment.file"),
            ("s.toml", "--scene"),
        ] {
            let e = crate::paths::check_not_input("--out", &d.path().join(name), &inputs)
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("is also {what}")), "{name}: {e}");
        }
        crate::paths::check_not_input("--out", &d.path().join("r.exr"), &inputs).unwrap();
    }

    /// The help's image sizes are the scene file's limit (doc comments cannot name it).
    #[test]
    fn the_help_gives_the_image_size_limit() {
        use clap::CommandFactory as _;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            a: super::Args,
        }
        let cmd = Cli::command();
        let range = format!("1 to {}", render_gpu::scene::MAX_IMAGE_SIDE);
        for id in ["width", "height"] {
            let help = crate::help_of(&cmd, id);
            assert!(help.contains(&range), "--{id}: {help}");
        }
    }
}
