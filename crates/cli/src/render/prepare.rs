//! A scene file and the command line's overrides made into what a render needs: the
//! scene's data, the model, the settings in force, and what to tell the user before the
//! render starts.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use render_gpu::integrator::{IntegratorKind, IntegratorSettings};
use render_gpu::scene::SceneFile;
use render_gpu::setup::SceneData;

use crate::model_cmds::{load_model, model_path};

use super::{Args, DEFAULT_SCENE};

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

/// What the user should know about the prepared render before it starts: an unused model,
/// conditions outside the model's training, steps simulated exactly, the lights.
pub(super) fn prepared_notes(a: &Args, p: &Prepared) {
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

#[cfg(test)]
mod tests {
    use super::{IntegratorKind, IntegratorSettings, SceneData, prepare, thresholds_hash};

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
}
