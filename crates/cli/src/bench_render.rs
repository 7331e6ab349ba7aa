//! `stcvae bench render`: the authors' teaser ladder, PT vs ST-CVAE side by side.
//!
//! Each integrator renders the same image twice with independent seeds (half the spp
//! each). The halves give every pixel's variance of the mean, Var ≈ (A₁ − A₂)²/4, so
//! the bias RMSE can be corrected for noise: RMSE² = mean((A − B)²) − mean(Var_A + Var_B).
//! Images are scaled so that the 99th percentile of PT's object pixels is 1.

use std::path::PathBuf;

use anyhow::{Result, anyhow, bail};
use render_gpu::integrator::IntegratorKind;
use render_gpu::render::RenderOptions;

use crate::device::{DeviceArg, Engine};
use crate::experiment::measure::{
    BLOCK, MIN_BLOCK_DOF, Pair, block_z, compare, half_spp, pair_seeds,
};
use crate::progress::significant4;
use crate::render::prepare;

#[derive(clap::Args)]
pub struct Args {
    /// Scene the ladder scales: its medium is replaced by the teaser's (σ_t = k·(150, 187.5,
    /// 125), albedo (0.99999, 0.99995, 0.975), g = 0.875); camera, object, lights and
    /// render settings are kept.
    #[arg(long, default_value = crate::render::DEFAULT_SCENE,
          value_parser = crate::shipped::scene_arg(crate::render::DEFAULT_SCENE))]
    scene: PathBuf,
    /// Density multipliers (each in [0.001, 1000]).
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8", value_parser = parse_k)]
    k: Vec<f64>,
    /// Samples per pixel of each integrator, 2 to 2^30: each of two seeds renders half
    /// (rounded down), rounded up to a multiple of 3 (one per hero channel), so 2 renders 6
    /// and 13 renders 12.
    #[arg(long, allow_negative_numbers = true, default_value_t = 16,
          value_parser = crate::whole::whole::<u32>(2, MAX_BENCH_SPP as u64))]
    spp: u32,
    /// Image side in pixels, 8 to 4,096 (at least 8: the bias is measured over 4×4-pixel
    /// blocks and the object's pixels, which a smaller image hardly has).
    #[arg(long, allow_negative_numbers = true, default_value_t = 64,
          value_parser = crate::whole::whole::<u32>(MIN_BENCH_SIZE as u64, MAX_BENCH_SIZE as u64))]
    size: u32,
    /// Model file for ST-CVAE (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    model: Option<PathBuf>,
    /// Thin-region threshold of ST-CVAE, an optical radius in [0, 1e6] (overrides the
    /// scene's).
    #[arg(long, allow_negative_numbers = true)]
    min_tau: Option<f64>,
    /// Largest sphere step of ST-CVAE, an optical radius in (0, the model's training
    /// maximum] (overrides the scene's).
    #[arg(long, allow_negative_numbers = true)]
    max_tau: Option<f64>,
    /// Representative events (EventGen draws) per model-drawn sphere step for NEE, 1 to
    /// 64 (overrides the scene's).
    #[arg(long)]
    nee_samples: Option<u32>,
    /// NEE events per exactly simulated sphere step, 1 to 4 (overrides the scene's).
    #[arg(long)]
    exact_nee_samples: Option<u32>,
    /// ST-CVAE's shadow rays per path, 0 to 2 (overrides the scene's; 0: one at every NEE
    /// event, as PT).
    #[arg(long)]
    path_nee_rays: Option<u32>,
    /// Below this optical radius ST-CVAE simulates a sphere step's walk exactly instead of
    /// drawing it from the models (overrides the scene's; in [0, 50]; 0: always the
    /// models).
    #[arg(long, allow_negative_numbers = true)]
    exact_tau: Option<f64>,
    /// Next-event estimation in both integrators. `false` counts only paths that escape
    /// into a light's disk or the environment, which takes EventGen out of ST-CVAE and
    /// so tells its error from LengthGen's and PathGen's (give a scene whose light has an
    /// angular diameter, e.g. configs/scenes/bunny_sun_wide.toml). Default: the scene's
    /// `nee` (on in the shipped scenes but bunny_sun_wide.toml).
    #[arg(long, action = clap::ArgAction::Set)]
    nee: Option<bool>,
    /// Where both integrators run: auto, gpu (any wgpu adapter) or cpu.
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    device: DeviceArg,
    /// Also write each density's images to this folder: kK_pt and kK_stcvae (EXR + PNG,
    /// the two seeds' mean) and kK_z.png, where the bias lies: per channel and 4×4-pixel
    /// block (measure::block_z), the z-score of ST-CVAE − PT against both noises, drawn
    /// as grey level 0.5 + z/8 (mid-grey 128: agreement, or a block whose noise estimate
    /// is too poor to judge: the background and silhouette blocks of a few noisy pixels;
    /// brighter: ST-CVAE brighter; |z| > 3 is rarely noise), and kK_pixels.csv: per pixel
    /// and channel both means and the variances of those means.
    #[arg(long)]
    save: Option<PathBuf>,
    /// Reuse PT's renders: each density's PT pair (both seeds, time, statistics) is read
    /// from this folder when an earlier run with the same scene, size, spp, PT settings,
    /// device and binary stored it there, and stored there otherwise. PT is most of the bench's time at
    /// high density, and comparing ST-CVAE models or settings needs it once. Speed-ups
    /// then use the stored PT time, from the run that measured it (the table says which).
    #[arg(long)]
    pt_cache: Option<PathBuf>,
    /// Which set of seeds: set N renders PT with seeds 11 + 4N and 12 + 4N and ST-CVAE with
    /// 13 + 4N and 14 + 4N (always four different ones). Another set is another
    /// realisation of the same comparison: at 1,024 spp the variance ratio moves by
    /// ±0.05–0.1 between sets (rare heavy paths), the bias estimate by its noise. At most
    /// 4,611,686,018,427,387,900, where 14 + 4N still fits a 64-bit seed.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0,
          value_parser = crate::whole::whole::<u64>(0, MAX_SEED_SET))]
    seeds: u64,
}

/// The largest set of seeds whose four seeds (up to 14 + 4N) do not wrap around.
const MAX_SEED_SET: u64 = (u64::MAX - 14) / 4;

impl Args {
    /// The two seeds of `kind` in this run's set.
    fn seeds_of(&self, kind: IntegratorKind) -> [u64; 2] {
        pair_seeds(kind).map(|s| s + 4 * self.seeds)
    }
}

/// A saved image's stem for density k (`name`: "pt" or "stcvae"), the z map and the pixel
/// table: the names `save_images` writes, one place for them and for `run`'s checks.
fn saved_stem(dir: &std::path::Path, k: f64, name: &str) -> std::path::PathBuf {
    dir.join(format!("k{k}_{name}"))
}

fn saved_z(dir: &std::path::Path, k: f64) -> std::path::PathBuf {
    dir.join(format!("k{k}_z.png"))
}

fn saved_pixels(dir: &std::path::Path, k: f64) -> std::path::PathBuf {
    dir.join(format!("k{k}_pixels.csv"))
}

/// Every file `save_images` writes for density k.
fn saved_files(dir: &std::path::Path, k: f64) -> Vec<std::path::PathBuf> {
    let mut files: Vec<_> = ["pt", "stcvae"]
        .iter()
        .flat_map(|n| {
            let stem = saved_stem(dir, k, n);
            ["exr", "png"].map(|e| crate::merge::image_out(&stem, e))
        })
        .collect();
    files.push(saved_z(dir, k));
    files.push(saved_pixels(dir, k));
    files
}

/// Writes the ladder step's images into `dir` (see `Args::save`) as one set: a failure
/// part way (a full disk at the pixel table, several GB at 4,096²) leaves the step's six
/// files as they were, all of an earlier run or none, never new images beside an earlier
/// run's z map and pixel table of other seeds or spp (and it removed the earlier run's).
fn save_images(a: &Args, dir: &std::path::Path, k: f64, pt: &Pair, st: &Pair) -> Result<()> {
    use render_gpu::image_io::{RenderTag, RgbImage, encode_exr, encode_png};
    use scatter_sim::output::Contents;
    // `run` checked `dir` before rendering; the set's writer makes it.
    let exposure = crate::experiment::measure::scale_of(&pt.mean) as f32;
    let mut images: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    for (name, p, kind) in [
        ("pt", pt, IntegratorKind::Pt),
        ("stcvae", st, IntegratorKind::Stcvae),
    ] {
        // A fractional k ("k0.5_pt") keeps its tail: `image_out` only replaces a typed
        // .exr, .png or .json, so the two integrators' images cannot overwrite each other.
        let tag = RenderTag {
            spp: p.spp as u64,
            scene_hash: p.hash,
            // The mean of the pair's two seeds (a cached PT pair was rendered with the
            // same ones): merge then knows them, where it compared pixels only.
            seeds: a.seeds_of(kind).to_vec(),
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: p.view,
        };
        let stem = saved_stem(dir, k, name);
        let exr = crate::merge::image_out(&stem, "exr");
        let png = crate::merge::image_out(&stem, "png");
        let exr_bytes = encode_exr(&p.mean, &tag).map_err(|e| anyhow!("{}: {e}", exr.display()))?;
        let png_bytes =
            encode_png(&p.mean, exposure).map_err(|e| anyhow!("{}: {e}", png.display()))?;
        images.extend([(exr, exr_bytes), (png, png_bytes)]);
    }
    let (w, h) = (pt.mean.width, pt.mean.height);
    let mut z = RgbImage::new(w, h);
    let blocks_x = w.div_ceil(BLOCK);
    let zs = block_z(pt, st);
    for (i, p) in z.pixels.iter_mut().enumerate() {
        let (x, y) = (i % w, i / w);
        let block = zs[(y / BLOCK) * blocks_x + x / BLOCK];
        *p = block.map(|v| v.map_or(0.5, |v| (0.5 + v / 8.0).clamp(0.0, 1.0) as f32));
    }
    let z_path = saved_z(dir, k);
    let z_bytes = render_gpu::image_io::encode_png_linear(&z)
        .map_err(|e| anyhow!("{}: {e}", z_path.display()))?;
    images.push((z_path, z_bytes));
    // Per pixel and channel, both pairs' means and the variances of those means (from
    // their two seeds): what the bias columns are computed from, for analyses the table
    // does not make (where in the image a bias lies, other pixel classes or metrics).
    // Streamed into its temporary: held as one string, a 4,096² table took ~3.5 GB.
    let table = saved_pixels(dir, k);
    let write_table: Contents = Box::new(|csv| {
        writeln!(csv, "x,y,channel,pt_mean,pt_var,stcvae_mean,stcvae_var")?;
        for i in 0..w * h {
            for c in 0..3 {
                writeln!(
                    csv,
                    "{},{},{c},{:e},{:e},{:e},{:e}",
                    i % w,
                    i / w,
                    pt.mean.pixels[i][c],
                    pt.var[i][c],
                    st.mean.pixels[i][c],
                    st.var[i][c]
                )?;
            }
        }
        Ok(())
    });
    let mut files: Vec<(&std::path::Path, Contents)> = images
        .iter()
        .map(|(path, bytes)| {
            let write: Contents = Box::new(move |f| f.write_all(bytes));
            (path.as_path(), write)
        })
        .collect();
    files.push((&table, write_table));
    scatter_sim::output::write_atomic_set_streamed(files)
        .map_err(|(path, e)| anyhow!("cannot write {}: {e}", path.display()))
}

/// A density given twice in `--k` would be measured twice and tabled as two rows (an
/// experiment's `densities` refuses it too).
pub(crate) fn reject_repeats(k: &[f64]) -> Result<()> {
    for (i, x) in k.iter().enumerate() {
        if k[..i].contains(x) {
            anyhow::bail!("--k lists {x} twice: give each density once");
        }
    }
    Ok(())
}

/// A density multiplier of `--k`: a number in [0.001, 1000]. Thinner than a thousandth of
/// the scene's medium, the object is all but transparent (the default bunny's optical
/// size falls below 0.2) and the table's ratios are of nothing: a k of 1e-300 printed
/// 300-digit densities and "± NaN %".
pub(crate) fn parse_k(s: &str) -> Result<f64, String> {
    let k: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    if (0.001..=1000.0).contains(&k) {
        Ok(k)
    } else {
        Err(format!(
            "{} is out of range: allowed [0.001, 1000]",
            s.trim()
        ))
    }
}

/// PT's pair at density k: from `--pt-cache` when stored there, else rendered (and stored).
/// The second value says when a stored pair was measured. `identity`: the cache's
/// [`crate::pt_cache::identity`] of this run.
fn pt_pair(
    a: &Args,
    engine: &Engine,
    k: f64,
    identity: Option<&str>,
) -> Result<(Pair, Option<u64>)> {
    let (Some(dir), Some(id)) = (&a.pt_cache, identity) else {
        return Ok((run_pair(a, engine, IntegratorKind::Pt, k)?, None));
    };
    let p = prepare_k(a, IntegratorKind::Pt, k)?;
    let spp = 2 * half_spp(a.spp);
    let file = crate::pt_cache::path(dir, k, p.data.hash, spp, id);
    let size = (p.data.camera.width, p.data.camera.height);
    match crate::pt_cache::load(&file, p.data.hash, spp, size, id) {
        Ok(Some((mut pair, when))) => {
            // The scene hash it was stored under covers everything the view hash does.
            pair.view = Some(p.data.view_hash);
            return Ok((pair, Some(when)));
        }
        Ok(None) => {}
        Err(e) if crate::pt_cache::is_damaged(&e) => {
            eprintln!("note: {e:#}: PT at k = {k} is rendered again and stored in its place");
        }
        Err(e) => return Err(e),
    }
    let pair = render_pair(a, engine, &p, IntegratorKind::Pt)?;
    // The render stands whether or not it can be kept for the next run.
    match crate::pt_cache::store(&file, &pair, id) {
        Ok(true) => {}
        Ok(false) => eprintln!(
            "warning: PT's render at k = {k} cannot be stored (a non-finite or out-of-range \
             value, or no measured time); not stored in {}",
            dir.display()
        ),
        Err(e) => eprintln!(
            "warning: PT's render at k = {k} not stored in {}: {e:#}",
            dir.display()
        ),
    }
    Ok((pair, None))
}

fn run_pair(a: &Args, engine: &Engine, kind: IntegratorKind, k: f64) -> Result<Pair> {
    let p = prepare_k(a, kind, k)?;
    render_pair(a, engine, &p, kind)
}

/// The bench's scene at density k for one integrator.
fn prepare_k(a: &Args, kind: IntegratorKind, k: f64) -> Result<crate::render::Prepared> {
    prepare(&a.scene, Some(kind), a.nee, a.model.as_deref(), |f| {
        ladder_scene(a, kind, k, f)
    })
    .map_err(|e| {
        // The medium is the ladder's, not the file's: say which flag made it.
        if format!("{e:#}").contains("medium.sigma_t") {
            e.context(format!(
                "--k {k}: the ladder's sigma_t is k × {LADDER_SIGMA_T:?}"
            ))
        } else {
            e
        }
    })
}

/// The teaser's medium at k = 1 (configs/scenes/bunny.toml's, which `experiment teaser`
/// reads; tested equal), which the ladder scales by k.
const LADDER_SIGMA_T: [f64; 3] = [150.0, 187.5, 125.0];
const LADDER_ALBEDO: [f64; 3] = [0.99999, 0.99995, 0.975];
const LADDER_G: f64 = 0.875;

/// The ladder's medium at density k, the bench's size and (ST-CVAE only) the command's
/// overrides of its settings.
fn ladder_scene(a: &Args, kind: IntegratorKind, k: f64, f: &mut render_gpu::scene::SceneFile) {
    f.medium.sigma_t = LADDER_SIGMA_T.map(|s| s * k);
    f.medium.albedo = LADDER_ALBEDO;
    f.medium.g = LADDER_G;
    f.camera.width = a.size;
    f.camera.height = a.size;
    // ST-CVAE's own settings: PT ignores them, and leaving them out of PT's scene
    // keeps its hash, so `--pt-cache` serves runs that compare them.
    if matches!(kind, IntegratorKind::Stcvae) {
        if let Some(t) = a.min_tau {
            f.render.min_tau = Some(t);
        }
        if a.max_tau.is_some() {
            f.render.max_tau = a.max_tau;
        }
        if let Some(m) = a.nee_samples {
            f.render.nee_samples = m;
        }
        if let Some(m) = a.exact_nee_samples {
            f.render.exact_nee_samples = m;
        }
        if let Some(m) = a.path_nee_rays {
            f.render.path_nee_rays = m;
        }
        if a.exact_tau.is_some() {
            f.render.exact_tau = a.exact_tau;
        }
    }
}

/// Renders the two seeds of `kind` (half the spp each) and pairs them.
fn render_pair(
    a: &Args,
    engine: &Engine,
    p: &crate::render::Prepared,
    kind: IntegratorKind,
) -> Result<Pair> {
    let set = p.settings();
    // Ctrl-C stops the render after its pass and the bench there: a cut-short render is
    // never measured, and the temporaries of a cache entry or image being written are
    // removed (a local flag let the signal kill the process, leaving them).
    let cancel = crate::interrupt::flag();
    let half = half_spp(a.spp);
    let cam = &p.file.camera;
    // The renderer compiles its kernel before its clock starts, but a hardware GPU idle
    // through the CPU's preparation runs its first timed render slower: untimed work
    // first, as in `bench devices`.
    engine.warm_up(&p.data, &set, half, a.seeds_of(kind)[0], cancel)?;
    if crate::interrupt::requested() {
        bail!("interrupted: the rows printed so far stand; nothing more was measured");
    }
    let mut outs = Vec::new();
    for seed in a.seeds_of(kind) {
        let label = format!(
            "σ_t {:?}, {}, seed {seed}",
            p.file.medium.sigma_t,
            kind.name()
        );
        let opts = RenderOptions {
            spp: half,
            seed,
            time_budget: None,
            variance: false,
        };
        let pb = crate::progress::render_bar(&label, cam.width as u64 * cam.height as u64, &opts);
        let o = engine.render(
            &p.data,
            &set,
            &opts,
            &|done, _| pb.set_position(done),
            cancel,
        );
        pb.finish_and_clear();
        outs.push(o?);
        if crate::interrupt::requested() {
            bail!("interrupted: the rows printed so far stand; nothing more was measured");
        }
    }
    let b = outs.pop().expect("two renders");
    let a_out = outs.pop().expect("two renders");
    let pair = Pair::from_halves(a_out, b, (p.data.hash, p.data.view_hash));
    // Every column compares the object's pixels, found by their noise: with none the
    // variance ratio was 0/0 printed as 0, and a bias of 0 read as a pass.
    if !pair.has_noise() {
        bail!(
            "{}: no pixel differs between the two {} renders: the object is out of view, \
             unlit or black, so there is nothing to measure (check the scene's camera, lights \
             and medium)",
            a.scene.display(),
            kind.name()
        );
    }
    Ok(pair)
}

/// Bytes a pixel the bench holds beside a render's own ([`render_gpu::render::BYTES_PER_PIXEL`]):
/// two pairs of mean (12), variance (24) and work (4), and the two renders a pair is
/// made from (image 12 and work 4 each).
const PAIRS_BYTES_PER_PIXEL: u64 = 2 * (12 + 24 + 4) + 2 * (12 + 4);

/// The image sides the bias is measured on, here and in the experiments' budgets: at
/// least 8, since it is measured over 4×4-pixel blocks and the object's pixels, which a
/// smaller image hardly has.
pub(crate) const MIN_BENCH_SIZE: u32 = 8;
pub(crate) const MAX_BENCH_SIZE: u32 = 4096;

/// Most samples a pixel the bench takes (the header's pair arithmetic is u32).
pub(crate) const MAX_BENCH_SPP: u32 = 1 << 30;

pub fn run(a: Args) -> Result<()> {
    // The overrides are checked before anything runs, and blamed on the command line
    // rather than on the scene file they are applied to.
    reject_repeats(&a.k)?;
    let scene = render_gpu::scene::SceneFile::load(&a.scene)?;
    check_options(&a, &scene)?;
    let engine = Engine::open(a.device)?.without_fallback();
    if engine.is_gpu() {
        crate::device::check_gpu_lights(&a.scene, scene.lights.len(), ": use --device cpu")?;
    }
    // The render's buffers and the bench's own (both pairs and a pair's two renders), as
    // `render` and `bench devices` check: --size 4096 under a memory limit aborted with
    // "memory allocation … failed" instead of a line.
    render_gpu::render::check_image_memory_with(a.size, a.size, PAIRS_BYTES_PER_PIXEL)
        .map_err(|e| anyhow::anyhow!("--size {}: {e}", a.size))?;
    check_densities(&a, &engine)?;
    let identity = match &a.pt_cache {
        // The set of seeds is part of what a stored pair depends on.
        Some(_) => Some(format!(
            "{} / seed set {}",
            crate::pt_cache::identity(&engine.describe())?,
            a.seeds
        )),
        None => None,
    };
    check_stored_pairs(&a, identity.as_deref())?;
    check_saved_files(&a, &scene)?;
    print_head(&a, &scene, &engine);
    // The folders --save makes (none yet: the first saved file makes them), so that a run
    // whose saving fails leaves none of them empty, as other commands' failed writes do.
    let save_made: Vec<PathBuf> = a.save.as_deref().map_or_else(Vec::new, |dir| {
        dir.ancestors()
            .take_while(|d| !d.as_os_str().is_empty() && !d.exists())
            .map(PathBuf::from)
            .collect()
    });
    for &k in &a.k {
        let (pt, cached) = pt_pair(&a, &engine, k, identity.as_deref())?;
        let st = run_pair(&a, &engine, IntegratorKind::Stcvae, k)?;
        let c = compare(&pt, &st);
        if let Some(dir) = &a.save {
            save_images(&a, dir, k, &pt, &st).inspect_err(|_| {
                // Deepest first; one that holds anything (an earlier density's files)
                // stays, and so do its parents.
                for d in &save_made {
                    if std::fs::remove_dir(d).is_err() {
                        break;
                    }
                }
            })?;
        }
        print_row(k, &pt, &st, &c, cached);
    }
    println!(
        "speed-up = PT time / ST-CVAE time at equal spp; var ratio = PT variance / ST-CVAE variance; \
         equal-error = their product (time ratio to reach the same noise); PT ev/path = scattering events \
         a path, ST st/path and ev/path = ST-CVAE's sphere steps and PT events (thin regions) a path; \
         noise = the RMSE the two renders' noise alone gives; bias RMSE is noise-corrected \
         (bias 95%: its one-sided 95% upper confidence bound, from a negative estimate raised to 0; \
         n/a: not resolved, where fewer than {} object pixels carry a term, as in sparse renders), \
         images scaled so PT's brightest 1% of object pixels is 1",
        crate::experiment::measure::MIN_BIAS_TERMS
    );
    Ok(())
}

/// The ladder's overrides of the scene, --max-tau and --min-tau against the model, and
/// the output folders.
fn check_options(a: &Args, scene: &render_gpu::scene::SceneFile) -> Result<()> {
    for &k in &a.k {
        let mut f = scene.clone();
        ladder_scene(a, IntegratorKind::Stcvae, k, &mut f);
        if let Err(e) = f.validate() {
            bail!(
                "{e} (set by this command's options, applied to {})",
                a.scene.display()
            );
        }
    }
    if let Some(t) = a.max_tau {
        let m = crate::model_cmds::load_model(a.model.as_deref())?;
        if crate::model_cmds::beyond_trained_tau(t, &m) {
            bail!(
                "--max-tau {t} is beyond the model's training range {}",
                crate::model_cmds::training_range(m.training.tau_range)
            );
        }
    } else if let Some(t) = a.min_tau {
        // Without --max-tau the cap is the model's: a threshold above it leaves no step.
        let m = crate::model_cmds::load_model(a.model.as_deref())?;
        if crate::model_cmds::default_max_tau(t, &m).is_none() {
            bail!(
                "--min-tau {} is above the model's training maximum {} (the default \
                 --max-tau): no sphere step could be taken",
                scatter_sim::ranges::num(t),
                scatter_sim::ranges::num(crate::model_cmds::trained_max_tau(&m) as f32)
            );
        }
    }
    // Checked before any rendering, so that a long bench does not fail at its end.
    if let Some(dir) = &a.save {
        if dir.exists() && !dir.is_dir() {
            bail!("--save {}: exists and is not a directory", dir.display());
        }
        // Checked, not made: the first saved file makes it (an interrupted bench left an
        // empty folder).
        crate::check_out_dir("--save", dir)?;
    }
    // So is the PT cache's directory: PT's renders are the long part of a bench, and a
    // cache that cannot take them should say so before they run.
    if let Some(dir) = &a.pt_cache {
        crate::check_out_dir("--pt-cache", dir)?;
    }
    Ok(())
}

/// Every density's ST-CVAE scene, checked before the table's head and the first render.
fn check_densities(a: &Args, engine: &Engine) -> Result<()> {
    // Every density's ST-CVAE scene is checked before the table's head and the first
    // render, so that a bad setting or model fails at once, not after PT's (possibly long)
    // renders. They are prepared again when rendered (well under a second each, the grid
    // coming from its disk cache) rather than kept: each holds its own copy of the
    // distance grid.
    for (i, &k) in a.k.iter().enumerate() {
        let p = prepare_k(a, IntegratorKind::Stcvae, k)?;
        if i == 0 {
            crate::render::note_lights(&p);
        }
        // A software adapter keeps its path state in host memory (ST-CVAE's, with its
        // NEE reservoirs, is the larger of the two integrators'), beside the bench's own.
        if engine.is_gpu() && !engine.is_hardware_gpu() {
            crate::render::software_gpu_memory(
                a.size,
                a.size,
                &p.settings(),
                false,
                PAIRS_BYTES_PER_PIXEL,
            )
            .map_err(|e| anyhow::anyhow!("--size {}: {e}", a.size))?;
        }
    }
    Ok(())
}

/// Every density's stored PT pair, read before the first render.
fn check_stored_pairs(a: &Args, identity: Option<&str>) -> Result<()> {
    // Every density's stored PT pair is read once before the first render, so that one
    // that cannot be read (a directory, no permission) fails now, not after the densities
    // before it have rendered. A damaged one is rendered again in its turn, with a note.
    if let (Some(dir), Some(id)) = (&a.pt_cache, identity) {
        let spp = 2 * half_spp(a.spp);
        for &k in &a.k {
            let p = prepare_k(a, IntegratorKind::Pt, k)?;
            let file = crate::pt_cache::path(dir, k, p.data.hash, spp, id);
            let size = (p.data.camera.width, p.data.camera.height);
            if let Err(e) = crate::pt_cache::load(&file, p.data.hash, spp, size, id)
                && !crate::pt_cache::is_damaged(&e)
            {
                return Err(e);
            }
        }
    }
    Ok(())
}

/// The files `--save` writes for every density, checked before the first render.
fn check_saved_files(a: &Args, scene: &render_gpu::scene::SceneFile) -> Result<()> {
    // So are the files `--save` writes for every density (one that is a directory failed
    // the run after that density's renders).
    if let Some(dir) = &a.save {
        let mut inputs = crate::render::scene_inputs(&a.scene, scene);
        let model = crate::model_cmds::model_path(a.model.as_deref());
        inputs.push(("the model".to_string(), model));
        for &k in &a.k {
            for f in saved_files(dir, k) {
                crate::check_out("--save", &f)?;
                crate::paths::check_not_input("--save", &f, &inputs)?;
            }
        }
    }
    Ok(())
}

/// The bench's title line and the table's head.
fn print_head(a: &Args, scene: &render_gpu::scene::SceneFile, engine: &Engine) {
    // The scene's own setting unless --nee gives one.
    let nee = a.nee.unwrap_or(scene.render.nee);
    println!(
        "stcvae bench render: {} ({}x{}), g = {LADDER_G}, albedo ({}, {}, {}), NEE {}, {} spp each (2 seeds of {}: a multiple of 3 per seed; seeds PT {:?}, ST-CVAE {:?}), {}",
        a.scene.display(),
        a.size,
        a.size,
        LADDER_ALBEDO[0],
        LADDER_ALBEDO[1],
        LADDER_ALBEDO[2],
        if nee { "on" } else { "off" },
        2 * half_spp(a.spp),
        half_spp(a.spp),
        a.seeds_of(IntegratorKind::Pt),
        a.seeds_of(IntegratorKind::Stcvae),
        engine.describe()
    );
    println!(
        "{:>4} {:>20} {:>8} {:>8} {:>9} {:>9} {:>11} {:>10} {:>10} {:>10} {:>9} {:>9} {:>9} {:>10} {:>10}",
        "k",
        "sigma_t",
        "PT s",
        "ST s",
        "speed-up",
        "var ratio",
        "equal-error",
        "PT ev/path",
        "ST st/path",
        "ST ev/path",
        "bias RMSE",
        "bias 95%",
        "noise",
        "PT paths/s",
        "ST paths/s"
    );
}

/// One density's row of the table, and the lines that detail it.
fn print_row(
    k: f64,
    pt: &Pair,
    st: &Pair,
    c: &crate::experiment::measure::Comparison,
    cached: Option<u64>,
) {
    println!(
        "{:>4} {:>20} {:>8} {:>8} {:>8.2}x {:>9.2} {:>10.2}x {:>10.1} {:>10.2} {:>10.2} {:>9.4} {:>9} {:>9.4} {:>10} {:>10}",
        k,
        format!(
            "({}, {}, {})",
            significant4(LADDER_SIGMA_T[0] * k),
            significant4(LADDER_SIGMA_T[1] * k),
            significant4(LADDER_SIGMA_T[2] * k)
        ),
        significant4(pt.seconds),
        significant4(st.seconds),
        c.speedup,
        c.var_ratio,
        c.speedup * c.var_ratio,
        pt.per_path(pt.stats.events),
        st.per_path(st.stats.steps),
        st.per_path(st.stats.events),
        c.bias,
        c.bias_upper95
            .map_or("n/a".to_owned(), |b| format!("{b:.4}")),
        c.noise,
        crate::progress::si(pt.paths_per_second()),
        crate::progress::si(st.paths_per_second())
    );
    if let Some(when) = cached {
        println!(
            "     (PT from --pt-cache, measured {} before this run: its time and so the speed-up are that run's)",
            crate::pt_cache::age(when)
        );
    }
    let [r, g, b] = c.channel_offset.map(|(o, se)| {
        if o.is_finite() && se.is_finite() {
            format!("{:+.2}% ± {:.2}%", 100.0 * o, 100.0 * se)
        } else {
            "n/a (PT's total is ~0)".to_owned()
        }
    });
    let blocks = if c.blocks == 0 {
        format!(
            "no {BLOCK}x{BLOCK} block has ≥ {MIN_BLOCK_DOF} dof of noise estimate (image too small or too few spp)"
        )
    } else {
        format!(
            "{BLOCK}x{BLOCK}-block chi2/dof {:.2} over {} with ≥ {MIN_BLOCK_DOF} dof ({:.2} ± {:.2} if they differ by noise alone)",
            c.block_chi2, c.blocks, c.block_null.0, c.block_null.1
        )
    };
    println!(
        "     var ratio {:.2} ± {:.2}; per channel (R, G, B): bias RMSE {:.4} {:.4} {:.4}; ST-CVAE/PT total − 1: {r}, {g}, {b}; {blocks}",
        c.var_ratio, c.var_ratio_se, c.channel_bias[0], c.channel_bias[1], c.channel_bias[2],
    );
    // The work the steps column hides: exact steps are walks simulated event by event.
    println!(
        "     ST-CVAE's exact steps (τ < exact_tau) a path {:.2}, whose walks simulate {:.1} events a path",
        st.per_path(st.stats.exact_steps),
        st.per_path(st.stats.exact_events)
    );
    if st.stats.leaks + pt.stats.leaks > 0 {
        println!(
            "     (paths found outside while believed inside: PT {}, ST-CVAE {})",
            pt.stats.leaks, st.stats.leaks
        );
    }
}

#[cfg(test)]
mod tests {
    use super::{Args, parse_k, save_images, saved_files};
    use crate::experiment::measure::Pair;
    use clap::Parser as _;

    /// `bench render`'s arguments at their defaults.
    fn default_args() -> Args {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            a: Args,
        }
        Cli::try_parse_from(["bench"]).unwrap().a
    }

    /// Saves `pt` and `st` into `dir` as `bench render --save` does (at k = 1) and reads
    /// the z map back: its width, height and RGB bytes.
    fn saved_z_map(dir: &std::path::Path, pt: &Pair, st: &Pair) -> (u32, u32, Vec<u8>) {
        save_images(&default_args(), dir, 1.0, pt, st).unwrap();
        let z = std::fs::read(super::saved_z(dir, 1.0)).unwrap();
        let mut dec = png::Decoder::new(std::io::Cursor::new(z))
            .read_info()
            .unwrap();
        let mut grey = vec![0; dec.output_buffer_size()];
        let info = dec.next_frame(&mut grey).unwrap();
        (info.width, info.height, grey)
    }

    /// A `side`² grey pair of 2 spp, pixel i of value `value(i)` with variance `var` per
    /// channel, as `save_images` reads it.
    fn grey_pair(side: usize, var: f64, value: &dyn Fn(usize) -> f32) -> Pair {
        let mut mean = render_gpu::image_io::RgbImage::new(side, side);
        for (i, p) in mean.pixels.iter_mut().enumerate() {
            *p = [value(i); 3];
        }
        let n = side * side;
        Pair {
            mean,
            var: vec![[var; 3]; n],
            seconds: 1.0,
            stats: Default::default(),
            work: vec![1.0; n],
            spp: 2,
            hash: 7,
            view: None,
        }
    }

    /// A save that fails part way (the pixel table's name taken by a folder, after the
    /// images were written) leaves k's files as an earlier run left them: no new image
    /// beside an earlier run's z map and pixel table (of other seeds, read as one run's),
    /// and the earlier run's set not removed either (it was, on a full disk).
    #[test]
    fn a_failed_save_leaves_the_earlier_set_whole() {
        let a = default_args();
        let dir = tempfile::tempdir().unwrap();
        let files = saved_files(dir.path(), 1.0);
        let (table, others) = files.split_last().unwrap();
        for f in others {
            std::fs::write(f, b"an earlier run's").unwrap();
        }
        std::fs::create_dir(table).unwrap();
        let pair = |v: f32| grey_pair(4, 0.01, &|_| v);
        let e = save_images(&a, dir.path(), 1.0, &pair(0.5), &pair(0.4)).unwrap_err();
        assert!(
            format!("{e:#}").contains(&format!("cannot write {}", table.display())),
            "{e:#}"
        );
        for f in others {
            assert_eq!(
                std::fs::read(f).unwrap(),
                b"an earlier run's",
                "{}",
                f.display()
            );
        }
        assert!(table.is_dir());
        // Nothing else: no temporary of the set left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), files.len());
    }

    /// `--save`'s pictures: both images at PT's exposure (its brightest 1 % at 1, so that
    /// they compare by eye), and the z map's grey per 4×4 block, 0.5 + z/8 with z of
    /// ST-CVAE − PT (brighter where ST-CVAE is brighter), in the block where it lies.
    /// Worked case: an 8×8 pair, PT 0.5 everywhere, every pixel-channel's variance of the
    /// mean 0.005 in both (a block's noise √(32 · 0.005) = 0.4, ν = 3·0.16²/0.0008 = 96 ≥
    /// MIN_BLOCK_DOF); ST-CVAE 0.55 (top left), 0.4 (top right), 0.5 (bottom left) and
    /// 0.7 (bottom right): z = 16·Δ/0.4 = 2, −4, 0 and 8, grey 0.75, 0, 0.5 and 1 (clamped),
    /// PNG levels 191, 0, 128 and 255 (⌊255·v + 0.5⌋; f32 rounding moves z by < 1e-6).
    /// ST-CVAE − PT taken the other way round gives 64, 255, 128, 0; blocks taken by
    /// column, 191, 128, 0, 255. PT's exposure is 1/0.5 = 2 (a constant image's 99th
    /// percentile), ST-CVAE's would be 1/0.7.
    #[test]
    fn the_saved_pictures_are_at_pts_exposure_and_the_z_map_shows_where_st_cvae_differs() {
        use render_gpu::image_io::encode_png;
        let dir = tempfile::tempdir().unwrap();
        let block = |i: usize| (i / 8 / 4) * 2 + (i % 8) / 4;
        let pair = |value: &dyn Fn(usize) -> f32| grey_pair(8, 0.005, value);
        let pt = pair(&|_: usize| 0.5f32);
        let st = pair(&|i: usize| [0.55f32, 0.4, 0.5, 0.7][block(i)]);
        let (width, height, grey) = saved_z_map(dir.path(), &pt, &st);
        assert_eq!((width, height, grey.len()), (8, 8, 8 * 8 * 3));
        for (i, p) in grey.chunks(3).enumerate() {
            let want = [191u8, 0, 128, 255][block(i)];
            assert_eq!(p, &[want; 3][..], "pixel ({}, {})", i % 8, i / 8);
        }
        assert_ne!(
            encode_png(&pt.mean, 2.0).unwrap(),
            encode_png(&pt.mean, 1.0 / 0.7).unwrap()
        );
        for (name, p) in [("pt", &pt), ("stcvae", &st)] {
            let file = crate::merge::image_out(&super::saved_stem(dir.path(), 1.0, name), "png");
            assert_eq!(
                std::fs::read(&file).unwrap(),
                encode_png(&p.mean, 2.0).unwrap(),
                "{}",
                file.display()
            );
        }
    }

    /// The ladder at k = 1 is the teaser's scene file, so that the bench's figures and
    /// `experiment teaser`'s are of one medium.
    #[test]
    fn the_ladder_at_k_1_is_the_teaser_medium() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/scenes/bunny.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let f = render_gpu::scene::SceneFile::parse(&path, &text).unwrap();
        assert_eq!(f.medium.sigma_t, super::LADDER_SIGMA_T);
        assert_eq!(f.medium.albedo, super::LADDER_ALBEDO);
        assert_eq!(f.medium.g, super::LADDER_G);
    }

    /// The help's ranges of the settings the bench overrides are the scene file's limits
    /// (clap's help is written as doc comments, which cannot name the constants).
    #[test]
    fn the_help_gives_the_scene_limits() {
        use clap::CommandFactory as _;
        use render_gpu::scene::{
            MAX_EXACT_NEE_SAMPLES, MAX_EXACT_TAU, MAX_NEE_SAMPLES, MAX_PATH_NEE_RAYS,
            MAX_SCENE_VALUE,
        };
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            a: Args,
        }
        let cmd = Cli::command();
        let help = |id: &str| crate::help_of(&cmd, id);
        for (id, range) in [
            ("nee_samples", format!("1 to {MAX_NEE_SAMPLES} ")),
            (
                "exact_nee_samples",
                format!("1 to {MAX_EXACT_NEE_SAMPLES} "),
            ),
            ("path_nee_rays", format!("0 to {MAX_PATH_NEE_RAYS} ")),
            ("exact_tau", format!("in [0, {MAX_EXACT_TAU}]")),
            ("min_tau", format!("in [0, {MAX_SCENE_VALUE:e}]")),
            (
                "size",
                format!(
                    "{} to {},{:03} ",
                    super::MIN_BENCH_SIZE,
                    super::MAX_BENCH_SIZE / 1000,
                    super::MAX_BENCH_SIZE % 1000
                ),
            ),
        ] {
            assert!(help(id).contains(&range), "--{id}: {}", help(id));
        }
        // The ladder as the help gives it.
        let [a, b, c] = super::LADDER_SIGMA_T;
        let medium = format!("σ_t = k·({a}, {b}, {c}), albedo");
        assert!(
            help("scene").contains(&medium),
            "--scene: {}",
            help("scene")
        );
    }

    #[test]
    fn k_takes_its_range_and_nothing_else() {
        for ok in ["0.001", "1e-3", " 1 ", "1000", "8"] {
            assert!(parse_k(ok).is_ok(), "{ok}");
        }
        for bad in ["0.0009", "1001", "0", "-1", "NaN", "inf", "1e-300", "x"] {
            assert!(parse_k(bad).is_err(), "{bad}");
        }
    }

    /// The pixel table's columns hold what their names say: PT's mean and the variance
    /// of PT's mean, then ST-CVAE's, at x = i mod side and y = i div side. A 4×4 pair
    /// whose pixel i reads i (PT) and 100 + i (ST-CVAE), with variances of the mean 0.01
    /// (PT) and 0.02 (ST-CVAE) per channel. Every value is printed with `{:e}`, which
    /// round-trips (integers and the f64 0.01 and 0.02 exactly), so they are compared
    /// exactly. The integration test checks only the means and that the variances are
    /// ≥ 0: ST-CVAE's variance written under pt_var passed it.
    #[test]
    fn the_pixel_table_holds_each_renders_mean_and_variance_in_its_column() {
        let a = default_args();
        let dir = tempfile::tempdir().unwrap();
        let pt = grey_pair(4, 0.01, &|i: usize| i as f32);
        let st = grey_pair(4, 0.02, &|i: usize| 100.0 + i as f32);
        save_images(&a, dir.path(), 1.0, &pt, &st).unwrap();
        let csv = std::fs::read_to_string(super::saved_pixels(dir.path(), 1.0)).unwrap();
        let mut lines = csv.lines();
        assert_eq!(
            lines.next(),
            Some("x,y,channel,pt_mean,pt_var,stcvae_mean,stcvae_var")
        );
        let mut rows = 0;
        for line in lines {
            let r: Vec<f64> = line.split(',').map(|v| v.parse().unwrap()).collect();
            assert_eq!(r.len(), 7, "{line}");
            let i = (r[1] * 4.0 + r[0]) as usize;
            assert_eq!(
                &r[3..],
                &[i as f64, 0.01, 100.0 + i as f64, 0.02][..],
                "{line}"
            );
            rows += 1;
        }
        // 16 pixels × 3 channels.
        assert_eq!(rows, 4 * 4 * 3);
    }

    /// The z map of an image whose side is no multiple of 4 (`--size 10`: three blocks a
    /// row, the last two pixels wide): every pixel shows its own block's z. PT 0.5
    /// everywhere; ST-CVAE 0.55 in the first block of the second block row (x < 4,
    /// 4 ≤ y < 8) and 0.5 elsewhere; every pixel-channel's variance of the mean 0.005 in
    /// both. That block's z = 16·0.05/√(32·0.005) = 2, grey 0.75, PNG level 191
    /// (⌊255·0.75 + 0.5⌋; the f32 rounding of 0.55 − 0.5 moves z by ~5e-7, far from a
    /// level's edge); every other block has z = 0 exactly, level 128. All blocks have
    /// ν = 3·(pixel-values in the block) ≥ 24 ≥ MIN_BLOCK_DOF (the 2×2 corner: 8 values),
    /// so all are judged. With ⌊10/4⌋ = 2 blocks a row the marked pixels showed the
    /// first row's third block (128) and the middle block of the second row showed 191.
    #[test]
    fn the_z_map_finds_each_pixels_block_when_the_side_is_no_multiple_of_four() {
        let dir = tempfile::tempdir().unwrap();
        let marked = |i: usize| i % 10 < 4 && (4..8).contains(&(i / 10));
        let pt = grey_pair(10, 0.005, &|_: usize| 0.5f32);
        let st = grey_pair(10, 0.005, &|i: usize| if marked(i) { 0.55f32 } else { 0.5 });
        let (width, height, grey) = saved_z_map(dir.path(), &pt, &st);
        assert_eq!((width, height, grey.len()), (10, 10, 10 * 10 * 3));
        for (i, p) in grey.chunks(3).enumerate() {
            let want = if marked(i) { 191u8 } else { 128 };
            assert_eq!(p, &[want; 3][..], "pixel ({}, {})", i % 10, i / 10);
        }
    }

    /// Blocks whose z cannot be judged are mid-grey (level 128) in the z map, as `--save`'s
    /// help says: the background (no noise in either render) and a silhouette block whose
    /// noise comes from one pixel (ν = 3·(2v)²/(2v²) = 6 < MIN_BLOCK_DOF = 10), even where
    /// that pixel's renders differ by 0.3 (z = 0.3/√0.01 = 3, which a judged block would
    /// draw at 0.875). 8×8: both 0 without noise in the top left block; in the top right
    /// block both 0.5 without noise but pixel (5, 1), where PT reads 0.5 and ST-CVAE 0.8,
    /// each with variance 0.005; the bottom blocks 0.5 in both with variance 0.005 (z = 0:
    /// 128 too). Drawn at 0 (black, "ST-CVAE far darker"), the background read as the
    /// strongest bias in the picture.
    #[test]
    fn unjudged_blocks_are_mid_grey_in_the_z_map() {
        let dir = tempfile::tempdir().unwrap();
        let block = |i: usize| (i / 8 / 4) * 2 + (i % 8) / 4;
        let lone = 8 + 5;
        let mut pt = grey_pair(8, 0.005, &|i: usize| {
            if block(i) == 0 { 0.0f32 } else { 0.5 }
        });
        let mut st = grey_pair(8, 0.005, &|i: usize| match block(i) {
            0 => 0.0f32,
            _ if i == lone => 0.8,
            _ => 0.5,
        });
        for p in [&mut pt, &mut st] {
            for i in 0..64 {
                if block(i) < 2 && i != lone {
                    p.var[i] = [0.0; 3];
                }
            }
        }
        // Both top blocks are unjudged (None), the bottom ones judged at z = 0.
        let zs = crate::experiment::measure::block_z(&pt, &st);
        assert_eq!((zs[0], zs[1]), ([None; 3], [None; 3]));
        assert_eq!((zs[2], zs[3]), ([Some(0.0); 3], [Some(0.0); 3]));
        let (width, height, grey) = saved_z_map(dir.path(), &pt, &st);
        assert_eq!((width, height, grey.len()), (8, 8, 8 * 8 * 3));
        for (i, p) in grey.chunks(3).enumerate() {
            // ⌊255·0.5 + 0.5⌋ = 128 for every block, judged at z = 0 or not judged.
            assert_eq!(p, &[128u8; 3][..], "pixel ({}, {})", i % 8, i / 8);
        }
    }

    /// The ladder's scene: the teaser medium times k whatever the scene file's own
    /// medium (the sphere's is σ_t 20, albedo (0.999, 0.99, 0.95), g 0.4), the bench's
    /// size on both sides, and for ST-CVAE each override in its own field; PT's render
    /// settings stay the file's (so that its scene hash, and `--pt-cache`, ignore
    /// ST-CVAE's options). Every override differs from the sphere file's value and from
    /// the others (defaults: nee_samples 2, exact_nee_samples 1, path_nee_rays 1, taus
    /// unset), so a flag applied to another field, or not at all, fails. All values are
    /// exact in binary (150·2, 187.5·2, 125·2), so compared exactly.
    #[test]
    fn the_ladder_applies_each_st_cvae_override_to_its_own_field() {
        use render_gpu::integrator::IntegratorKind;
        let mut a = default_args();
        a.size = 16;
        a.min_tau = Some(0.5);
        a.max_tau = Some(30.0);
        a.exact_tau = Some(7.0);
        a.nee_samples = Some(5);
        a.exact_nee_samples = Some(3);
        a.path_nee_rays = Some(2);
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/scenes/sphere.toml");
        let base = render_gpu::scene::SceneFile::load(&path).unwrap();
        assert_eq!(
            (
                base.render.nee_samples,
                base.render.exact_nee_samples,
                base.render.path_nee_rays
            ),
            (2, 1, 1)
        );
        let mut st = base.clone();
        super::ladder_scene(&a, IntegratorKind::Stcvae, 2.0, &mut st);
        assert_eq!(st.medium.sigma_t, [300.0, 375.0, 250.0]);
        assert_eq!(st.medium.albedo, super::LADDER_ALBEDO);
        assert_eq!(st.medium.g, super::LADDER_G);
        assert_eq!((st.camera.width, st.camera.height), (16, 16));
        let r = &st.render;
        assert_eq!(
            (r.min_tau, r.max_tau, r.exact_tau),
            (Some(0.5), Some(30.0), Some(7.0))
        );
        assert_eq!(
            (r.nee_samples, r.exact_nee_samples, r.path_nee_rays),
            (5, 3, 2)
        );
        let mut pt = base.clone();
        super::ladder_scene(&a, IntegratorKind::Pt, 2.0, &mut pt);
        assert_eq!(pt.medium.sigma_t, [300.0, 375.0, 250.0]);
        assert_eq!((pt.camera.width, pt.camera.height), (16, 16));
        let (b, r) = (&base.render, &pt.render);
        assert_eq!(
            (r.min_tau, r.max_tau, r.exact_tau),
            (b.min_tau, b.max_tau, b.exact_tau)
        );
        assert_eq!(
            (r.nee_samples, r.exact_nee_samples, r.path_nee_rays),
            (b.nee_samples, b.exact_nee_samples, b.path_nee_rays)
        );
    }
}
