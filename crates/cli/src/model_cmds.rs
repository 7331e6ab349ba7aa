//! `stcvae sample` and `stcvae eval`: drawing from a model file and measuring its fit.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;

use anyhow::{Result, bail};
use cvae::ModelSet;
use cvae::eval::{self, SettingReport};
use rayon::prelude::*;
use scatter_sim::conditions::Conditions;
use scatter_sim::dataset::{CsvWriter, Row, RowSink, is_csv};
use scatter_sim::walk::CanonicalWalk;

use crate::{interrupt, progress};

/// The model shipped in the repository, used when no --model is given.
pub const DEFAULT_MODEL: &str = "models/default.stcvae";

/// The model file a missing `--model` stands for: the shipped one, found from any working
/// directory while the checkout the binary was built from exists (shipped.rs).
pub fn model_path(path: Option<&Path>) -> PathBuf {
    path.map_or_else(|| crate::shipped::locate(DEFAULT_MODEL), Path::to_path_buf)
}

pub fn load_model(path: Option<&Path>) -> Result<ModelSet> {
    let p = model_path(path);
    if path.is_none() && !p.exists() {
        bail!(
            "{DEFAULT_MODEL} not found here or in the checkout this binary was built from: run \
             from the repository root (the shipped model lives there) or pass --model FILE"
        );
    }
    // A file the user named is named as the flag's value (a bare "x: No such file" did
    // not say which option it came from).
    ModelSet::load(&p).map_err(|e| match path {
        Some(_) => anyhow::anyhow!("--model {e}"),
        None => e.into(),
    })
}

#[derive(clap::Args)]
#[command(
    after_help = "Example:\n  stcvae sample --model models/default.stcvae --tau 5 --g 0.4 --albedo 0.9 \
    --samples 10000 --seed 3 --out s.csv\n\nThe CSV has the columns of `stcvae generate`; `n` is N as \
    sampled, before absorption."
)]
pub struct SampleArgs {
    /// Model file (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    model: Option<PathBuf>,
    /// Optical radius τ, in [0, 1000] (the shipped model was trained on [0, 300]; beyond
    /// the model's training range the samples are an extrapolation, with a warning).
    #[arg(long, allow_hyphen_values = true)]
    tau: f64,
    /// Henyey–Greenstein g, in [-0.999, 0.999].
    #[arg(long, allow_hyphen_values = true)]
    g: f64,
    /// Single-scattering albedo φ in [0, 1] (steers the representative event).
    #[arg(long, allow_hyphen_values = true)]
    albedo: f64,
    /// Number of model walks to draw, at least 1.
    #[arg(long, allow_negative_numbers = true, default_value_t = 10_000,
          value_parser = crate::whole::whole::<u64>(1, u64::MAX))]
    samples: u64,
    /// Random seed: walk i has a stream of its own, so a run is reproducible whatever the
    /// thread count. The model's streams are apart from the simulator's: a `generate` of
    /// the same seed gives independent walks (and `eval` with seed S draws these for a
    /// setting of seed S).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1,
          value_parser = crate::render::parse_seed)]
    seed: u64,
    /// Output CSV file.
    #[arg(long)]
    out: PathBuf,
}

pub fn sample(a: SampleArgs) -> Result<()> {
    let c = Conditions {
        tau: a.tau,
        g: a.g,
        albedo: a.albedo,
    };
    c.validate().map_err(|e| anyhow::anyhow!("--{e}"))?;
    // A folder first: "name the file *.csv" would not say what is wrong with /tmp.
    crate::check_out("--out", &a.out)?;
    if !is_csv(&a.out) {
        bail!(
            "--out {}: sample writes CSV; name the file *.csv",
            a.out.display()
        );
    }
    // First, so that a Ctrl-C from here on stops cleanly.
    let cancel = interrupt::flag();
    crate::paths::check_not_input(
        "--out",
        &a.out,
        &[("the model".to_string(), model_path(a.model.as_deref()))],
    )?;
    crate::paths::check_room(&a.out, a.samples, "--samples")?;
    let m = load_model(a.model.as_deref())?;
    let _ = warn_outside_training(&m, c, "--");
    let mut sink = Box::new(CsvWriter::create(&a.out, a.samples)?);
    // Drawn in chunks so that memory stays bounded however many walks are asked for.
    const CHUNK: u64 = 1 << 16;
    let pb = progress::bar(a.samples, "walks");
    // N is a u32 column (as in `generate`'s files); a model asked far outside its training
    // can draw more, written as u32::MAX and counted here.
    let mut saturated = 0u64;
    let mut repaired = 0u64;
    for start in (0..a.samples).step_by(CHUNK as usize) {
        if cancel.load(Ordering::Relaxed) {
            // Dropping the sink removes its temporary file.
            pb.finish_and_clear();
            bail!("interrupted: nothing written to {}", a.out.display());
        }
        let walks: Vec<_> = (start..(start + CHUNK).min(a.samples))
            .into_par_iter()
            .map(|i| {
                let mut rng = cvae::eval::model_rng(a.seed, i);
                m.sample_walk_checked(c.tau, c.g, c.albedo, true, &mut rng)
            })
            .collect();
        for (w, bad) in &walks {
            repaired += u64::from(*bad);
            saturated += u64::from(w.n > u64::from(u32::MAX));
            let cw = CanonicalWalk {
                n: w.n,
                exit: w.exit,
                event_pos: w.event_pos,
                event_dir: w.event_dir,
            };
            sink.push(&Row::new(c, &cw))?;
        }
        pb.inc(walks.len() as u64);
    }
    pb.finish_and_clear();
    // A Ctrl-C during the last chunk (or the only one: 65,536 walks or fewer) stops it too.
    if cancel.load(Ordering::Relaxed) {
        bail!("interrupted: nothing written to {}", a.out.display());
    }
    sink.finish()?;
    if repaired > 0 {
        eprintln!(
            "warning: {repaired} of the walks had a decoder output that is not finite, \
             written with it replaced by a value in range: a trained model never gives one, \
             so the model file {} was damaged or edited; train it again",
            model_path(a.model.as_deref()).display()
        );
    }
    if saturated > 0 {
        eprintln!(
            "note: {saturated} of the walks drew N above {} (the N column's largest value), \
             written as {}",
            u32::MAX,
            u32::MAX
        );
    }
    eprintln!(
        "wrote {} to {}",
        progress::count(a.samples, "model walk"),
        crate::paths::shown(&a.out)
    );
    Ok(())
}

#[derive(clap::Args)]
#[command(
    after_help = "Compares the model with fresh simulator walks on the paper's grid \
    τ ∈ {1, 5, 25, 125} × g ∈ {-0.7, 0, 0.4, 0.9} (φ = 1, plus φ = 0.9 for EventGen), or on \
    the settings given with --at, and writes metrics.md and metrics.json (and, for the grid, \
    plots).\n\nExample:\n  stcvae eval --at 5,0.875,1 --at 5,0.875,0.975 --samples 40000 --out results/eval-bunny"
)]
pub struct EvalArgs {
    /// Model file (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    model: Option<PathBuf>,
    /// Output directory.
    #[arg(long, default_value = "results/eval")]
    out: PathBuf,
    /// Samples per setting, for the model and for the simulator each: 2 to 4,000,000.
    #[arg(long, allow_negative_numbers = true, default_value_t = 10_000,
          value_parser = crate::whole::whole::<usize>(2, MAX_EVAL_SAMPLES as u64))]
    samples: usize,
    /// Random seed; setting i (of the grid or of --at) uses seed + i (mod 2^64). The
    /// model's walks are those `sample --seed` draws with it, in streams apart from the
    /// simulator's, so the two are independent.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1,
          value_parser = crate::render::parse_seed)]
    seed: u64,
    /// Evaluate these settings instead of the paper's grid, each given as TAU,G,ALBEDO
    /// (repeatable): a scene's own g and albedos, for instance. Writes metrics.md and
    /// metrics.json without plots, and prints beside the table how the representative
    /// events fill thin bands near the sphere's surface.
    #[arg(long, value_parser = parse_setting, allow_hyphen_values = true)]
    at: Vec<Conditions>,
}

fn parse_setting(s: &str) -> Result<Conditions, String> {
    let v: Vec<f64> = s
        .split(',')
        // + 0.0 makes -0 a plain 0: `--at -0,0,1` printed "-0" in the tables.
        .map(|x| x.trim().parse::<f64>().map(|v| v + 0.0))
        .collect::<Result<_, _>>()
        .map_err(|e| format!("'{s}': {e}: expected three numbers TAU,G,ALBEDO, e.g. 5,0.875,1"))?;
    let [tau, g, albedo] = v[..] else {
        return Err(format!(
            "'{s}': expected three numbers TAU,G,ALBEDO, e.g. 5,0.875,1"
        ));
    };
    let c = Conditions { tau, g, albedo };
    c.validate().map_err(|e| e.to_string())?;
    Ok(c)
}

/// The models extrapolate outside the conditions they were trained on: warns (stderr) of
/// each condition outside the model's training range, and returns the warnings for a
/// report that keeps them.
fn warn_outside_training(m: &cvae::ModelSet, c: Conditions, flag: &str) -> Vec<String> {
    let t = &m.training;
    let mut warnings = Vec::new();
    for (name, v, r) in [
        ("tau", c.tau, t.tau_range),
        ("g", c.g, t.g_range),
        ("albedo", c.albedo, t.albedo_range),
    ] {
        if outside_training(v, r) {
            let w = format!(
                "{flag}{name} {v} lies outside the model's training range {}: the samples are an extrapolation",
                training_range(r)
            );
            eprintln!("warning: {w}");
            warnings.push(w);
        }
    }
    warnings
}

/// Which of the paper's grid settings (`eval`'s) lie outside the model's training range,
/// as one line, or None: a model trained on other conditions had its figures there
/// reported as a fit, without a word.
fn grid_outside_training(m: &cvae::ModelSet) -> Option<String> {
    let t = &m.training;
    let mut outside = Vec::new();
    for (name, values, r) in [
        ("tau", &eval::TAUS[..], t.tau_range),
        ("g", &eval::GS[..], t.g_range),
        ("albedo", &eval::ALBEDOS[..], t.albedo_range),
    ] {
        let out: Vec<String> = values
            .iter()
            .filter(|&&v| outside_training(v, r))
            .map(|v| v.to_string())
            .collect();
        if !out.is_empty() {
            outside.push(format!(
                "{name} {} (trained {})",
                out.join(", "),
                training_range(r)
            ));
        }
    }
    (!outside.is_empty()).then(|| {
        format!(
            "the grid's {} lie outside the model's training range: its figures at those \
             settings measure an extrapolation",
            outside.join("; ")
        )
    })
}

/// Whether `v` lies outside a model's training range `r` beyond rounding and beyond the
/// gap between the range the training data happened to cover and its nominal bounds
/// (the shipped model's τ reaches 299.9996 of the 300 its sampler allows): 1e-5 of the
/// range's width.
pub(crate) fn outside_training(v: f64, r: [f64; 2]) -> bool {
    let tol = 1e-6 + 1e-5 * (r[1] - r[0]).abs();
    v < r[0] - tol || v > r[1] + tol
}

/// The model's training maximum, as the renderer holds it (f32): the largest sphere step
/// without `max_tau` ([`default_max_tau`]).
pub(crate) fn trained_max_tau(m: &ModelSet) -> f64 {
    m.training.tau_range[1] as f32 as f64
}

/// The largest sphere step without `max_tau`, for a render whose threshold is `min_tau`:
/// the model's training maximum ([`trained_max_tau`]), raised to a `min_tau` within
/// [`beyond_trained_tau`]'s tolerance above it, as a `max_tau` written there is allowed
/// (min_tau = 300 was refused against the shipped model's 299.9996, and min_tau = max_tau
/// = 300 rendered). None for a `min_tau` beyond that: ST-CVAE would have no step to take.
pub(crate) fn default_max_tau(min_tau: f64, m: &ModelSet) -> Option<f64> {
    let top = trained_max_tau(m);
    if min_tau <= top {
        Some(top)
    } else if beyond_trained_tau(min_tau, m) {
        None
    } else {
        Some(min_tau)
    }
}

/// Whether a largest sphere step `t` (render.max_tau, --max-tau) goes beyond the model's
/// training range, with [`outside_training`]'s tolerance: the shipped model's 299.9996
/// admits the max_tau = 300 of the README's example.
pub(crate) fn beyond_trained_tau(t: f64, m: &ModelSet) -> bool {
    let r = m.training.tau_range;
    t > r[1] && outside_training(t, r)
}

/// `[lo, hi]` with enough digits that a bound near 0 or 1 (albedo's 2.8e-6) does not
/// print as the round number it is not.
pub(crate) fn training_range(r: [f64; 2]) -> String {
    let f = |v: f64| {
        if v != 0.0 && v.abs() < 1e-3 {
            format!("{v:.2e}")
        } else if f64::from(v as f32) == v {
            // Ranges recorded from f32 data: their shortest f32 digits (299.99963, not
            // 299.9996337890625).
            format!("{}", v as f32)
        } else {
            // Shortest round-trip digits: 0.9999995 stays itself, 1 is 1.
            format!("{v}")
        }
    };
    format!("[{}, {}]", f(r[0]), f(r[1]))
}

/// Most walks a setting `eval` compares: it keeps every sample of both sides in memory
/// (a few hundred bytes a walk), and 10⁹ asked for 80 GB and aborted.
pub(crate) const MAX_EVAL_SAMPLES: usize = 4_000_000;
/// Most samples a setting for which `eval` keeps the plots' columns as the grid draws
/// them: 640 bytes a sample over the 16 plotted settings (`plots::plotted`).
const KEEP_PLOT_SAMPLES: usize = 500_000;

#[derive(serde::Serialize)]
struct EvalJson<'a> {
    model: String,
    samples: usize,
    seed: u64,
    max_ks: std::collections::BTreeMap<&'static str, f64>,
    settings: &'a [SettingReport],
}

pub fn evaluate(a: EvalArgs) -> Result<()> {
    // Only the files eval writes: the user's own metrics.csv or fig1.png in the folder
    // were named as an earlier run's, to delete.
    let before = crate::left_over::Snapshot::take_matching(&a.out, |name| {
        ["metrics.md", "metrics.json"].contains(&name) || crate::plots::PLOT_FILES.contains(&name)
    });
    if !a.at.is_empty() {
        evaluate_settings(&a)?;
    } else {
        evaluate_into(a.model.as_deref(), &a.out, a.samples, a.seed)?;
        print!(
            "{}",
            String::from_utf8_lossy(&std::fs::read(a.out.join("metrics.md"))?)
        );
    }
    before.note_left_over("metrics.md");
    Ok(())
}

/// Checks shared by both modes of `eval`; the model and the name to print for it.
/// Checks `eval`'s arguments and every file it will write (metrics.json, metrics.md and,
/// with `plots`, the plots: a directory in a plot's place once failed only after the whole
/// grid), then loads the model.
fn open_eval(
    model: Option<&Path>,
    out: &Path,
    samples: usize,
    plots: bool,
) -> Result<(ModelSet, String)> {
    if !(2..=MAX_EVAL_SAMPLES).contains(&samples) {
        bail!(
            "--samples {samples} is out of range: allowed [2, {MAX_EVAL_SAMPLES}] (the KS and \
             moment tests need two samples; eval holds every sample in memory)"
        );
    }
    if out.exists() && !out.is_dir() {
        bail!(
            "--out {}: exists and is not a directory (eval writes metrics.md, metrics.json and plots into a directory)",
            out.display()
        );
    }
    let m = load_model(model)?;
    let name = model_path(model).display().to_string();
    // Checked now, created when the results are written: an eval stopped part way (Ctrl-C
    // kills it) leaves no empty directory behind.
    let plot_files = if plots {
        &crate::plots::PLOT_FILES[..]
    } else {
        &[]
    };
    let inputs = [("--model".to_string(), model_path(model))];
    for file in ["metrics.json", "metrics.md"].iter().chain(plot_files) {
        let f = out.join(file);
        crate::paths::check_not_input("--out", &f, &inputs)?;
        scatter_sim::output::check_output_path(&f)
            .map_err(|e| anyhow::anyhow!("--out {}: {e}", out.display()))?;
    }
    Ok((m, name))
}

/// The quantities whose largest KS the summary gives: all that `eval` compares but log N,
/// whose KS is N's (the statistic does not change under a monotone map).
fn summarised() -> impl Iterator<Item = &'static str> {
    eval::QUANTITIES
        .into_iter()
        .filter(|&q| q != "log_n")
        .chain(eval::PAIRS.map(|p| p.0))
}

/// Largest KS per quantity over the reports, for the quantities they measured.
fn max_ks_of(reports: &[SettingReport]) -> std::collections::BTreeMap<&'static str, f64> {
    summarised()
        .filter_map(|q| Some((q, eval::max_ks(reports, q)?)))
        .collect()
}

/// metrics.json, metrics.md and the plots (named, encoded) as one set (none is left
/// beside the others' previous versions by a failure, e.g. a full disk), errors naming
/// the file.
fn write_metrics(out: &Path, json: &[u8], md: &[u8], plots: &[(String, Vec<u8>)]) -> Result<()> {
    let (j, m) = (out.join("metrics.json"), out.join("metrics.md"));
    let paths: Vec<PathBuf> = plots.iter().map(|(name, _)| out.join(name)).collect();
    let mut files: Vec<(&Path, &[u8])> = vec![(&j, json), (&m, md)];
    files.extend(
        paths
            .iter()
            .zip(plots)
            .map(|(p, (_, b))| (p.as_path(), b.as_slice())),
    );
    scatter_sim::output::write_atomic_set(&files)
        .map_err(|(path, e)| anyhow::anyhow!("cannot write {}: {e}", path.display()))
}

/// metrics.json, and the head of metrics.md (title, sample counts, max KS, the table).
fn eval_json_and_head(
    name: &str,
    samples: usize,
    seed: u64,
    reports: &[SettingReport],
) -> Result<(Vec<u8>, Vec<u8>)> {
    let max_ks = max_ks_of(reports);
    let json = serde_json::to_vec_pretty(&EvalJson {
        model: name.to_owned(),
        samples,
        seed,
        max_ks: max_ks.clone(),
        settings: reports,
    })?;
    let mut md = Vec::new();
    writeln!(md, "# Distribution fidelity of {name}\n")?;
    writeln!(
        md,
        "{samples} model samples vs {samples} fresh simulator walks per setting (setting i: \
         seed {seed} + i, mod 2^64; the model's walks are those `sample --seed` draws, in streams \
         apart from the simulator's). KS = two-sample Kolmogorov–Smirnov statistic, W1 = Wasserstein-1 \
         distance; for the pairs (cos θ, α) and (cos θ, β) the 2-D KS statistic (the largest \
         difference of the samples' shares in a quadrant about any sample point, Fasano–\
         Franceschini) and the sliced W1 (mean 1-D W1 of {} projections). Only the representative \
         event (EventGen) depends on φ; N and the exit do not. Renders with the default \
         exact_tau = {} simulate sphere steps below that τ exactly and draw from the models \
         only above it: rows of smaller τ matter only for scenes that lower exact_tau.\n",
        eval::SLICES,
        render_gpu::scene::DEFAULT_EXACT_TAU
    )?;
    let mut line = max_ks
        .iter()
        .map(|(k, v)| format!("{k} {v:.3}"))
        .collect::<Vec<_>>()
        .join(", ");
    let missing: Vec<&str> = summarised().filter(|q| !max_ks.contains_key(q)).collect();
    if !missing.is_empty() {
        line += &format!(" (not measured at these settings: {})", missing.join(", "));
    }
    writeln!(md, "Max KS over these settings: {line}\n")?;
    md.extend(eval::markdown_table(reports).into_bytes());
    Ok((json, md))
}

/// `eval --at`: the given settings only (setting i with seed + i), no plots; the table and
/// the fine shell bands go to stdout too.
fn evaluate_settings(a: &EvalArgs) -> Result<()> {
    let (m, name) = open_eval(a.model.as_deref(), &a.out, a.samples, false)?;
    let mut reports = Vec::new();
    let mut bands = String::new();
    let cancel = crate::interrupt::flag();
    eprintln!(
        "evaluating {name} at {} ({} model and simulator samples each) -> {}",
        progress::count(a.at.len() as u64, "setting"),
        a.samples,
        crate::paths::shown(&a.out)
    );
    let pb = progress::bar(a.at.len() as u64, "settings");
    // Ctrl-C stops it, writing nothing: within a setting's walks (a setting takes minutes
    // at 4M samples and τ = 125), and after the last one.
    let stopped = || anyhow::anyhow!("interrupted: nothing written to {}", a.out.display());
    // Kept in metrics.md too: saved figures of an extrapolation read as a fit.
    let mut warnings = Vec::new();
    for (i, c) in a.at.iter().enumerate() {
        warnings.extend(warn_outside_training(&m, *c, "--at "));
        let seed = a.seed.wrapping_add(i as u64);
        let setting = (c.tau, c.g, c.albedo);
        let model =
            eval::model_columns_until(&m, setting, a.samples, seed, cancel).ok_or_else(stopped)?;
        let sim =
            eval::simulator_columns_until(setting, a.samples, seed, cancel).ok_or_else(stopped)?;
        let report =
            eval::compare_setting_until(&model, &sim, setting, cancel).ok_or_else(stopped)?;
        reports.push(report);
        if cancel.load(std::sync::atomic::Ordering::Relaxed) {
            return Err(stopped());
        }
        bands += &eval::fine_shells_table(&model, &sim, c.tau, c.g, c.albedo);
        pb.inc(1);
    }
    pb.finish_and_clear();
    if cancel.load(std::sync::atomic::Ordering::Relaxed) {
        return Err(stopped());
    }
    let (json, mut md) = eval_json_and_head(&name, a.samples, a.seed, &reports)?;
    for w in &warnings {
        writeln!(md, "\n**Warning:** {w}.")?;
    }
    md.extend(bands.into_bytes());
    write_metrics(&a.out, &json, &md, &[])?;
    print!("{}", String::from_utf8_lossy(&md));
    Ok(())
}

/// What [`evaluate_into`] measured beyond its files.
pub struct GridEval {
    /// The max KS per quantity over the grid.
    pub max_ks: std::collections::BTreeMap<&'static str, f64>,
    /// The grid settings outside the model's training range, as printed and kept in
    /// metrics.md (for a report that embeds the plots).
    pub outside: Option<String>,
}

/// Evaluates the model into `out` (metrics.json, metrics.md, plots).
pub fn evaluate_into(
    model: Option<&Path>,
    out: &Path,
    samples: usize,
    seed: u64,
) -> Result<GridEval> {
    let (m, model_name) = open_eval(model, out, samples, true)?;
    let outside = grid_outside_training(&m);
    if let Some(w) = &outside {
        eprintln!("warning: {w}");
    }
    // Ctrl-C stops it after the current setting, writing nothing.
    let cancel = crate::interrupt::flag();
    eprintln!(
        "evaluating {model_name} on the paper's grid (32 settings, {samples} model and \
         simulator samples each) -> {}",
        crate::paths::shown(out)
    );
    let pb = progress::bar(32, "settings");
    let stopped = || cancel.load(std::sync::atomic::Ordering::Relaxed);
    let interrupted = || anyhow::anyhow!("interrupted: nothing written to {}", out.display());
    // The plots' columns of the φ = 1 settings are kept as the grid draws them (drawn
    // again they doubled those settings' time, with no word while it ran); beyond
    // KEEP_PLOT_SAMPLES (~0.3 GB kept) they are drawn again, with their own bar.
    let keep = samples <= KEEP_PLOT_SAMPLES;
    let mut cols = Vec::new();
    let reports = eval::evaluate_grid(
        &m,
        samples,
        seed,
        cancel,
        |i, _| {
            pb.set_position(i as u64);
            !stopped()
        },
        |(tau, g, albedo), model, sim| {
            if keep && albedo == 1.0 {
                cols.push((
                    tau,
                    g,
                    crate::plots::plotted(model, g),
                    crate::plots::plotted(sim, g),
                ));
            }
        },
    );
    pb.finish_and_clear();
    if stopped() {
        return Err(interrupted());
    }
    let max_ks = max_ks_of(&reports);
    let (json, mut md) = eval_json_and_head(&model_name, samples, seed, &reports)?;
    if let Some(w) = &outside {
        writeln!(md, "\n**Warning:** {w}.")?;
    }
    if !keep {
        // The φ = 1 settings again with the grid's seeds (the same samples).
        let pb = progress::bar(16, "settings drawn again for the plots");
        for (i, &tau) in eval::TAUS.iter().enumerate() {
            for (j, &g) in eval::GS.iter().enumerate() {
                if stopped() {
                    return Err(interrupted());
                }
                let seed = seed.wrapping_add((i * eval::GS.len() + j) as u64);
                let model = eval::model_columns_until(&m, (tau, g, 1.0), samples, seed, cancel)
                    .ok_or_else(interrupted)?;
                let sim = eval::simulator_columns_until((tau, g, 1.0), samples, seed, cancel)
                    .ok_or_else(interrupted)?;
                let plotted = |c: &eval::Columns| crate::plots::plotted(c, g);
                cols.push((tau, g, plotted(&model), plotted(&sim)));
                pb.inc(1);
            }
        }
        pb.finish_and_clear();
    }
    let panels: Vec<crate::plots::Panel> = cols.iter().map(|(t, g, m, s)| (*t, *g, m, s)).collect();
    let figs = crate::plots::render_all(&panels)?;
    // A Ctrl-C while the plots were drawn (seconds) stops it too: it said it would stop.
    if stopped() {
        return Err(interrupted());
    }
    writeln!(
        md,
        "\nPlots: {}",
        figs.iter()
            .map(|(f, _)| format!("[{f}]({f})"))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    write_metrics(out, &json, &md, &figs)?;
    Ok(GridEval { max_ks, outside })
}

#[cfg(test)]
mod tests {
    fn shipped_model() -> cvae::ModelSet {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        cvae::ModelSet::load(&root.join("models/default.stcvae")).unwrap()
    }

    /// The grid settings outside the training range, by quantity; the shipped model
    /// covers the whole grid.
    #[test]
    fn the_grid_settings_outside_the_training_range_are_named() {
        let mut m = shipped_model();
        assert_eq!(super::grid_outside_training(&m), None);
        m.training.tau_range = [2.0, 100.0];
        m.training.g_range = [-0.5, 0.5];
        m.training.albedo_range = [0.95, 1.0];
        assert_eq!(
            super::grid_outside_training(&m).as_deref(),
            Some(
                "the grid's tau 1, 125 (trained [2, 100]); g -0.7, 0.9 (trained [-0.5, 0.5]); \
                 albedo 0.9 (trained [0.95, 1]) lie outside the model's training range: its \
                 figures at those settings measure an extrapolation"
            )
        );
    }

    /// `outside_training` allows 1e-6 + 1e-5 × the range's width either side: 0.002001 for
    /// [100, 300], 1.1e-5 for [−0.5, 0.5], 1e-6 for a range of no width.
    #[test]
    fn outside_training_allows_its_tolerance_and_no_more() {
        use super::outside_training as out;
        for (v, want) in [
            (200.0, false),
            (300.0019, false),
            (300.0021, true),
            (99.9981, false),
            (99.9979, true),
        ] {
            assert_eq!(out(v, [100.0, 300.0]), want, "{v}");
        }
        assert!(!out(0.500005, [-0.5, 0.5]) && out(0.500012, [-0.5, 0.5]));
        assert!(!out(0.2500005, [0.25, 0.25]) && out(0.250002, [0.25, 0.25]));
    }

    /// Only a τ above the range, beyond its tolerance (0.002701 for [30, 300]), is beyond
    /// it; one below is an extrapolation warned of elsewhere, not refused.
    #[test]
    fn only_a_tau_above_the_training_range_is_beyond_it() {
        let mut m = shipped_model();
        m.training.tau_range = [30.0, 300.0];
        assert!(!super::beyond_trained_tau(20.0, &m));
        assert!(!super::beyond_trained_tau(300.002, &m));
        assert!(super::beyond_trained_tau(300.003, &m));
        assert_eq!(super::default_max_tau(20.0, &m), Some(300.0));
        assert_eq!(super::default_max_tau(300.002, &m), Some(300.002));
        assert_eq!(super::default_max_tau(300.003, &m), None);
    }

    /// Training ranges print their own digits: small bounds in exponent form (0 as 0),
    /// bounds recorded from f32 data by their shortest f32 digits, others as themselves.
    #[test]
    fn training_ranges_print_their_own_digits() {
        use super::training_range as tr;
        assert_eq!(tr([0.0, 0.005]), "[0, 0.005]");
        assert_eq!(tr([2.794284463036867e-6, 1.0]), "[2.79e-6, 1]");
        assert_eq!(
            tr([8.068644611386843e-17, 299.9996337890625]),
            "[8.07e-17, 299.99963]"
        );
        assert_eq!(tr([0.005, 0.9990000128746033]), "[0.005, 0.999]");
    }

    /// `--at -0,-0,1` printed "-0" for tau and g in eval's tables.
    #[test]
    fn a_negative_zero_setting_reads_as_zero() {
        let c = super::parse_setting("-0,-0.0,1").unwrap();
        assert!(c.tau.is_sign_positive() && c.g.is_sign_positive(), "{c:?}");
        assert_eq!((c.tau, c.g, c.albedo), (0.0, 0.0, 1.0));
    }
}
