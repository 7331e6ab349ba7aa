//! The seven experiments: what each renders and measures (see configs/experiments/).

use anyhow::{Result, bail};
use render_gpu::image_io::RgbImage;
use render_gpu::integrator::IntegratorKind::{Pt, Stcvae};
use render_gpu::scene::{LightDesc, SceneFile};

use super::measure::{
    Comparison, Pair, compare, difference, errors, opts, pair_seeds, render_once, render_pair,
    save, save_map, save_picture, scale_of, side_by_side, side_by_side_with, work_image,
};
use super::report::{Cell, Report};
use super::{Ctx, Kind};
use crate::plots::{Series, line_plot};

pub fn run(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    match ctx.cfg.kind {
        Kind::Teaser => teaser(ctx, rep),
        Kind::Quality => quality(ctx, rep),
        Kind::Complexity => complexity(ctx, rep),
        Kind::Absorption => absorption(ctx, rep),
        Kind::Distributions => distributions(ctx, rep),
        Kind::Nee => nee(ctx, rep),
        Kind::Fallback => fallback(ctx, rep),
    }
}

fn scale_density(k: f64) -> impl Fn(&mut SceneFile) {
    move |f: &mut SceneFile| f.medium.sigma_t = f.medium.sigma_t.map(|s| s * k)
}

/// The absorption experiment's edit: absorption `a` is albedo φ = 1 − a on every channel.
fn absorb(a: f64) -> impl Fn(&mut SceneFile) {
    move |f: &mut SceneFile| f.medium.albedo = [1.0 - a; 3]
}

/// The scene files the experiment renders.
pub(super) fn scene_paths(cfg: &super::config::Config) -> Vec<std::path::PathBuf> {
    let mut scenes = Vec::new();
    if cfg.scene.is_some() {
        scenes.push(cfg.scene_path());
    }
    scenes.extend(cfg.scenes.iter().map(|s| cfg.dir.join(s)));
    scenes
}

/// Checks every scene edit the experiment will make before the first render, so that a
/// density or threshold out of the scene file's ranges fails at once, not after the
/// renders before it.
pub(super) fn preflight(
    cfg: &super::config::Config,
    model: Option<&std::path::Path>,
) -> Result<()> {
    let scenes = scene_paths(cfg);
    check_names(cfg, &scenes)?;
    for path in &scenes {
        let base = SceneFile::load(path)?;
        check_lights_reached(cfg, path, &base)?;
        check_heights(cfg, path, &base)?;
        // The mesh too, before hours of rendering: a missing one failed the run after its
        // first scene (with the previous run's report left beside the new images).
        let dir = path.parent().unwrap_or(std::path::Path::new("."));
        let eps = render_gpu::setup::object_eps(&base, dir)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let check = |f: &SceneFile, what: String| -> Result<()> {
            f.validate()
                .map_err(|e| anyhow::anyhow!("{}: {what}: {e}", path.display()))
        };
        check_densities(cfg, path, &base, eps, check)?;
        for &t in &cfg.thresholds {
            let mut f = base.clone();
            f.render.min_tau = Some(t);
            // Checked as the ST-CVAE render it is for: a scene file of `pt` skips the
            // min_tau-against-max_tau check, which then failed after PT's renders.
            f.render.integrator = Stcvae;
            check(&f, format!("with threshold {t}"))?;
        }
        // Without max_tau the cap is the model's (render::prepare refuses the rest, but
        // only when that threshold's turn comes, after the renders before it).
        if !cfg.thresholds.is_empty() && base.render.max_tau.is_none() {
            let m = crate::model_cmds::load_model(model)?;
            if let Some(&t) = cfg
                .thresholds
                .iter()
                .find(|&&t| crate::model_cmds::default_max_tau(t, &m).is_none())
            {
                bail!(
                    "{}: threshold {} is above the model's training maximum {} (the default \
                     max_tau): no sphere step could be taken",
                    path.display(),
                    scatter_sim::ranges::num(t),
                    scatter_sim::ranges::num(crate::model_cmds::trained_max_tau(&m) as f32)
                );
            }
        }
    }
    Ok(())
}

/// Images are named after their scene file's stem and the varied value: two scenes of
/// one stem, or a value listed twice, would overwrite each other's images.
fn check_names(cfg: &super::config::Config, scenes: &[std::path::PathBuf]) -> Result<()> {
    let mut stems: Vec<_> = scenes
        .iter()
        .map(|p| p.file_stem().map(|s| s.to_owned()))
        .collect();
    stems.sort();
    if stems.windows(2).any(|w| w[0] == w[1]) {
        anyhow::bail!("two scenes share a file name; their images would overwrite each other");
    }
    for (what, v) in [
        ("densities", &cfg.densities),
        ("absorptions", &cfg.absorptions),
        ("thresholds", &cfg.thresholds),
    ] {
        if let Some(x) = v.iter().enumerate().find(|(i, x)| v[..*i].contains(x)) {
            anyhow::bail!("{what} lists {} twice", x.1);
        }
    }
    Ok(())
}

/// Without NEE a delta light is never reached: the renders would converge to an image
/// lit by the environment alone, and be compared as if lit.
fn check_lights_reached(
    cfg: &super::config::Config,
    path: &std::path::Path,
    base: &SceneFile,
) -> Result<()> {
    // (A scene without lights, lit by its environment, is fine; a disk below a
    // micro-radian is a delta light to the renderer, light::disk_sin2.)
    if cfg.renders_without_nee()
        && !base.lights.is_empty()
        && base
            .lights
            .iter()
            .all(|l| render_gpu::light::disk_sin2(l).is_none())
    {
        bail!(
            "{}: every light is a delta light (light.angular_diameter_deg = 0), and a \
             render without next-event estimation{} never reaches one: give a light a \
             disk (e.g. configs/scenes/bunny_sun_wide.toml)",
            path.display(),
            if cfg.kind == Kind::Nee {
                " (the \"PT, no NEE\" row)"
            } else {
                " (nee = false)"
            }
        );
    }
    Ok(())
}

/// The budgets' size is the width; the scene's aspect sets the height, which the same
/// range bounds (a 1000×10 camera at size 8 rendered an 8×1 image).
fn check_heights(
    cfg: &super::config::Config,
    path: &std::path::Path,
    base: &SceneFile,
) -> Result<()> {
    for (name, b) in [("full", &cfg.full), ("quick", &cfg.quick)] {
        let size = b.size();
        let h = super::measure::height_at(size, &base.camera);
        use crate::bench_render::{MAX_BENCH_SIZE, MIN_BENCH_SIZE};
        if !(MIN_BENCH_SIZE..=MAX_BENCH_SIZE).contains(&h) {
            bail!(
                "{}: its camera's aspect ({} x {}) makes {name}.size = {size} a {size} x \
                 {h} image, and the height, as the width, is allowed [{MIN_BENCH_SIZE}, \
                 {MAX_BENCH_SIZE}] (the figures are measured over 4×4-pixel blocks)",
                path.display(),
                base.camera.width,
                base.camera.height
            );
        }
    }
    Ok(())
}

/// Each density the experiment scales the scene's medium by, checked against the scene
/// file's ranges (`check`) and the object's size.
fn check_densities(
    cfg: &super::config::Config,
    path: &std::path::Path,
    base: &SceneFile,
    eps: f32,
    check: impl Fn(&SceneFile, String) -> Result<()>,
) -> Result<()> {
    // The scene's own medium where no densities scale it (its check came after the
    // renders of the scenes before it).
    let unscaled = [1.0];
    let densities = if cfg.densities.is_empty() {
        &unscaled[..]
    } else {
        &cfg.densities[..]
    };
    for &k in densities {
        let mut f = base.clone();
        scale_density(k)(&mut f);
        check(&f, format!("with density {k}"))?;
        // How dense a medium the object takes depends on its size, which the scene
        // file's ranges cannot know: a density of 1000 on the bunny failed only
        // after the renders at the densities before it.
        render_gpu::setup::check_density(f.medium.sigma_t, eps).map_err(|e| {
            if cfg.densities.is_empty() {
                // A kind that scales nothing: the scene's own sigma_t, whose limit the
                // message gives.
                return anyhow::anyhow!("{}: {e}", path.display());
            }
            let densest = base.medium.sigma_t.iter().copied().fold(0.0, f64::max);
            let most = render_gpu::setup::max_sigma_t(eps);
            anyhow::anyhow!(
                "{}: densities = {k}: {e} ({})",
                path.display(),
                densest_hint(most / densest)
            )
        })?;
    }
    Ok(())
}

fn plot(
    ctx: &Ctx,
    rep: &mut Report,
    file: &str,
    title: &str,
    axes: (&str, &str),
    log: (bool, bool),
    series: &[Series],
) -> Result<()> {
    line_plot(
        &ctx.out.join(file),
        title,
        axes.0,
        axes.1,
        log,
        // (The legend above the lines: in plotters' middle right it hid the paper's
        // k = 8 point and the last point of other curves.)
        series,
    )?;
    ctx.saved_one()?;
    rep.image(title, file);
    Ok(())
}

/// The most density that fits, rounded down to three significant figures (at least one
/// decimal) so that the figure given fits, within the configs' range [0.001, 1000].
fn densest_hint(k_max: f64) -> String {
    if !(k_max >= 0.001) {
        return "no density from the configs' least, 0.001, fits this object".to_string();
    }
    let k_max = k_max.min(1000.0);
    let decimals = (2 - k_max.log10().floor() as i32).max(1) as usize;
    let scale = 10f64.powi(decimals as i32);
    format!(
        "densities up to {:.decimals$} fit this object",
        (k_max * scale).floor() / scale
    )
}

/// A density as file names write it: as typed where that is short (k0.5, k8), else in
/// exponent form (a density of 1e-300 made a name of 300 digits, too long to write).
fn k_name(k: f64) -> String {
    let plain = k.to_string();
    if plain.len() <= 12 {
        plain
    } else {
        format!("{k:e}")
    }
}

fn series(name: &str, points: Vec<(f64, f64)>) -> Series {
    Series::new(name, points)
}

/// The teaser's figures table: its columns, in the order of [`teaser_row`]'s cells.
const TEASER_COLUMNS: [&str; 17] = [
    "density",
    "sigma_t_r",
    "pt_seconds",
    "st_seconds",
    "speedup",
    "var_ratio",
    "var_ratio_se",
    "equal_error_speedup",
    "pt_events_per_path",
    "st_steps_per_path",
    "st_fallback_events_per_path",
    "bias_rmse",
    "bias_upper95",
    "noise_rmse",
    "paper_speedup",
    "pt_paths_per_second",
    "st_paths_per_second",
];

/// The teaser's row for density ×`k` (σ_t `sigma` in the first channel): PT's and
/// ST-CVAE's pairs, their comparison, and the paper's speed-up where the config gives one
/// (without it the cell is empty: it read NaN).
fn teaser_row(
    k: f64,
    sigma: f64,
    pt: &Pair,
    st: &Pair,
    c: &Comparison,
    paper: Option<f64>,
) -> Vec<Cell> {
    vec![
        k.into(),
        sigma.into(),
        pt.seconds.into(),
        st.seconds.into(),
        c.speedup.into(),
        c.var_ratio.into(),
        c.var_ratio_se.into(),
        (c.speedup * c.var_ratio).into(),
        pt.per_path(pt.stats.events).into(),
        st.per_path(st.stats.steps).into(),
        st.per_path(st.stats.events).into(),
        c.bias.into(),
        c.bias_upper95.into(),
        c.noise.into(),
        paper.map_or_else(|| "".into(), Into::into),
        pt.paths_per_second().into(),
        st.paths_per_second().into(),
    ]
}

/// Fig. 1: PT vs ST-CVAE at equal spp along the density ladder.
fn teaser(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    let scene = ctx.cfg.scene_path();
    rep.columns(&TEASER_COLUMNS);
    let mut sp = Vec::new();
    let mut paper = Vec::new();
    let mut times = (Vec::new(), Vec::new());
    let mut figs = Vec::new();
    for (i, &k) in ctx.cfg.densities.iter().enumerate() {
        let edit = scale_density(k);
        let pt = render_pair(ctx, &scene, Pt, &edit)?;
        let st = render_pair(ctx, &scene, Stcvae, &edit)?;
        let c = compare(&pt, &st);
        let exposure = scale_of(&pt.mean) as f32;
        let sigma = SceneFile::load(&scene)?.medium.sigma_t[0] * k;
        let p = ctx.cfg.paper.get(i).copied();
        rep.row(teaser_row(k, sigma, &pt, &st, &c, p));
        sp.push((k, c.speedup));
        if let Some(p) = p.filter(|p| p.is_finite()) {
            paper.push((k, p));
        }
        times.0.push((k, pt.seconds));
        times.1.push((k, st.seconds));
        save(
            ctx,
            &format!("pt_k{}", k_name(k)),
            &pt.mean,
            (pt.spp, (pt.hash, pt.view), &pair_seeds(Pt)),
            exposure,
        )?;
        save(
            ctx,
            &format!("stcvae_k{}", k_name(k)),
            &st.mean,
            (st.spp, (st.hash, st.view), &pair_seeds(Stcvae)),
            exposure,
        )?;
        let both = side_by_side(&[&pt.mean, &st.mean]);
        figs.push((
            k,
            save_picture(ctx, &format!("teaser_k{}", k_name(k)), &both, exposure)?,
        ));
    }
    rep.text(&format!("Both integrators at equal spp; speed-up = PT time / ST-CVAE time; var ratio = PT's per-pixel variance / ST-CVAE's (var_ratio_se: its standard error; heavy-tailed pixels make it swing); bias RMSE is noise-corrected (bias_upper95: {}), in units of PT's brightest 1 % of object pixels. {}Pictures exposed so that PT's 99th-percentile pixel of the frame is 1.\n", super::measure::bias_bound_words(), if ctx.cfg.nee() { "" } else { "Without NEE (most likely as the paper timed its speed-ups): light counted where a path escapes into a light's disk or the environment. " }));
    rep.table();
    for (k, f) in figs {
        rep.image(
            &format!("density ×{k}: PT (left) and ST-CVAE (right), equal spp"),
            &f,
        );
    }
    // teaser_no_nee's plots were titled as teaser's.
    let without = if ctx.cfg.nee() { "" } else { ", without NEE" };
    let mut s = vec![series("stcvae (this run)", sp)];
    if !paper.is_empty() {
        s.push(series("paper (teaser)", paper));
    }
    plot(
        ctx,
        rep,
        "speedup.png",
        &format!("Speed-up over PT at equal spp{without}"),
        ("density multiplier", "speed-up"),
        (true, false),
        &s,
    )?;
    plot(
        ctx,
        rep,
        "time.png",
        &format!("Render time{without}"),
        ("density multiplier", "seconds"),
        (true, true),
        &[series("PT", times.0), series("ST-CVAE", times.1)],
    )
}

/// Fig. 6/7: PT vs ST-CVAE and their difference ×4, front and back lighting, low and high
/// density.
fn quality(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    let scene = ctx.cfg.scene_path();
    rep.columns(&[
        "lighting",
        "density",
        "bias_rmse",
        "bias_upper95",
        "noise_rmse",
        "speedup",
        "var_ratio",
        "var_ratio_se",
        "paper_speedup",
    ]);
    let mut figs = Vec::new();
    for (name, dir) in [("front", [0.3, -0.3, -1.0]), ("back", [0.3, -0.3, 1.0])] {
        for (i, &k) in ctx.cfg.densities.iter().enumerate() {
            let edit = move |f: &mut SceneFile| {
                scale_density(k)(f);
                let irradiance = f.lights.first().map_or([3.0; 3], |l| l.irradiance);
                // One delta light, as the report says: a scene's sun disk (and its other
                // lights) were kept or dropped without a word.
                f.lights = vec![LightDesc {
                    direction: dir,
                    irradiance,
                    angular_diameter_deg: 0.0,
                    ..f.lights.first().cloned().unwrap_or_else(default_light)
                }];
            };
            // With NEE, unlike the paper's Fig. 6/7: the light is a delta light, which paths
            // without NEE never reach (front and back renders were the same picture, lit by
            // the environment alone).
            let pt = render_pair(ctx, &scene, Pt, &edit)?;
            let st = render_pair(ctx, &scene, Stcvae, &edit)?;
            let c = compare(&pt, &st);
            rep.row(vec![
                name.into(),
                k.into(),
                c.bias.into(),
                c.bias_upper95.into(),
                c.noise.into(),
                c.speedup.into(),
                c.var_ratio.into(),
                c.var_ratio_se.into(),
                ctx.cfg
                    .paper
                    .get(i)
                    .copied()
                    .map_or_else(|| "".into(), Into::into),
            ]);
            let exposure = scale_of(&pt.mean) as f32;
            let diff = difference(&pt.mean, &st.mean, 4.0);
            let all = side_by_side(&[&pt.mean, &st.mean, &diff]);
            figs.push((
                name,
                k,
                save_picture(
                    ctx,
                    &format!("quality_{name}_k{}", k_name(k)),
                    &all,
                    exposure,
                )?,
            ));
        }
    }
    rep.text(&format!("Both with NEE (ST-CVAE's through EventGen), unlike the paper's Fig. 6/7: the scene's lights are replaced by one delta light (the first light's irradiance) from the front or the back, which paths without NEE never reach. Noise-corrected bias RMSE of ST-CVAE against PT at equal spp, with {} (in units of PT's brightest 1 % of object pixels). Speed-up = PT time / ST-CVAE time at equal spp; paper_speedup: the paper's, per density (its renders without NEE). Pictures exposed so that PT's 99th-percentile pixel of the frame is 1. The |difference| ×4 panel is the paper's, whose renders had 16,000 spp; at {} spp it is mostly the two renders' noise (most of the object clips), and the table's noise-corrected bias is the measure of their difference.\n", super::measure::bias_bound_words(), 2 * super::measure::half_spp(ctx.budget.spp())));
    rep.table();
    for (name, k, f) in figs {
        rep.image(
            &format!("{name} lighting, density ×{k}: PT, ST-CVAE, |difference| ×4"),
            &f,
        );
    }
    Ok(())
}

fn default_light() -> LightDesc {
    toml::from_str(
        "kind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = [3.0, 3.0, 3.0]",
    )
    .expect("a valid light")
}

/// Fig. 8/9: where the work goes (per-pixel PT events vs sphere steps) and time vs
/// density, for the scene and for a thin-featured object.
fn complexity(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    rep.columns(&[
        "object",
        "density",
        "pt_seconds",
        "st_seconds",
        "speedup",
        "pt_events_per_path",
        "st_steps_per_path",
        "st_exact_steps_per_path",
        "st_exact_walk_events_per_path",
        "st_fallback_events_per_path",
    ]);
    let mut scenes = vec![ctx.cfg.scene_path()];
    scenes.extend(ctx.cfg.scenes.iter().map(|s| ctx.cfg.dir.join(s)));
    let mut figs = Vec::new();
    let mut curves = Vec::new();
    for scene in &scenes {
        let obj = scene
            .file_stem()
            .map_or("scene".into(), |s| s.to_string_lossy().into_owned());
        let (mut tp, mut ts) = (Vec::new(), Vec::new());
        let mut works = Vec::new();
        for &k in &ctx.cfg.densities {
            let edit = scale_density(k);
            let pt: Pair = render_pair(ctx, scene, Pt, &edit)?;
            let st: Pair = render_pair(ctx, scene, Stcvae, &edit)?;
            rep.row(vec![
                obj.clone().into(),
                k.into(),
                pt.seconds.into(),
                st.seconds.into(),
                (pt.seconds / st.seconds.max(1e-9)).into(),
                pt.per_path(pt.stats.events).into(),
                st.per_path(st.stats.steps).into(),
                st.per_path(st.stats.exact_steps).into(),
                st.per_path(st.stats.exact_events).into(),
                st.per_path(st.stats.events).into(),
            ]);
            tp.push((k, pt.seconds));
            ts.push((k, st.seconds));
            // Both devices count the work (a render without counts has none to draw).
            if !pt.work.is_empty() && !st.work.is_empty() {
                let size = (pt.mean.width, pt.mean.height);
                works.push((k, size, pt.work, st.work));
            }
        }
        figs.extend(work_maps(ctx, &obj, works)?);
        curves.push((obj, tp, ts));
    }
    rep.text("Events per path count real scattering events (PT) and sphere steps plus thin-region PT fallback events (ST-CVAE), over all pixels (background included). Of the sphere steps, those of optical radius below exact_tau have their walk simulated exactly (st_exact_steps_per_path), with st_exact_walk_events_per_path scattering events inside them: work the steps column does not show (the work maps count a step as one).\n");
    rep.table();
    for (obj, k, max, f) in figs {
        rep.image(&format!("{obj}, density ×{k}: PT events (left) vs ST-CVAE steps + events (right) per path; grey level log(1 + n) / log(1 + {max:.0}), white = {max:.0}, the most of any density's map (the EXR beside it holds the counts)"), &f);
    }
    let mut s = Vec::new();
    for (obj, tp, ts) in curves {
        s.push(series(&format!("PT, {obj}"), tp));
        s.push(series(&format!("ST-CVAE, {obj}"), ts));
    }
    plot(
        ctx,
        rep,
        "time_vs_density.png",
        "Render time vs density",
        ("density multiplier", "seconds"),
        (true, true),
        &s,
    )
}

/// One density's work counts per path: (density, (width, height), PT's, ST-CVAE's).
type Work = (f64, (usize, usize), Vec<f32>, Vec<f32>);

/// Writes an object's work maps, PT's and ST-CVAE's side by side for each density, all
/// on one scale (each pair's own largest count as white drew k = 1 and k = 8 alike,
/// where PT's work grew 6.6-fold); returns (object, density, that largest count, the
/// PNG's name) for the report.
fn work_maps(ctx: &Ctx, obj: &str, works: Vec<Work>) -> Result<Vec<(String, f64, f32, String)>> {
    let max = works
        .iter()
        .flat_map(|(.., pt, st)| pt.iter().chain(st))
        .cloned()
        .fold(0.0, f32::max);
    let mut figs = Vec::new();
    for (k, (w, h), pt_work, st_work) in works {
        // The EXR holds the counts per path (a reader compares devices or runs by number),
        // the PNG their log scale against the object's largest.
        let counts = |work: &[f32]| {
            let mut img = RgbImage::new(w, h);
            for (p, &n) in img.pixels.iter_mut().zip(work) {
                *p = [n; 3];
            }
            img
        };
        // The gap holds 0 in the EXR (a reader averaging the halves would count a largest
        // value there) and is red in the PNG (grey would read as a level of the shared
        // scale: white, the object's largest count; the pair's own largest before).
        let data = side_by_side_with(&[&counts(&pt_work), &counts(&st_work)], [0.0; 3]);
        let display = side_by_side_with(
            &[
                &work_image(&pt_work, w, h, max),
                &work_image(&st_work, w, h, max),
            ],
            [1.0, 0.0, 0.0],
        );
        let name = format!("work_{obj}_k{}", k_name(k));
        figs.push((
            obj.to_string(),
            k,
            max,
            save_map(ctx, &name, &data, &display)?,
        ));
    }
    Ok(figs)
}

/// Fig. 10: time of PT and ST-CVAE as the absorption 1 − φ doubles.
fn absorption(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    let scene = ctx.cfg.scene_path();
    rep.columns(&[
        "absorption",
        "pt_seconds",
        "st_seconds",
        "speedup",
        "pt_events_per_path",
        "st_steps_per_path",
        "bias_rmse",
        "bias_upper95",
        "noise_rmse",
        "offset_pct",
        "offset_se_pct",
    ]);
    let (mut tp, mut ts) = (Vec::new(), Vec::new());
    for &a in &ctx.cfg.absorptions {
        let edit = absorb(a);
        let pt = render_pair(ctx, &scene, Pt, &edit)?;
        let st = render_pair(ctx, &scene, Stcvae, &edit)?;
        let c = compare(&pt, &st);
        rep.row(vec![
            a.into(),
            pt.seconds.into(),
            st.seconds.into(),
            c.speedup.into(),
            pt.per_path(pt.stats.events).into(),
            st.per_path(st.stats.steps).into(),
            c.bias.into(),
            c.bias_upper95.into(),
            c.noise.into(),
            (100.0 * c.offset().0).into(),
            (100.0 * c.offset().1).into(),
        ]);
        tp.push((a, pt.seconds));
        ts.push((a, st.seconds));
    }
    rep.text(&format!("Albedo φ = 1 − absorption on all channels, equal spp. Bias RMSE is noise-corrected, with {}; offset is ST-CVAE's image total over PT's on the object, minus 1, in %, averaged over the channels, with the mean of the channels' standard errors (offset_se_pct: an upper bound on the average's standard error, as the channels share paths); the bias in units of PT's brightest 1 % of object pixels.\n", super::measure::bias_bound_words()));
    rep.table();
    plot(
        ctx,
        rep,
        "time_vs_absorption.png",
        "Render time vs absorption",
        ("1 − φ", "seconds"),
        (true, true),
        &[series("PT", tp), series("ST-CVAE", ts)],
    )
}

/// Fig. 11/12: the eval plots and tables of the model.
fn distributions(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    let samples = ctx.budget.samples();
    let grid = crate::model_cmds::evaluate_into(ctx.model.as_deref(), &ctx.out, samples, 1)?;
    // Its metrics and plots, written at its end as one set, are this run's first files.
    ctx.saved_one()?;
    // The report's figures are the eval's: so is its warning (in metrics.md only, the
    // report presented the plots of an extrapolation as a fit).
    if let Some(w) = grid.outside {
        ctx.warnings.borrow_mut().push(("distributions".into(), w));
    }
    let max_ks = grid.max_ks;
    rep.columns(&["quantity", "max_ks"]);
    for (q, v) in &max_ks {
        rep.row(vec![(*q).into(), Cell::Num(*v)]);
    }
    // The grid as eval::TAUS, GS and ALBEDOS hold it, minus signs typeset.
    let set = |v: &[f64]| {
        let items: Vec<String> = v.iter().map(|x| format!("{x}").replace('-', "−")).collect();
        format!("{{{}}}", items.join(", "))
    };
    rep.text(&format!(
        "{samples} model samples vs {samples} simulator walks per setting (τ ∈ {} × g ∈ {}, φ ∈ {}); the largest two-sample KS statistic over the grid. Full table: [metrics.md](metrics.md).\n",
        set(&cvae::eval::TAUS),
        set(&cvae::eval::GS),
        set(&cvae::eval::ALBEDOS)
    ));
    rep.table();
    for f in crate::plots::PLOT_FILES {
        if ctx.out.join(f).exists() {
            rep.image(f, f);
        }
    }
    Ok(())
}

/// Fig. 13: equal-time comparison against a converged reference.
fn nee(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    let scene = ctx.cfg.scene_path();
    let none = |_: &mut SceneFile| {};
    let seconds = ctx.budget.seconds();
    let ref_spp = ctx.budget.reference_spp();
    let ref_seed = 99;
    let (reference, (hash, view)) = render_once(
        ctx,
        &scene,
        (Pt, true),
        &none,
        &opts(ref_spp, ref_seed, None),
    )?;
    let exposure = scale_of(&reference.image) as f32;
    save(
        ctx,
        "reference",
        &reference.image,
        (reference.spp, (hash, Some(view)), &[ref_seed]),
        exposure,
    )?;
    rep.columns(&["method", "budget_seconds", "seconds", "spp", "rmse", "mae"]);
    let methods = [
        ("PT, no NEE", Pt, false),
        ("PT, NEE", Pt, true),
        ("ST-CVAE, EventGen NEE", Stcvae, true),
    ];
    let mut curves = Vec::new();
    let mut finals = Vec::new();
    for (name, kind, with_nee) in methods {
        let mut pts = Vec::new();
        for frac in [0.25, 0.5, 1.0] {
            let b = seconds * frac;
            let (o, _) = render_once(
                ctx,
                &scene,
                (kind, with_nee),
                &none,
                // The budget alone ends it, as `render --time-budget` does: a cap of 2^20
                // spp stopped a fast method (a GPU, a small frame) before its time.
                &opts(u32::MAX, 7, Some(b)),
            )?;
            let (e, m) = errors(&reference.image, &o.image);
            rep.row(vec![
                name.into(),
                b.into(),
                o.seconds.into(),
                (o.spp as f64).into(),
                e.into(),
                m.into(),
            ]);
            pts.push((o.seconds, m));
            if frac == 1.0 {
                finals.push(o.image);
            }
        }
        curves.push(series(name, pts));
    }
    rep.text(&format!("Each method renders for the same wall time (the budget; a render stops after the pass in which it ran out); RMSE and mean absolute error (MAE; the plot) over the whole frame (the background, a constant, adds no error but dilutes both) against a PT + NEE reference of {ref_spp} spp, in units where the reference's 99th-percentile pixel is 1 (of its pixels brighter than 1/1,000 of its brightest, the visible background included: about the object's 95th percentile when the background fills most of the frame; the reference's own noise is included). RMSE squares errors and is decided by a few firefly pixels; MAE measures the noise the eye sees.\n"));
    rep.table();
    let refs: Vec<&_> = std::iter::once(&reference.image)
        .chain(finals.iter())
        .collect();
    let f = save_picture(ctx, "equal_time", &side_by_side(&refs), exposure)?;
    rep.image(&format!("reference, then PT without NEE, PT with NEE, ST-CVAE with EventGen NEE at {seconds} s each"), &f);
    plot(
        ctx,
        rep,
        "error_vs_time.png",
        "Error vs time",
        (
            "seconds",
            "mean absolute error (reference's 99th percentile = 1)",
        ),
        (true, true),
        &curves,
    )
}

/// Beyond the paper: speed-up vs the thin-region threshold of the sphere step, for the
/// project's estimator (steps below `exact_tau` simulated exactly) and the authors' (every
/// step drawn from the models: `exact_tau = 0`).
fn fallback(ctx: &Ctx, rep: &mut Report) -> Result<()> {
    let scene = ctx.cfg.scene_path();
    let k = ctx.cfg.densities.first().copied().unwrap_or(1.0);
    rep.columns(&[
        "steps_drawn",
        "min_tau",
        "density",
        "st_seconds",
        "speedup",
        "var_ratio",
        "var_ratio_se",
        "st_steps_per_path",
        "st_exact_steps_per_path",
        "st_exact_walk_events_per_path",
        "st_fallback_events_per_path",
        "bias_rmse",
        "bias_upper95",
        "noise_rmse",
    ]);
    let pt = render_pair(ctx, &scene, Pt, &scale_density(k))?;
    // The scene's exact_tau (the default unless it sets one) against 0. With the default
    // (20) every threshold below it only moves steps between exact walks and PT events:
    // labelled "the authors' behaviour" alone, min_tau = 0 was no model step at all.
    let default_exact = SceneFile::load(&scene)?.render.exact_tau_or_default();
    let mut modes = vec![(
        format!(
            "models above exact_tau = {}",
            crate::progress::significant4(default_exact)
        ),
        None,
    )];
    // A scene of exact_tau = 0 is the authors' mode already: not rendered twice.
    if default_exact > 0.0 {
        modes.push(("models at every step (exact_tau = 0)".to_owned(), Some(0.0)));
    }
    let mut curves = Vec::new();
    for (label, exact_tau) in &modes {
        let mut sp = Vec::new();
        for &t in &ctx.cfg.thresholds {
            let exact_tau = *exact_tau;
            let edit = move |f: &mut SceneFile| {
                scale_density(k)(f);
                f.render.min_tau = Some(t);
                if exact_tau.is_some() {
                    f.render.exact_tau = exact_tau;
                }
            };
            let st = render_pair(ctx, &scene, Stcvae, &edit)?;
            let c = compare(&pt, &st);
            rep.row(vec![
                label.clone().into(),
                t.into(),
                k.into(),
                st.seconds.into(),
                c.speedup.into(),
                c.var_ratio.into(),
                c.var_ratio_se.into(),
                st.per_path(st.stats.steps).into(),
                st.per_path(st.stats.exact_steps).into(),
                st.per_path(st.stats.exact_events).into(),
                st.per_path(st.stats.events).into(),
                c.bias.into(),
                c.bias_upper95.into(),
                c.noise.into(),
            ]);
            sp.push((t, c.speedup));
        }
        curves.push((label.clone(), sp));
    }
    // A log axis cannot show 0: it is drawn a decade below the smallest positive
    // threshold, at most at 0.01 (every threshold below 0.01 was drawn at 0.01 with it).
    let smallest = ctx
        .cfg
        .thresholds
        .iter()
        .copied()
        .filter(|&t| t > 0.0)
        .fold(f64::INFINITY, f64::min);
    let zero_at = (smallest / 10.0).min(0.01);
    for (_, sp) in &mut curves {
        for p in sp.iter_mut() {
            if p.0 == 0.0 {
                p.0 = zero_at;
            }
        }
    }
    rep.text(&format!("Points where σ_t·r < min_tau take an ordinary PT event instead of a sphere step; a step of optical radius below exact_tau has its walk simulated exactly, above it drawn from the models. The authors draw every step from the models, however thin the free region: min_tau = 0 with exact_tau = 0. With the scene's exact_tau ({}) every threshold below it only trades exact walks for PT events. Speed-up against PT at equal spp; min_tau = 0 is drawn at {}. Steps per path count both kinds of step (the exact ones also apart, with the scattering events simulated inside them), over all pixels. Bias RMSE is noise-corrected, with {}.\n", crate::progress::significant4(default_exact), crate::progress::significant4(zero_at), super::measure::bias_bound_words()));
    rep.table();
    let s: Vec<_> = curves.into_iter().map(|(l, sp)| series(&l, sp)).collect();
    plot(
        ctx,
        rep,
        "speedup_vs_min_tau.png",
        "Speed-up vs thin-region threshold",
        (
            &format!(
                "min_tau (0 drawn at {})",
                crate::progress::significant4(zero_at)
            ),
            "speed-up over PT",
        ),
        (true, false),
        &s,
    )
}

#[cfg(test)]
mod tests {
    /// The shipped configs' densities keep their names; extreme ones get short names.
    #[test]
    fn density_names_stay_short() {
        for (k, name) in [(1.0, "1"), (8.0, "8"), (0.5, "0.5"), (1.0e-300, "1e-300")] {
            assert_eq!(super::k_name(k), name);
        }
        assert!(super::k_name(1e300).len() <= 12);
    }

    /// The density given as the most that fits is rounded down (0.99996 is not "1.000"),
    /// to three significant figures, and stays within the configs' range.
    #[test]
    fn the_densest_hint_rounds_down() {
        for (k, shown) in [
            (259.95, "259.9"),
            (1.0, "1.00"),
            (0.99996, "0.999"),
            (0.012345, "0.0123"),
            (5e4, "1000.0"),
        ] {
            assert_eq!(
                super::densest_hint(k),
                format!("densities up to {shown} fit this object")
            );
        }
        assert!(super::densest_hint(5e-4).starts_with("no density"));
        assert!(super::densest_hint(f64::NAN).starts_with("no density"));
    }

    /// The teaser's equal-error speed-up is the time ratio times the variance ratio (PT's
    /// time × variance over ST-CVAE's, the work each needs for one error): speed-up 3 and
    /// variance ratio 0.5 give 1.5 (3 / 0.5 would give 6), in the column the header names,
    /// and the row has a cell for every column.
    #[test]
    fn the_equal_error_speedup_is_the_speedup_times_the_variance_ratio() {
        use super::{Cell, Comparison, Pair, TEASER_COLUMNS, teaser_row};
        let pair = |seconds| Pair {
            mean: render_gpu::image_io::RgbImage::new(1, 1),
            var: vec![[1e-3; 3]],
            seconds,
            stats: render_gpu::integrator::PathStats {
                paths: 10,
                events: 40,
                steps: 5,
                ..Default::default()
            },
            work: vec![1.0],
            spp: 2,
            hash: 0,
            view: None,
        };
        let c = Comparison {
            speedup: 3.0,
            var_ratio: 0.5,
            var_ratio_se: 0.1,
            bias: 0.0,
            bias_upper95: None,
            noise: 0.01,
            channel_bias: [0.0; 3],
            channel_offset: [(0.0, 0.01); 3],
            block_chi2: 1.0,
            blocks: 0,
            block_null: (1.0, 0.0),
        };
        let row = teaser_row(1.0, 20.0, &pair(6.0), &pair(2.0), &c, None);
        assert_eq!(row.len(), TEASER_COLUMNS.len());
        let at = TEASER_COLUMNS
            .iter()
            .position(|&h| h == "equal_error_speedup")
            .unwrap();
        match &row[at] {
            Cell::Num(v) => assert!((v - 1.5).abs() < 1e-12, "{v}"),
            Cell::Text(t) => panic!("a number, not {t:?}"),
        }
    }

    /// The absorption experiment renders at albedo φ = 1 − a on every channel (a, the
    /// absorption, is what its config lists): a = 1/32 gives [31/32; 3], exact in binary,
    /// whatever the scene's own albedo (the sphere scene's [0.999, 0.99, 0.95]).
    #[test]
    fn an_absorption_sets_the_albedo_to_one_minus_it() {
        let path = std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/scenes/sphere.toml"
        ));
        let mut f = render_gpu::scene::SceneFile::load(path).unwrap();
        assert_eq!(f.medium.albedo, [0.999, 0.99, 0.95]);
        super::absorb(1.0 / 32.0)(&mut f);
        assert_eq!(f.medium.albedo, [31.0 / 32.0; 3]);
    }

    /// Two scenes of one file stem are refused wherever they stand in the list (their
    /// images, named after the stem, would overwrite each other): here the first and the
    /// third of a complexity config's scenes, with another stem between them. Scenes of
    /// distinct stems pass.
    #[test]
    fn two_scenes_of_one_stem_are_refused_wherever_they_are_listed() {
        let cfg: super::super::config::Config = toml::from_str(
            "kind = \"complexity\"\ntitle = \"t\"\nscene = \"a/bunny.toml\"\n\
             scenes = [\"torus_knot.toml\", \"b/bunny.toml\"]\ndensities = [1.0]\n\
             [full]\nsize = 8\nspp = 2\n[quick]\nsize = 8\nspp = 2\n",
        )
        .unwrap();
        let scenes = super::scene_paths(&cfg);
        assert_eq!(scenes.len(), 3, "{scenes:?}");
        let e = super::check_names(&cfg, &scenes).unwrap_err();
        assert!(
            e.to_string().contains("two scenes share a file name"),
            "{e}"
        );
        let distinct: Vec<std::path::PathBuf> = ["a/bunny.toml", "torus_knot.toml", "sphere.toml"]
            .into_iter()
            .map(std::path::PathBuf::from)
            .collect();
        super::check_names(&cfg, &distinct).unwrap();
    }
}
