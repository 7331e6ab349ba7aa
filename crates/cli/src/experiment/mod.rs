//! `stcvae experiment CONFIG [--quick]`: one TOML config per paper result, run end to end
//! into `results/<name>/`: images (EXR + PNG), `figures.csv` with every measured figure,
//! PNG plots and a `report.md` that embeds them.

mod config;
mod kinds;
pub mod measure;
mod report;

use std::path::{Path, PathBuf};

use render_gpu::scene::SceneFile;

use anyhow::{Context, Result};

use crate::device::{DeviceArg, Engine};
pub use config::{Budget, Config, Kind};
pub use report::Report;

/// `--out`'s default: the results root.
pub const DEFAULT_OUT: &str = "results";

#[derive(clap::Args)]
#[command(
    after_help = "Configs: configs/experiments/{teaser,teaser_no_nee,quality,complexity,\
    absorption,distributions,nee,fallback}.toml. Each writes OUT/<name>/report.md with its figures \
    (OUT/<name>-quick/ with --quick).\n\n\
    Example:\n  stcvae experiment configs/experiments/teaser.toml --quick"
)]
pub struct Args {
    /// Experiment config (TOML).
    pub config: PathBuf,
    /// The reduced version (small images, few samples): seconds, for checks.
    #[arg(long)]
    pub quick: bool,
    /// Where renders run: auto (a hardware GPU if any, else the CPU), gpu or cpu.
    #[arg(long, value_enum, default_value_t = DeviceArg::Auto)]
    pub device: DeviceArg,
    /// Results root; the experiment writes `OUT/<config name>/` (`OUT/<config name>-quick/`
    /// with --quick).
    #[arg(long, default_value = DEFAULT_OUT)]
    pub out: PathBuf,
    /// Model file (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    pub model: Option<PathBuf>,
}

/// What every experiment kind gets.
pub struct Ctx<'a> {
    pub cfg: &'a Config,
    pub budget: Budget,
    pub engine: &'a Engine,
    pub model: Option<PathBuf>,
    pub out: PathBuf,
    /// Whether this run has saved a file yet ([`Ctx::saved_one`]).
    saved: std::cell::Cell<bool>,
    /// Warnings said during the run (key, text), each once, repeated in the report (a
    /// model extrapolating showed only on the terminal).
    pub warnings: std::cell::RefCell<Vec<(String, String)>>,
}

impl Ctx<'_> {
    /// Called after every file a run saves into its folder (renders, pictures, plots,
    /// metrics): the first removes the earlier run's report.md and figures.csv, which no
    /// longer describe the folder's images, however this run then ends (a second Ctrl-C
    /// or a kill skips any clean-up). Until a file of this run is in place they stay: a
    /// run that saves nothing leaves them as they were (removed up front, an interrupted
    /// rerun took a finished run's report with it; removed before the first save, a full
    /// disk at the first image did).
    pub fn saved_one(&self) -> Result<()> {
        // Set first: a report that cannot be removed (an immutable file) fails the run
        // with a file of it saved, and the message then says where.
        if !self.saved.replace(true) {
            for stale in ["report.md", "figures.csv"] {
                let p = self.out.join(stale);
                if p.is_file() {
                    std::fs::remove_file(&p)
                        .with_context(|| format!("cannot remove {}", p.display()))?;
                }
            }
        }
        Ok(())
    }
}

pub fn run(a: Args) -> Result<()> {
    let cfg = Config::load(&a.config)?;
    let name = a
        .config
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "experiment".into());
    kinds::preflight(&cfg, a.model.as_deref()).with_context(|| a.config.display().to_string())?;
    // A quick run has a folder of its own: it wrote over a full run's images and report
    // (hours of rendering) in the same one.
    let out = a.out.join(if a.quick {
        format!("{name}-quick")
    } else {
        name.clone()
    });
    // A file where the folder or a report goes, or an unwritable place, fails now rather
    // than after the renders (the reports' checks cover their folder's).
    for f in ["report.md", "figures.csv"] {
        crate::check_out("--out", &out.join(f))?;
    }
    // The scene files, read once for the checks below (preflight has checked them).
    let scenes = kinds::scene_paths(&cfg)
        .into_iter()
        .map(|p| Ok((SceneFile::load(&p)?, p)))
        .collect::<Result<Vec<_>>>()?;
    check_inputs_outside(&a, &scenes, &out)?;
    // The device and the model first: a run that cannot start leaves no empty folder behind.
    let engine = open_engine(&a, &cfg, &scenes)?;
    // The folders this run makes, innermost first, so that a run that saves nothing can
    // take them all away again (the results root too, when this run made it).
    let made: Vec<PathBuf> = out
        .ancestors()
        .take_while(|p| !p.as_os_str().is_empty() && !p.exists())
        .map(PathBuf::from)
        .collect();
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    // (The reports are written anew at the end: never named as left over.)
    let before = crate::left_over::Snapshot::take(&out);
    let ctx = Ctx {
        cfg: &cfg,
        budget: if a.quick { cfg.quick } else { cfg.full },
        engine: &engine,
        model: a.model.clone(),
        out: out.clone(),
        saved: std::cell::Cell::new(false),
        warnings: Default::default(),
    };
    let mut rep = Report::new(&cfg, &a, &engine);
    rep.text(&budget_line(&cfg, &ctx.budget));
    eprintln!(
        "experiment {name} ({}{}) -> {}",
        cfg.kind.name(),
        if a.quick { ", quick" } else { "" },
        crate::paths::shown(&out)
    );
    // Ctrl-C is a request to stop after the current render pass (measure::render_once).
    crate::interrupt::flag();
    if let Err(e) = kinds::run(&ctx, &mut rep) {
        return Err(failed_run(e, &out, ctx.saved.get(), &made, &before));
    }
    for (_, w) in ctx.warnings.borrow().iter() {
        rep.text(&format!("\n**Warning:** {w}."));
    }
    rep.write(&out)?;
    before.note_left_over("report.md");
    eprintln!("wrote {}", crate::paths::shown(&out.join("report.md")));
    Ok(())
}

/// The engine the run renders on, its light limit checked against every scene, and the
/// model named by --model read (so that a run that cannot start has made no folder).
fn open_engine(a: &Args, cfg: &Config, scenes: &[(SceneFile, PathBuf)]) -> Result<Engine> {
    // `distributions` samples the models and the simulator and renders nothing: no device
    // to look for (it said "rendering on the CPU").
    let device = if cfg.kind == config::Kind::Distributions {
        DeviceArg::Cpu
    } else {
        a.device
    };
    let engine = Engine::open(device)?.without_fallback();
    // The GPU's light limit, which only the chosen device knows, before any render too (a
    // scene past it failed the run at its first render, after the renders before it).
    // (`quality` replaces a scene's lights with one delta light of its own.)
    if engine.is_gpu() && cfg.kind != config::Kind::Quality {
        for (f, path) in scenes {
            crate::device::check_gpu_lights(path, f.lights.len(), ": use --device cpu")
                .with_context(|| a.config.display().to_string())?;
        }
    }
    if a.model.is_some() {
        crate::model_cmds::load_model(a.model.as_deref())?;
    }
    Ok(engine)
}

/// The error of a run that failed part way, after the clean-up its state asks for: the
/// folders `made` are removed again if the run `saved` nothing, and the message says what
/// of an earlier run or of this one stays in `out` (`before` names an earlier run's files).
fn failed_run(
    e: anyhow::Error,
    out: &Path,
    saved: bool,
    made: &[PathBuf],
    before: &crate::left_over::Snapshot,
) -> anyhow::Error {
    // A run that saved files removed the earlier report after its first (Ctx::saved_one);
    // one stopped before it saved anything leaves the earlier run's results as they
    // were.
    if !saved && out.join("report.md").is_file() {
        return anyhow::anyhow!(
            "{e:#} (nothing was saved: the earlier run's report in {} is as it was)",
            out.display()
        );
    }
    // A run stopped before it saved anything leaves no empty folder (remove_dir
    // removes only an empty one); one that saved images says where they are.
    let _ = std::fs::remove_dir(out);
    if !out.exists() {
        for dir in made.iter().skip(1) {
            if std::fs::remove_dir(dir).is_err() {
                break;
            }
        }
    }
    if out.exists() {
        // Files of an earlier run that this one did not reach keep their names: say
        // so, or the folder reads as this run's alone.
        before.note_left_over("saved images");
        return anyhow::anyhow!("{e:#} (images saved so far stay in {})", out.display());
    }
    e
}

/// What was rendered, so that paths/s and noise can be checked against the files: the
/// image width, and the samples actually taken (an experiment's spp are two seeds of
/// half each, rounded up to a multiple of 3, so 256 asked are 258 rendered).
fn budget_line(cfg: &Config, b: &config::Budget) -> String {
    match cfg.kind {
        config::Kind::Distributions => format!(
            "Samples: {} model draws and as many simulator walks per setting.\n",
            b.samples()
        ),
        config::Kind::Nee => format!(
            "Renders: {} pixels wide (the scene's aspect kept); budgets of {}, {} and {} s \
             per method ({} s each in all); the reference is PT with NEE at {} spp.\n",
            b.size(),
            b.seconds() / 4.0,
            b.seconds() / 2.0,
            b.seconds(),
            1.75 * b.seconds(),
            b.reference_spp()
        ),
        _ => {
            let half = measure::half_spp(b.spp());
            format!(
                "Renders: {} pixels wide (the scene's aspect kept), {} spp each: two seeds of \
                 {half} ({} asked, halved and rounded up to a multiple of 3 so that every \
                 pixel gives each colour channel as many samples). Next-event estimation \
                 {} in both integrators.\n",
                b.size(),
                2 * half,
                b.spp(),
                if cfg.nee() {
                    "on"
                } else {
                    "off (only paths escaping into a light's disk or the environment count)"
                }
            )
        }
    }
}

/// What an experiment writes into its output folder: images (EXR, PNG, JSON), plots, the
/// figures' CSV and the report.
const WRITTEN_EXTS: [&str; 5] = ["exr", "png", "json", "csv", "md"];

/// Refuses an input (the config, the model, a scene and the files it reads) in the output
/// folder under a name of the kind the run writes there: a `--model` named figures.csv in
/// it was removed as the previous run's figures, and the run failed at its next render.
fn check_inputs_outside(
    a: &Args,
    scenes: &[(SceneFile, PathBuf)],
    out: &std::path::Path,
) -> Result<()> {
    let mut inputs = vec![("the config".to_string(), a.config.clone())];
    inputs.extend(a.model.iter().map(|m| ("--model".to_string(), m.clone())));
    for (f, path) in scenes {
        inputs.extend(crate::render::scene_inputs(path, f));
    }
    let folder = crate::paths::identity(out);
    for (what, p) in &inputs {
        let written = p
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| WRITTEN_EXTS.iter().any(|x| e.eq_ignore_ascii_case(x)));
        if written && crate::paths::identity(p).parent() == Some(folder.as_path()) {
            anyhow::bail!(
                "{what} {} is in the output folder {}, where the run writes and replaces \
                 .exr, .png, .json, .csv and .md files: move it or choose another --out",
                p.display(),
                out.display()
            );
        }
    }
    Ok(())
}
