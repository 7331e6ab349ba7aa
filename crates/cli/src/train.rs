//! `stcvae train`: the three CVAEs from a dataset, concurrently, to a model file.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::prelude::Device;
use cvae::model_file::{ModelSet, SingleScattering, TrainingInfo};
use cvae::train::data::ConditionRanges;
use cvae::train::validation::{MIN_VALIDATION_ROWS, VALIDATION_ROWS, Validation, ValidationPoint};
use cvae::train::{ModelConfig, ModelKind, Table, TrainError, train_model};
use indicatif::{MultiProgress, ProgressBar};
use scatter_sim::dataset::{held_out_rows, read_dataset};
use serde::Deserialize;

use crate::generate::parse_toml;
use crate::{interrupt, progress};

#[derive(clap::Args)]
#[command(
    after_help = "Example:\n  stcvae train --config configs/train/default.toml\n\n\
    The default config writes models/trained.stcvae; the shipped models/default.stcvae, \
    which `render` reads by default, is left as it is.\n\n\
    The three models train concurrently, one thread each. If the dataset named in the config \
    does not exist it is generated first from `dataset_config`. Ctrl-C saves a checkpoint; \
    --resume continues from it. Checkpoints already in checkpoint_dir stop a new run unless \
    --resume or --fresh says what to do with them. A run holds its checkpoint_dir (a lock on \
    its .train.lock): a second run on the same folder is refused.\n\n\
    Validation: 4,096 walks the dataset's run would have drawn next are simulated as held-out \
    walks; at each report every model's loss on up to 2,048 of them (those of the kind it \
    trains on) is read beside its loss on \
    as many of its training walks (both with fixed draws), shown on the progress bar, plotted beside \
    the model file (NAME.loss.png), and a held-out loss far above the training walks' is \
    reported as memorising."
)]
pub struct Args {
    /// Training config (TOML).
    #[arg(long, default_value = DEFAULT_CONFIG)]
    config: PathBuf,
    /// Train only this model (lengthgen, pathgen or eventgen); the other two decoders of
    /// the exported file come from their checkpoints.
    #[arg(long)]
    model: Option<ModelKind>,
    /// With --model: take the other two decoders from this model file instead of their
    /// checkpoints (e.g. retrain EventGen alone against the shipped models/default.stcvae).
    #[arg(long, requires = "model", value_parser = crate::shipped::model_arg)]
    base: Option<PathBuf>,
    /// Continue from the checkpoints in the config's checkpoint_dir.
    #[arg(long)]
    resume: bool,
    /// Start over although the config's checkpoint_dir holds checkpoints of the models to
    /// train: they are removed as the training starts. Without --resume or --fresh, such
    /// checkpoints make `train` stop before any work.
    #[arg(long, conflicts_with = "resume")]
    fresh: bool,
    /// Output model file (overrides the config).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Scale every model's step count, in (0, 1000] (e.g. 0.01 for a smoke test); a
    /// scaled run's warm-up is at most a quarter of its steps.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.0)]
    steps_scale: f64,
    /// burn backend: flex (pure-Rust CPU, the default) or wgpu (GPU through wgpu; needs a
    /// build with `--features stcvae/wgpu-train`).
    #[arg(long, default_value = "flex", value_parser = ["flex", "wgpu"])]
    backend: String,
    /// Write the model file although a decoder in it, trained now or taken from its
    /// checkpoint, ended with a loss above its untrained network's (above the first
    /// batch's by more than a tenth of it, or 0.1 where it is below 1 in size: it diverged
    /// or learned nothing); without it `train` stops before writing such a file.
    #[arg(long)]
    keep_diverged: bool,
}

/// The training device of `--backend`, with autodiff.
fn device(backend: &str) -> Result<Device> {
    match backend {
        "wgpu" => {
            #[cfg(feature = "wgpu-train")]
            {
                Ok(Device::wgpu(burn::tensor::DeviceKind::DefaultDevice).autodiff())
            }
            #[cfg(not(feature = "wgpu-train"))]
            bail!(
                "--backend wgpu: this binary was built without the GPU backend; rebuild with \
                 `cargo run --release --features stcvae/wgpu-train -- train --backend wgpu`"
            )
        }
        _ => Ok(Device::flex().autodiff()),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TrainConfig {
    dataset: PathBuf,
    /// Dataset config used to generate `dataset` when it does not exist.
    dataset_config: Option<PathBuf>,
    out: PathBuf,
    checkpoint_dir: PathBuf,
    #[serde(default = "one")]
    seed: u64,
    #[serde(default = "exact")]
    single_scattering: SingleScattering,
    #[serde(
        default = "checkpoint_every",
        deserialize_with = "crate::generate::at_least_one"
    )]
    checkpoint_every: u64,
    lengthgen: ModelConfig,
    pathgen: ModelConfig,
    eventgen: ModelConfig,
}

fn one() -> u64 {
    1
}
fn exact() -> SingleScattering {
    SingleScattering::Exact
}
fn checkpoint_every() -> u64 {
    5000
}

impl TrainConfig {
    fn model(&self, k: ModelKind) -> &ModelConfig {
        match k {
            ModelKind::LengthGen => &self.lengthgen,
            ModelKind::PathGen => &self.pathgen,
            ModelKind::EventGen => &self.eventgen,
        }
    }
}

/// The shipped training config, relative to the repository root.
const DEFAULT_CONFIG: &str = "configs/train/default.toml";

/// Paths in a config are relative to the current directory (the repository root for
/// the shipped configs), like every other path on the command line.
fn load(path: &Path) -> Result<TrainConfig> {
    let text = scatter_sim::output::read_input_to_string(path).with_context(|| {
        // The default's paths inside (dataset, dataset_config, checkpoints, out) are
        // relative to the repository root too, so it is not looked for elsewhere.
        let hint = if path == Path::new(DEFAULT_CONFIG) && !path.exists() {
            " (run from the repository root, where the shipped configs are, or pass --config)"
        } else {
            ""
        };
        format!("cannot read training config {}{hint}", path.display())
    })?;
    crate::generate::wrong_kind(path, &text, render_gpu::scene::ConfigKind::Training)?;
    let cfg: TrainConfig = parse_toml(path, &text)?;
    // An empty path is the current directory (nine checkpoint files landed there) or no
    // file at all ("error: : No such file or directory" after the dataset was made).
    let paths = [
        ("dataset", Some(&cfg.dataset)),
        ("dataset_config", cfg.dataset_config.as_ref()),
        ("out", Some(&cfg.out)),
        ("checkpoint_dir", Some(&cfg.checkpoint_dir)),
    ];
    if let Some((field, _)) = paths
        .iter()
        .find(|(_, p)| p.is_some_and(|p| p.as_os_str().is_empty()))
    {
        bail!("{}: {field} = \"\" names no path", path.display());
    }
    // A CSV was generated in full (2^22 walks with the shipped config) and then refused as
    // "not an stcvae dataset (bad magic bytes)".
    if scatter_sim::dataset::is_csv(&cfg.dataset) {
        bail!(
            "{}: dataset = \"{}\": train reads binary datasets (e.g. .bin; `stcvae generate` \
             writes one for any other name than .csv)",
            path.display(),
            cfg.dataset.display()
        );
    }
    // 0 turned the periodic checkpoints off without a word: a kill (not a Ctrl-C, which
    // saves one) after most of an hour lost the whole run.
    if cfg.checkpoint_every == 0 {
        bail!(
            "{}: checkpoint_every = 0 is out of range: allowed {} (steps between checkpoints)",
            path.display(),
            scatter_sim::ranges::whole_range(1, u64::MAX)
        );
    }
    for k in ModelKind::ALL {
        cfg.model(k)
            .validate(k.name())
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    Ok(cfg)
}

fn ensure_dataset(cfg: &TrainConfig) -> Result<()> {
    if cfg.dataset.exists() {
        return Ok(());
    }
    let Some(dc) = &cfg.dataset_config else {
        // A relative path is read from the working directory, not the config's folder (a
        // config run from elsewhere named only the bare file).
        let from = if cfg.dataset.is_relative() {
            std::env::current_dir().map_or(String::new(), |d| {
                format!(" (relative to the working directory, {})", d.display())
            })
        } else {
            String::new()
        };
        bail!(
            "dataset = \"{}\"{from} does not exist, and the config names no dataset_config to \
             generate it",
            cfg.dataset.display()
        );
    };
    eprintln!(
        "dataset {} not found: generating it from {} first",
        crate::paths::shown(&cfg.dataset),
        crate::paths::shown(dc)
    );
    crate::generate::generate_from_config(dc, &cfg.dataset)
}

/// A dataset that is there is trained on as it is, but one that is not the whole run its
/// `dataset_config` describes (the config edited since, or another `generate` written
/// over it) is a warning: the model would learn other walks than the config says, unsaid.
fn not_the_configs_run(
    dataset: &Path,
    config: &Path,
    header: &scatter_sim::dataset::Header,
) -> Option<String> {
    // A warning's check: a config that does not load (not needed while the dataset is
    // there) is said, not fatal.
    let dc = match crate::generate::load_config(config) {
        Ok(dc) => dc,
        Err(e) => {
            return Some(format!(
                "note: {} is not compared with its dataset_config: {e:#}",
                dataset.display()
            ));
        }
    };
    let run = scatter_sim::dataset::Piece {
        seed: dc.seed,
        sampler: dc.conditions,
        total_walks: dc.walks,
        first_walk: 0,
        count: dc.walks,
        simulator: None,
    };
    // `merge` refuses overlapping pieces of one run, so pieces of the run that add up to
    // its size are the whole of it.
    if header.count == dc.walks && header.pieces.iter().all(|p| p.same_run(&run)) {
        return None;
    }
    let first = header.pieces.first();
    let holds = match first {
        Some(p) if header.pieces.iter().all(|q| q.same_run(p)) => format!(
            "{} walks of a run with seed {}, {} walks{}",
            header.count,
            p.seed,
            p.total_walks,
            if p.sampler == run.sampler {
                ", the config's conditions"
            } else {
                ", other conditions"
            }
        ),
        Some(_) => format!("{} walks of several runs", header.count),
        None => "no walks".to_owned(),
    };
    Some(format!(
        "warning: {} is not the run {} describes (seed {}, {} walks): it holds {holds}. \
         Training on it as it is; remove it to generate the config's run",
        dataset.display(),
        config.display(),
        dc.seed,
        dc.walks
    ))
}

/// A dataset drawn by another build's simulator (its fingerprint recorded and not this
/// build's) is a warning: the validation loss compares its rows with held-out walks this
/// build simulates, so a changed simulator reads as a gap between the two losses, and the
/// model learns the old simulator's walks.
fn another_simulator(dataset: &Path, header: &scatter_sim::dataset::Header) -> Option<String> {
    let this = scatter_sim::dataset::simulator_fingerprint();
    let mut others = header.simulators().0;
    others.retain(|s| *s != this);
    (!others.is_empty()).then(|| {
        format!(
            "warning: {} was generated by another simulator (fingerprint {}; this build's is \
             {this}: another version, platform or dependency): the model learns that \
             simulator's walks, and the held-out loss compares them with this build's. \
             Remove it to generate it anew",
            dataset.display(),
            others.join(", ")
        )
    })
}

/// Below this many usable walks per model `train` warns: a CVAE's conditional
/// distribution cannot be learned from fewer, though a test may still want to try.
const MIN_ROWS: usize = 1000;

/// A decoder read from its checkpoint: the decoder, its feature version, the condition
/// ranges it was trained on (None for checkpoints that predate recording them), its step,
/// and its loss's rise where it rose ([`loss_rise`]).
type CheckpointDecoder = (
    cvae::decoder::Decoder,
    u32,
    Option<ConditionRanges>,
    u64,
    Option<String>,
);

/// The decoder of `k` from the config's checkpoint folder, for a model file whose other
/// decoders are trained now (see [`CheckpointDecoder`]).
fn checkpoint_decoder(
    cfg: &TrainConfig,
    k: ModelKind,
    steps_scale: f64,
) -> Result<CheckpointDecoder> {
    let (d, info) =
        cvae::train::trainer::load_decoder(&cfg.checkpoint_dir, k, &cfg.model(k).architecture())
            .with_context(|| {
                // A checkpoint that is there but cannot be read is damaged or from another
                // architecture: training it "first" is not the advice then.
                if cvae::train::trainer::has_checkpoint(&cfg.checkpoint_dir, k) {
                    format!(
                        "the model file needs {0}, whose checkpoint in {1} cannot be used: \
                         retrain it (train --model {0} --fresh), or take it from a model file \
                         with --base",
                        k.name(),
                        cfg.checkpoint_dir.display()
                    )
                } else {
                    format!(
                        "the model file needs {}: train it first (or all three at once), or \
                         take it from a model file with --base",
                        k.name()
                    )
                }
            })?;
    let version = info.feature_version;
    if cvae::features::EventRadial::of_version(version).is_none() {
        bail!(
            "the {} checkpoint has feature version {version}, which this build does not read",
            k.name()
        );
    }
    // A decoder trained the other way would be read wrongly by the file's sampler: a
    // learned-mode EventGen in an exact-mode file counts the centre event twice, an
    // exact-mode LengthGen in a learned-mode file loses every N = 1 walk.
    if let Some(m) = info.single_scattering
        && m != cfg.single_scattering
    {
        bail!(
            "the {} checkpoint in {} was trained with single_scattering = {} and the config \
             says {}: retrain it too (train without --model, with --fresh), or take it from a \
             model file with --base",
            k.name(),
            cfg.checkpoint_dir.display(),
            m.name(),
            cfg.single_scattering.name()
        );
    }
    // A checkpoint left by an interrupted run is taken as it is, but not unsaid. Finished
    // or not by its own run's steps (a run stopped at step 4,000 of 400,000 was taken as
    // finished by a run scaled to 4,000); older checkpoints, which do not record them, by
    // the steps as this run scales them.
    let this_run = scaled_steps(cfg.model(k).steps, steps_scale);
    let steps = info.plan.as_ref().map_or(this_run, |p| p.steps);
    if info.step < steps {
        eprintln!(
            "note: {} comes from its checkpoint at step {} of {steps}: an unfinished training \
             (train it on with --model {} --resume{})",
            k.name(),
            info.step,
            k.name(),
            if steps != this_run {
                " and the settings it was started with".to_owned()
            } else if steps_scale == 1.0 {
                String::new()
            } else {
                format!(" --steps-scale {}", scatter_sim::ranges::num(steps_scale))
            }
        );
    }
    let rise = loss_rise(k, &info.history);
    Ok((d, version, info.ranges, info.step, rise))
}

/// The command that goes on from an interrupted run's checkpoints: the run's own with
/// --resume for --fresh ("the same command with --resume" was `--fresh --resume`, which
/// clap refuses).
fn resume_command(a: &Args) -> String {
    let mut c = format!(
        "stcvae train --config {}",
        crate::paths::shell_word(&a.config)
    );
    if let Some(k) = a.model {
        c += &format!(" --model {}", k.name());
    }
    if let Some(b) = &a.base {
        c += &format!(" --base {}", crate::paths::shell_word(b));
    }
    c += " --resume";
    if let Some(o) = &a.out {
        c += &format!(" --out {}", crate::paths::shell_word(o));
    }
    if a.steps_scale != 1.0 {
        c += &format!(" --steps-scale {}", scatter_sim::ranges::num(a.steps_scale));
    }
    if a.backend != "flex" {
        c += &format!(" --backend {}", a.backend);
    }
    if a.keep_diverged {
        c += " --keep-diverged";
    }
    c
}

/// The models a run trains: the one `--model` names, else all three.
fn trained_kinds(model: Option<ModelKind>) -> Vec<ModelKind> {
    match model {
        Some(k) => vec![k],
        None => ModelKind::ALL.to_vec(),
    }
}

/// A model's steps under `--steps-scale`: rounded, at least one.
fn scaled_steps(steps: u64, scale: f64) -> u64 {
    ((steps as f64 * scale).round() as u64).max(1)
}

/// A model's configuration under `--steps-scale`. A config's own warm-up is kept as
/// written at scale 1 (it was shortened to a quarter of the steps without a word); a
/// scaled run's is capped at a quarter of its steps so that its rate still decays.
fn scaled_model(m: &ModelConfig, scale: f64) -> ModelConfig {
    let mut m = m.clone();
    if scale != 1.0 {
        let warmup = m.warmup();
        m.steps = scaled_steps(m.steps, scale);
        m.warmup = Some(warmup.min(m.steps / 4));
    }
    m
}

/// The untrained loss when a run's last reported loss is above it by more than a tenth
/// (of it, or of 1 near 0): the first report is one step's batch, so a margin keeps its
/// noise from refusing a model that did learn. Losses may be negative (the
/// log-variance heads).
fn loss_rose(history: &[(u64, f32)]) -> Option<f32> {
    let (&(_, first), &(_, last)) = (history.first()?, history.last()?);
    (last > first + 0.1 * first.abs().max(1.0)).then_some(first)
}

/// "K's from FIRST (untrained) to LAST" where `k`'s loss rose ([`loss_rose`]): how the
/// refusals of a diverged model name it, trained now or taken from its checkpoint.
fn loss_rise(k: ModelKind, history: &[(u64, f32)]) -> Option<String> {
    let first = loss_rose(history)?;
    let last = history.last()?.1;
    Some(format!(
        "{}'s from {first:.4} (untrained) to {last:.4}",
        k.name()
    ))
}

/// Held-out walks simulated for the validation loss: twice the rows a validation reads,
/// so that models which leave walks out (N = 1 in exact mode, EventGen's centre events)
/// still find enough.
const HELD_OUT_WALKS: u64 = 2 * VALIDATION_ROWS as u64;

/// Held-out losses this far above the training walks' (`ValidationPoint::gap_z`, N(0, 1)
/// while the model generalises) are reported as memorising: noise alone passes it with
/// probability ~3·10⁻⁵ at 2,048 rows a side (~1.5·10⁻⁴ at the fewest, 20, where z follows
/// Student's t with ~38 degrees of freedom).
const GAP_WARNING_Z: f32 = 4.0;

/// Each model's validation batches: walks the dataset's run would have drawn next,
/// simulated now, standardised as the model's table. A model with no usable held-out
/// walk trains without one, and says so.
fn validations(
    cfg: &TrainConfig,
    kinds: &[ModelKind],
    tables: &[Table],
    pieces: &[scatter_sim::dataset::Piece],
) -> Vec<Option<Validation>> {
    let t0 = Instant::now();
    let held = held_out_rows(pieces, HELD_OUT_WALKS);
    eprintln!(
        "{} held out for the validation loss (the walks the dataset's run would draw next), \
         simulated in {:.1} s",
        progress::count(held.len() as u64, "walk"),
        t0.elapsed().as_secs_f64()
    );
    kinds
        .iter()
        .zip(tables)
        .map(|(&k, t)| {
            let v = Validation::new(t, &Table::like(t, &held), cfg.model(k).latent, cfg.seed);
            if v.is_none() {
                eprintln!(
                    "note: fewer than {MIN_VALIDATION_ROWS} usable training or held-out walks for \
                     {}: it trains without a validation loss",
                    k.name()
                );
            }
            v
        })
        .collect()
}

/// The lock file a training run holds in its checkpoint_dir.
const CHECKPOINT_LOCK: &str = ".train.lock";

/// Holds `dir` for this run (an advisory lock, released when the process ends however it
/// ends). Two runs sharing a checkpoint_dir deleted each other's temporaries when they
/// started and then took turns overwriting the same checkpoints, whose checksums still
/// matched: a later --resume continued whichever saved last. A file system without locks
/// is warned about, not refused.
fn lock_checkpoint_dir(dir: &Path, config: &Path) -> Result<std::fs::File> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: checkpoint_dir = {}", config.display(), dir.display()))?;
    let path = dir.join(CHECKPOINT_LOCK);
    // Opening a named pipe there waited for a reader for ever.
    if path.exists() {
        scatter_sim::output::check_input(&path).with_context(|| format!("{}", path.display()))?;
    }
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    match f.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => bail!(
            "{}: checkpoint_dir = {} is in use by another `stcvae train` (it holds {}): wait \
             for it to end, or give this run a checkpoint_dir of its own",
            config.display(),
            dir.display(),
            path.display()
        ),
        Err(std::fs::TryLockError::Error(e)) => eprintln!(
            "warning: cannot lock {} ({e}): make sure no other training uses this \
             checkpoint_dir",
            path.display()
        ),
    }
    Ok(f)
}

/// Where the loss curves of model file `out` go: NAME.loss.png for NAME.stcvae, else the
/// whole file name with .loss.png added (`with_extension` gave m.v1 and m.v2 one plot).
fn loss_plot_path(out: &Path) -> PathBuf {
    let mut name = match out.extension() {
        Some(e) if e == "stcvae" => out.with_extension(""),
        _ => out.to_path_buf(),
    }
    .into_os_string();
    name.push(".loss.png");
    PathBuf::from(name)
}

/// The trained models' validation losses against their steps, as the PNG for
/// [`loss_plot_path`]; `None` when no model read any.
fn loss_plot(path: &Path, trained: &[cvae::train::Trained]) -> Result<Option<Vec<u8>>> {
    use crate::plots::{Series, line_plot_png};
    let mut series = Vec::new();
    // One colour per model, the same in every run whatever order the models finished in:
    // its training walks solid, its held-out walks dashed.
    for (i, kind) in ModelKind::ALL.into_iter().enumerate() {
        let Some(t) = trained
            .iter()
            .find(|t| t.kind == kind && !t.info.validation.is_empty())
        else {
            continue;
        };
        let points = |f: fn(&ValidationPoint) -> f32| {
            t.info
                .validation
                .iter()
                .map(|v| (v.step as f64, f64::from(f(v))))
                .collect()
        };
        series.push(Series {
            colour: Some(i),
            ..Series::new(
                format!("{} training walks", t.kind.name()),
                points(|v| v.train.0),
            )
        });
        series.push(Series {
            colour: Some(i),
            dashed: true,
            ..Series::new(
                format!("{} held-out walks", t.kind.name()),
                points(|v| v.held_out.0),
            )
        });
    }
    if series.is_empty() {
        return Ok(None);
    }
    line_plot_png(
        path,
        "Validation loss (negative ELBO, fixed draws)",
        "step",
        "loss",
        (true, false),
        &series,
    )
    .map(Some)
}

/// Narrows the file's ranges to what a decoder from elsewhere (`source`) was trained on:
/// the file's ranges bound every decoder in it (the renderer's default max_tau is
/// `tau_range[1]`), so with decoders from two trainings, only what both saw.
fn narrow(info: &mut TrainingInfo, other: ConditionRanges, source: &str) -> Result<()> {
    let both = |x: [f64; 2], y: [f64; 2]| [x[0].max(y[0]), x[1].min(y[1])];
    info.tau_range = both(info.tau_range, other.tau);
    info.g_range = both(info.g_range, other.g);
    info.albedo_range = both(info.albedo_range, other.albedo);
    for (name, r) in [
        ("tau", info.tau_range),
        ("g", info.g_range),
        ("albedo", info.albedo_range),
    ] {
        if !(r[0] <= r[1]) || (name == "tau" && r[1] <= 0.0) {
            bail!(
                "{source}: its {name} range and the dataset's do not overlap; the mixed model \
                 would hold decoders trained on disjoint conditions"
            );
        }
    }
    Ok(())
}

/// The model file's path (`--out`, else the config's `out`), refused before hours of
/// training where writing it would fail or replace what is not a model: checked here, not
/// when the model is saved. The checkpoint folder is checked as an output too.
fn model_out(a: &Args, cfg: &TrainConfig) -> Result<PathBuf> {
    let out = a.out.clone().unwrap_or_else(|| cfg.out.clone());
    let out_flag = match a.out {
        Some(_) => "--out".to_string(),
        None => format!("{}: out =", a.config.display()),
    };
    crate::check_out(&out_flag, &out)?;
    crate::check_out(
        &format!("{out_flag} (its loss curves)"),
        &loss_plot_path(&out),
    )?;
    // Nor a checkpoint's name: .bpk here, .json with the renders' reports.
    let not_models = [
        &crate::paths::IMAGE_EXTS[..],
        &crate::paths::CONFIG_EXTS,
        &crate::paths::DATASET_EXTS,
        &["bpk"],
    ]
    .concat();
    crate::paths::check_kind(&out_flag, &out, "a model file (.stcvae)", &not_models)?;
    // Whatever its name, an existing file is replaced only if it is a model file: a
    // dataset or scene without the usual extension was overwritten without a word.
    if let Ok(mut f) = std::fs::File::open(&out)
        && out.is_file()
    {
        use std::io::Read as _;
        let mut head = Vec::new();
        let _ = f.by_ref().take(8).read_to_end(&mut head);
        if !head.is_empty() && head != cvae::model_file::MAGIC {
            bail!(
                "{out_flag} {}: exists and is not an stcvae model file (it would be replaced): \
                 choose another name or remove it",
                out.display()
            );
        }
    }
    // Nor the checkpoints' folder itself: it failed only once training was done. (A
    // model saved over a checkpoint, which broke --resume, has a checkpoint's extension,
    // refused above; a model file beside the checkpoints is fine.)
    if crate::paths::identity(&out) == crate::paths::identity(&cfg.checkpoint_dir) {
        bail!(
            "{out_flag} {} is checkpoint_dir = {} of {}, the folder the checkpoints go \
             in: give the model a file name",
            out.display(),
            cfg.checkpoint_dir.display(),
            a.config.display()
        );
    }
    let field = |f: &str| format!("the config's {f}");
    let mut inputs = vec![
        ("--config".to_string(), a.config.clone()),
        (field("dataset"), cfg.dataset.clone()),
    ];
    inputs.extend(
        cfg.dataset_config
            .iter()
            .map(|p| (field("dataset_config"), p.clone())),
    );
    crate::paths::check_not_input(&out_flag, &out, &inputs)?;
    // So is the checkpoint directory, which the first checkpoint writes into minutes in.
    crate::check_out_dir(
        &format!("{}: checkpoint_dir =", a.config.display()),
        &cfg.checkpoint_dir,
    )?;
    Ok(out)
}

/// The `--base` model whose decoders fill those not trained now, read before hours of
/// training so that a wrong path fails at once; with its name as given.
fn load_base(a: &Args, cfg: &TrainConfig, out: &Path) -> Result<Option<(String, ModelSet)>> {
    Ok(match &a.base {
        Some(p) => {
            if crate::paths::identity(p) == crate::paths::identity(out) {
                bail!(
                    "--base {} is also the output: give --out another file, or the base would \
                     be overwritten by the mix",
                    p.display()
                );
            }
            let set = ModelSet::load(p).map_err(|e| anyhow::anyhow!("--base {e}"))?;
            if set.single_scattering != cfg.single_scattering {
                bail!(
                    "--base {}: its single_scattering ({}) differs from the config's ({})",
                    p.display(),
                    set.single_scattering.name(),
                    cfg.single_scattering.name()
                );
            }
            Some((p.display().to_string(), set))
        }
        None => None,
    })
}

/// The models of `kinds` this run continues from their checkpoints, after refusing what
/// would lose or misread a checkpoint: a record without its JSON, `--resume` with nothing
/// to continue, or a new run over checkpoints it would replace (neither `--resume` nor
/// `--fresh`).
fn checkpoints_to_resume(
    a: &Args,
    cfg: &TrainConfig,
    kinds: &[ModelKind],
) -> Result<Vec<ModelKind>> {
    if !a.fresh
        && let Some(p) = kinds
            .iter()
            .find_map(|&k| cvae::train::trainer::orphan_record(&cfg.checkpoint_dir, k))
    {
        let stem = p.file_stem().unwrap_or_default().to_string_lossy();
        let name = stem.trim_end_matches("-optim");
        bail!(
            "{}: a checkpoint record without its {name}.json beside it (the JSON was removed, \
             or a save was cut short): it cannot be resumed; --fresh --model {name} removes it \
             and trains from the start",
            p.display()
        );
    }
    // The models this run continues (their notes count the seconds of the runs before).
    let resumed: Vec<ModelKind> = kinds
        .iter()
        .copied()
        .filter(|&k| a.resume && cvae::train::trainer::has_checkpoint(&cfg.checkpoint_dir, k))
        .collect();
    if a.resume {
        // Resuming from nothing used to start afresh without a word.
        let missing: Vec<&str> = kinds
            .iter()
            .filter(|k| !resumed.contains(k))
            .map(|k| k.name())
            .collect();
        if missing.len() == kinds.len() {
            bail!(
                "--resume: {} holds no checkpoint to continue from; train without --resume to \
                 start afresh",
                cfg.checkpoint_dir.display()
            );
        }
        if !missing.is_empty() {
            eprintln!(
                "note: --resume: no checkpoint of {} in {}: {} from the start",
                missing.join(", "),
                cfg.checkpoint_dir.display(),
                if missing.len() == 1 {
                    "it trains"
                } else {
                    "they train"
                }
            );
        }
    }
    if !a.resume && !a.fresh {
        // A new run replaces the checkpoints as it saves its own: a smoke test (e.g.
        // --steps-scale 0.01) would silently end an hour-long run's chance to --resume.
        let held: Vec<&str> = kinds
            .iter()
            .filter(|&&k| cvae::train::trainer::has_checkpoint(&cfg.checkpoint_dir, k))
            .map(|k| k.name())
            .collect();
        if !held.is_empty() {
            bail!(
                "{} holds checkpoints of {} (checkpoint_dir in {}): pass --resume to continue \
                 them, or --fresh to start over and replace them",
                cfg.checkpoint_dir.display(),
                held.join(", "),
                a.config.display()
            );
        }
    }
    Ok(resumed)
}

/// The dataset (generated first where the config says how and it is missing), read and
/// turned into one table per model of `kinds`; refused where a model would have no walks
/// to learn from.
fn read_tables(
    cfg: &TrainConfig,
    kinds: &[ModelKind],
) -> Result<(
    scatter_sim::dataset::Header,
    Vec<scatter_sim::dataset::Row>,
    Vec<Table>,
)> {
    ensure_dataset(cfg)?;
    let t0 = Instant::now();
    eprintln!("reading {}", cfg.dataset.display());
    let (header, rows) = read_dataset(&cfg.dataset)?;
    if let Some(dc) = &cfg.dataset_config
        && let Some(w) = not_the_configs_run(&cfg.dataset, dc, &header)
    {
        eprintln!("{w}");
    }
    if let Some(w) = another_simulator(&cfg.dataset, &header) {
        eprintln!("{w}");
    }
    let tables: Vec<Table> = kinds
        .iter()
        .map(|&k| Table::build(k, &rows, cfg.single_scattering))
        .collect();
    for (k, t) in kinds.iter().zip(&tables) {
        if t.rows == 0 {
            let why = if cfg.single_scattering != SingleScattering::Exact {
                "the dataset is empty; generate one with more samples"
            } else if *k == ModelKind::EventGen && t.ranges.albedo[1] <= 0.0 {
                // The reservoir keeps event 1, the centre, whenever the albedo is 0.
                "every walk has albedo 0, whose representative event is always the centre, \
                 which exact mode draws without EventGen; generate a dataset with albedo > 0"
            } else {
                "it needs walks with N >= 2 and, for EventGen, events other than the centre; \
                 generate a dataset with larger tau or more samples"
            };
            bail!(
                "{}: none of its {} walks is usable for {} ({why})",
                cfg.dataset.display(),
                rows.len(),
                k.name(),
            );
        }
        if t.rows < MIN_ROWS {
            eprintln!(
                "warning: {} has only {} for {}: too few to learn a distribution \
                 (the shipped model used 2^22 walks)",
                cfg.dataset.display(),
                progress::count(t.rows as u64, "usable walk"),
                k.name()
            );
        }
    }
    // Each model's count: EventGen's also leaves out walks whose only event is the centre.
    let used: Vec<String> = kinds
        .iter()
        .zip(&tables)
        .map(|(k, t)| format!("{} {}", k.name(), t.rows))
        .collect();
    eprintln!(
        "{} walks (used: {}; {}), read and prepared in {:.1} s",
        rows.len(),
        used.join(", "),
        if cfg.single_scattering == SingleScattering::Exact {
            "N >= 2; N = 1 is exact"
        } else {
            "all, the paper's way"
        },
        t0.elapsed().as_secs_f64()
    );
    Ok((header, rows, tables))
}

/// Trains each model of `kinds` on its own thread, with a progress bar each, and returns
/// them with the seconds the training took. One model's failure stops the others at their
/// next step (each with a checkpoint); an interrupt ends with the command that resumes.
fn train_models(
    a: &Args,
    cfg: &TrainConfig,
    device: &Device,
    kinds: &[ModelKind],
    tables: &[Table],
    validations: &[Option<Validation>],
    resumed: &[ModelKind],
) -> Result<(Vec<cvae::train::Trained>, f64)> {
    // The handler is installed already (`run`): this is its flag.
    let cancel = interrupt::flag();
    let multi = MultiProgress::with_draw_target(crate::progress::target());
    let scaled = |k: ModelKind| scaled_model(cfg.model(k), a.steps_scale);
    let bars: Vec<ProgressBar> = kinds
        .iter()
        .map(|&k| {
            let pb = multi.add(progress::bar(scaled(k).steps, "steps"));
            pb.set_prefix(k.name());
            pb.set_message(format!("{:>9}", k.name()));
            pb
        })
        .collect();
    let report = |k: ModelKind, step: u64, loss: f32, v: Option<&ValidationPoint>| {
        if let Some(i) = kinds.iter().position(|&x| x == k) {
            // A resumed run's first report jumps from 0 to the checkpoint's step: the
            // rate and ETA are measured from there, not from the jump.
            let resumed = bars[i].position() == 0 && step > 1;
            bars[i].set_position(step);
            if resumed {
                bars[i].reset_eta();
            }
            let held = v.map_or(String::new(), |v| {
                format!(
                    ", held-out {:.4} (training walks {:.4})",
                    v.held_out.0, v.train.0
                )
            });
            bars[i].set_message(format!("{:>9} loss {loss:.4}{held}", k.name()));
        }
    };
    let start = Instant::now();
    // Each with its model's index: the threads finish in any order.
    let results: Mutex<Vec<(usize, Result<cvae::train::Trained, TrainError>)>> =
        Mutex::new(Vec::new());
    // The model whose failure stopped the others (usize::MAX: none): a model stopped by it
    // may fail too (its stop checkpoint cannot be saved), and its error is not the cause.
    let first_failure = std::sync::atomic::AtomicUsize::new(usize::MAX);
    std::thread::scope(|s| {
        for (i, &k) in kinds.iter().enumerate() {
            let table = &tables[i];
            let validation = validations[i].as_ref();
            let mc = scaled(k);
            let (results, report, bar) = (&results, &report, &bars[i]);
            let first_failure = &first_failure;
            let device = device.clone();
            s.spawn(move || {
                // A panic inside burn or the optimiser (a resumed optimiser state whose
                // tensors have another shape than the model's) is an error of this model:
                // it ended the command with "a scoped thread panicked".
                let r = scatter_sim::quiet::quietly(|| {
                    train_model(
                        k,
                        table,
                        &mc,
                        cfg.seed,
                        &device,
                        &cfg.checkpoint_dir,
                        cfg.checkpoint_every,
                        a.resume,
                        cancel,
                        validation,
                        report,
                    )
                })
                .unwrap_or_else(|panic| {
                    let what = scatter_sim::quiet::panic_text(&*panic);
                    Err(TrainError::Failed(if resumed.contains(&k) {
                        format!(
                            "{}: {}'s training stopped on an error ({what}): the checkpoint it \
                             resumed may have been edited or damaged; start over with --fresh \
                             --model {}",
                            cfg.checkpoint_dir.display(),
                            k.name(),
                            k.name()
                        )
                    } else {
                        format!(
                            "{}'s training stopped on an internal error: {what}",
                            k.name()
                        )
                    }))
                });
                bar.finish();
                // One model's failure (a checkpoint that does not fit, a divergence) stops
                // the others at their next step, each with a checkpoint: they trained on to
                // their end (40 minutes at the default size) before the error was shown.
                if matches!(&r, Err(e) if !matches!(e, TrainError::Interrupted(_))) {
                    let _ = first_failure.compare_exchange(
                        usize::MAX,
                        i,
                        std::sync::atomic::Ordering::SeqCst,
                        std::sync::atomic::Ordering::SeqCst,
                    );
                    interrupt::stop_the_others();
                }
                results.lock().unwrap().push((i, r));
            });
        }
    });
    let seconds = start.elapsed().as_secs_f64();
    let trained = in_models_order(a, results.into_inner().unwrap(), first_failure.into_inner())?;
    Ok((trained, seconds))
}

/// The trained models in the models' order, or the error to show: the failure of the
/// model `first` (usize::MAX: none) that stopped the others, else any other failure, else
/// the interruption.
fn in_models_order(
    a: &Args,
    mut results: Vec<(usize, Result<cvae::train::Trained, TrainError>)>,
    first: usize,
) -> Result<Vec<cvae::train::Trained>> {
    // In the models' order, not the order they finished in: the summary, the warnings and
    // the model file's notes came out in a different order from run to run. A failure that
    // stopped the others goes first, so that it is the error shown.
    results.sort_by_key(|&(i, _)| (i != first, i));
    let results = results.into_iter().map(|(_, r)| r).collect::<Vec<_>>();
    // A model's own failure is the error to show; the others stopped because of it.
    let stopped = results
        .iter()
        .any(|r| matches!(r, Err(TrainError::Interrupted(_))));
    let mut trained = Vec::new();
    let mut interrupted = None;
    for r in results {
        match r {
            Ok(t) => trained.push(t),
            Err(TrainError::Interrupted(d)) => interrupted = Some(TrainError::Interrupted(d)),
            Err(e) if stopped && !interrupt::requested() => {
                return Err(anyhow::anyhow!(
                    "{e} (the other models stopped at their next step with a checkpoint; \
                     --resume continues them)"
                ));
            }
            Err(e) => return Err(e.into()),
        }
    }
    if let Some(TrainError::Interrupted(d)) = interrupted {
        bail!(
            "interrupted: checkpoints saved in {}; go on with: {}",
            d.display(),
            resume_command(a)
        );
    }
    Ok(trained)
}

/// The model file's set: the decoders trained now, the others from `--base` or from their
/// checkpoints (read before the training), with the notes that say where each came from.
/// Warns where a trained model's losses show it learned the dataset's walks (one whose
/// loss rose is refused by [`refuse_diverged`]).
fn model_set(
    a: &Args,
    cfg: &TrainConfig,
    trained: &[cvae::train::Trained],
    resumed: &[ModelKind],
    base: Option<&(String, ModelSet)>,
    mut from_checkpoints: Vec<(ModelKind, CheckpointDecoder)>,
    info: TrainingInfo,
) -> (ModelSet, Vec<String>) {
    let scaled = |k: ModelKind| scaled_model(cfg.model(k), a.steps_scale);
    let mut decoders = std::collections::HashMap::new();
    let mut notes = Vec::new();
    // A file's feature version says how to read its EventGen (versions 2 and 3 differ only
    // there), so it is the version of wherever EventGen comes from.
    let mut event_version = cvae::features::FEATURE_VERSION;
    for t in trained {
        notes.push(trained_note(
            t,
            scaled(t.kind).steps,
            resumed.contains(&t.kind),
        ));
        decoders.insert(t.kind, t.decoder.clone());
    }
    for k in ModelKind::ALL {
        if let std::collections::hash_map::Entry::Vacant(slot) = decoders.entry(k) {
            if let Some((base_name, b)) = base {
                let d = match k {
                    ModelKind::LengthGen => &b.length,
                    ModelKind::PathGen => &b.path,
                    ModelKind::EventGen => {
                        event_version = b.feature_version;
                        &b.event
                    }
                };
                notes.push(format!("{}: from {base_name}", k.name()));
                slot.insert(d.clone());
                continue;
            }
            let at = from_checkpoints
                .iter()
                .position(|(c, _)| *c == k)
                .expect("read before the training: no base, not trained now");
            let (_, (d, version, _, step, _)) = from_checkpoints.swap_remove(at);
            notes.push(format!("{}: from checkpoint at step {step}", k.name()));
            if k == ModelKind::EventGen {
                event_version = version;
            }
            slot.insert(d);
        }
    }
    let set = ModelSet {
        feature_version: event_version,
        single_scattering: cfg.single_scattering,
        training: TrainingInfo {
            notes: format!(
                "stcvae {} train --config {}; dataset {}; {}",
                env!("CARGO_PKG_VERSION"),
                a.config.display(),
                cfg.dataset.display(),
                notes.join("; ")
            ),
            ..info
        },
        length: decoders.remove(&ModelKind::LengthGen).unwrap(),
        path: decoders.remove(&ModelKind::PathGen).unwrap(),
        event: decoders.remove(&ModelKind::EventGen).unwrap(),
    };
    (set, notes)
}

/// The warnings a trained model calls for (a step count past the one asked, a model that
/// learned its walks rather than their distribution), printed, and the model file's note
/// on it (`resumed`: its seconds span several runs).
fn trained_note(t: &cvae::train::Trained, steps: u64, resumed: bool) -> String {
    if t.info.step > steps {
        eprintln!(
            "note: {}'s checkpoint was already at step {}, past the {steps} steps asked: \
             exported as it was (no step undone)",
            t.kind.name(),
            t.info.step
        );
    }
    let last = t.info.history.last().map_or(f32::NAN, |h| h.1);
    let held = t.info.validation.last();
    if let Some(v) = held
        && v.gap_z > GAP_WARNING_Z
    {
        eprintln!(
            "warning: {}'s losses on held-out walks (mean {:.4}) lie above those on its \
             training walks (mean {:.4}) by z = {:.0}: it is learning the dataset's walks \
             rather than their distribution; train on more walks (a larger `walks` in the \
             dataset config) or for fewer steps",
            t.kind.name(),
            v.held_out.0,
            v.train.0,
            v.gap_z
        );
    }
    // A resumed model's seconds include the runs before this one (one that --resume
    // found no checkpoint of started this run).
    format!(
        "{}: {}, final loss {last:.4}{}, {:.0} s{}",
        t.kind.name(),
        crate::progress::count(t.info.step, "step"),
        held.map_or(String::new(), |v| format!(
            " (held-out {:.4})",
            v.held_out.0
        )),
        t.info.seconds,
        if resumed { " over all its runs" } else { "" }
    )
}

/// What the model file records of its training: the dataset's condition ranges, narrowed
/// to those of the decoders taken from `--base` or from checkpoints, and checked as every
/// reader of the file will check them (here, not after hours of training). Warns where the
/// dataset holds one value of a condition.
fn training_info(
    cfg: &TrainConfig,
    rows: &[scatter_sim::dataset::Row],
    base: Option<&(String, ModelSet)>,
    from_checkpoints: &[(ModelKind, CheckpointDecoder)],
) -> Result<TrainingInfo> {
    let ranges = ConditionRanges::of(rows);
    let mut info = TrainingInfo {
        tau_range: ranges.tau,
        g_range: ranges.g,
        albedo_range: ranges.albedo,
        notes: String::new(),
    };
    // A condition the dataset never varies (a `generate --tau/--g/--albedo` dataset) gives
    // decoders that know one value of it: anywhere else they extrapolate blindly.
    let fixed: Vec<String> = [
        ("tau", info.tau_range),
        ("g", info.g_range),
        ("albedo", info.albedo_range),
    ]
    .iter()
    .filter(|(_, r)| r[0] == r[1])
    // The ranges are the dataset's f32 columns: 0.4 printed as 0.4000000059604645.
    .map(|(name, r)| format!("{name} = {}", r[0] as f32))
    .collect();
    if !fixed.is_empty() {
        eprintln!(
            "warning: {}: every walk has {}; the model will know only that value, and renders \
             or samples at any other are extrapolation",
            cfg.dataset.display(),
            fixed.join(", ")
        );
    }
    if let Some((base_name, b)) = base {
        let t = &b.training;
        let theirs = ConditionRanges {
            tau: t.tau_range,
            g: t.g_range,
            albedo: t.albedo_range,
        };
        narrow(&mut info, theirs, &format!("--base {base_name}"))?;
    }
    // Checked before the training, as the modes are above.
    for (k, (_, _, ranges, _, _)) in from_checkpoints {
        if let Some(r) = ranges {
            narrow(&mut info, *r, &format!("the {} checkpoint", k.name()))?;
        }
    }
    // The model file's own check, here rather than after the training, which it would
    // otherwise end with "nothing written" (walks all at tau = 0, say).
    cvae::model_file::check_training(&info).map_err(|e| {
        anyhow::anyhow!(
            "{}: its walks cannot make a model file: {e}",
            cfg.dataset.display()
        )
    })?;
    Ok(info)
}

pub fn run(a: Args) -> Result<()> {
    let cfg = load(&a.config)?;
    let device = device(&a.backend)?;
    check_steps_scale(&a, &cfg)?;
    let out = model_out(&a, &cfg)?;
    // A folder already there is held from now on, before its checkpoints are looked at
    // (a second run was told "holds checkpoints", and with --fresh read the whole dataset
    // before being refused); one not there yet is made and held only before the first
    // thing written into it, so a refused run leaves no folder.
    let early_lock = cfg
        .checkpoint_dir
        .is_dir()
        .then(|| lock_checkpoint_dir(&cfg.checkpoint_dir, &a.config))
        .transpose()?;
    // A checkpoint save killed between its renames is put back before any checkpoint is
    // read (a model not trained now is read from its checkpoint, and the mixed set's
    // checksums refused it).
    if early_lock.is_some() {
        scatter_sim::output::restore_killed_sets(&cfg.checkpoint_dir);
    }
    check_dataset_source(&a, &cfg)?;
    let base = load_base(&a, &cfg, &out)?;
    let kinds = trained_kinds(a.model);
    warn_cpu_only_models(&a, &cfg, &kinds);
    let resumed = checkpoints_to_resume(&a, &cfg, &kinds)?;
    // Without a base, the decoders not trained now come from the checkpoints: read (and
    // checked) once, before the training rather than after it.
    let mut from_checkpoints = Vec::new();
    if base.is_none() {
        for k in ModelKind::ALL.into_iter().filter(|k| !kinds.contains(k)) {
            from_checkpoints.push((k, checkpoint_decoder(&cfg, k, a.steps_scale)?));
        }
    }
    refuse_diverged_checkpoints(&a, &cfg, &from_checkpoints)?;
    let (header, rows, tables) = read_tables(&cfg, &kinds)?;
    let info = training_info(&cfg, &rows, base.as_ref(), &from_checkpoints)?;
    drop(rows);
    let validations = validations(&cfg, &kinds, &tables, &header.pieces);

    // The handler, installed now, before the checkpoints are touched.
    interrupt::flag();
    // A Ctrl-C after a dataset was generated here (whose handler then caught it) while the
    // rows were read: --fresh removed the checkpoints and each model saved a step-1 set.
    if interrupt::requested() {
        bail!("interrupted before training: no checkpoint removed or written");
    }
    // Held until the model is written; taken before this run removes or writes anything.
    let _lock = match early_lock {
        Some(l) => l,
        None => lock_checkpoint_dir(&cfg.checkpoint_dir, &a.config)?,
    };
    for &k in &kinds {
        cvae::train::trainer::remove_stale_temporaries(&cfg.checkpoint_dir, k);
        if a.fresh {
            cvae::train::trainer::remove_checkpoint(&cfg.checkpoint_dir, k)?;
        }
    }
    let (trained, seconds) =
        train_models(&a, &cfg, &device, &kinds, &tables, &validations, &resumed)?;
    let (set, notes) = model_set(
        &a,
        &cfg,
        &trained,
        &resumed,
        base.as_ref(),
        from_checkpoints,
        info,
    );
    refuse_diverged(&a, &trained)?;
    write_model(&a, &cfg, &out, &set, &trained, seconds, &notes)
}

/// A decoder whose checkpoint records a loss that rose ([`refuse_diverged`]) would go into
/// the file as it is: refused before any training (a diverged run refused, then
/// `--model lengthgen`, wrote the diverged PathGen with exit status 0), unless
/// `--keep-diverged` asks.
fn refuse_diverged_checkpoints(
    a: &Args,
    cfg: &TrainConfig,
    from_checkpoints: &[(ModelKind, CheckpointDecoder)],
) -> Result<()> {
    let rose: Vec<(ModelKind, &str)> = from_checkpoints
        .iter()
        .filter_map(|(k, (.., rise))| Some((*k, rise.as_deref()?)))
        .collect();
    let Some((k, _)) = rose.first() else {
        return Ok(());
    };
    let losses = rose.iter().map(|r| r.1).collect::<Vec<_>>().join(", ");
    let what = format!(
        "checkpoints in {} record a loss that rose ({losses})",
        cfg.checkpoint_dir.display()
    );
    if !a.keep_diverged {
        bail!(
            "{what}: diverged or learned nothing, and the model file would hold them; \
             retrain them (e.g. train --model {} --fresh, with a lower lr or lr_final), take \
             them from a model file with --base, or write them as they are with \
             --keep-diverged",
            k.name()
        );
    }
    eprintln!("warning: {what}; written as --keep-diverged asks");
    Ok(())
}

/// A learning rate too high can leave a finite but useless model, its loss above the
/// untrained network's (one run's EventGen went from 6.07 to 21,916). Written with a
/// warning and exit status 0, such a file went on into `train && render` scripts; it is
/// now written only when `--keep-diverged` asks. The checkpoints are kept either way, so
/// the file can still be had without training again.
fn refuse_diverged(a: &Args, trained: &[cvae::train::Trained]) -> Result<()> {
    let rose: Vec<String> = trained
        .iter()
        .filter_map(|t| loss_rise(t.kind, &t.info.history))
        .collect();
    if rose.is_empty() {
        return Ok(());
    }
    if a.keep_diverged {
        eprintln!(
            "warning: the loss rose ({}): the model diverged or learned nothing; written \
             as --keep-diverged asks",
            rose.join(", ")
        );
        return Ok(());
    }
    bail!(
        "the loss rose ({}): training diverged or learned nothing, so no model was written; \
         lower lr or lr_final in {} (or check the dataset) and train again with --fresh, or \
         write this one as it is with `{} --keep-diverged`",
        rose.join(", "),
        a.config.display(),
        resume_command(a)
    )
}

/// Refuses a --steps-scale out of range, or one that takes a model past the steps a config
/// may ask for (a checkpoint past them would be refused as damaged on --resume).
fn check_steps_scale(a: &Args, cfg: &TrainConfig) -> Result<()> {
    if !(a.steps_scale > 0.0 && a.steps_scale <= 1e3) {
        bail!(
            "--steps-scale = {} is out of range: allowed (0, 1000]",
            scatter_sim::ranges::num(a.steps_scale)
        );
    }
    for k in trained_kinds(a.model) {
        let steps = scaled_steps(cfg.model(k).steps, a.steps_scale);
        if steps > cvae::train::trainer::MAX_STEPS {
            bail!(
                "--steps-scale {} gives {}.steps = {steps} in {}: allowed at most 2^40",
                scatter_sim::ranges::num(a.steps_scale),
                k.name(),
                a.config.display()
            );
        }
    }
    Ok(())
}

/// Refuses a dataset that is a folder, and, where the dataset is to be generated, a
/// dataset_config that cannot be read or a dataset path that cannot be written, before
/// anything is read or generated.
fn check_dataset_source(a: &Args, cfg: &TrainConfig) -> Result<()> {
    // A folder named as the dataset failed with a bare "Is a directory"; a bad
    // dataset_config only after "generating it from … first".
    if cfg.dataset.is_dir() {
        bail!(
            "{}: dataset = \"{}\" is a directory: name a binary dataset file",
            a.config.display(),
            cfg.dataset.display()
        );
    }
    if !cfg.dataset.exists()
        && let Some(dc) = &cfg.dataset_config
    {
        crate::generate::load_config(dc).with_context(|| {
            format!(
                "{}: dataset_config = \"{}\" (read to generate the missing dataset)",
                a.config.display(),
                dc.display()
            )
        })?;
        // Generated here, the dataset is `generate`'s output: a path it cannot write was
        // blamed on `--out`, a flag the user never gave.
        scatter_sim::output::check_output_path(&cfg.dataset).map_err(|e| {
            anyhow::anyhow!(
                "{}: dataset = \"{}\": {e}",
                a.config.display(),
                cfg.dataset.display()
            )
        })?;
    }
    Ok(())
}

/// Warns of a model too large for the GPU kernels: the CPU renders any model the config
/// allows.
fn warn_cpu_only_models(a: &Args, cfg: &TrainConfig, kinds: &[ModelKind]) {
    for &k in kinds {
        if let Err(e) =
            render_gpu::gpu::decoder_gen::fits_kernels(k.cond(), cfg.model(k).latent, k.out())
        {
            eprintln!(
                "warning: {}: {}.latent = {}: the model {e}; it will render on the CPU only",
                a.config.display(),
                k.name(),
                cfg.model(k).latent
            );
        }
    }
}

/// Checks the trained set as its readers will, then writes it with its loss curves as one
/// set, and says where they went.
fn write_model(
    a: &Args,
    cfg: &TrainConfig,
    out: &Path,
    set: &ModelSet,
    trained: &[cvae::train::Trained],
    seconds: f64,
    notes: &[String],
) -> Result<()> {
    // What every reader will check, checked before writing: a file they would all refuse
    // is not written (a decoder from an old checkpoint is not otherwise validated).
    let bytes = set.to_bytes();
    // The checks' own wording blames a damaged or edited file; one trained here failing
    // them comes from its data or its schedule, which is what to look at.
    ModelSet::from_bytes(&bytes, out).with_context(|| {
        format!(
            "the trained model fails the model file's checks, so nothing was written; a model \
             trained (not edited) fails them when the dataset {} holds walks far from what \
             the simulator draws, or when training diverged (lower lr); a decoder taken from \
             another run's checkpoint or --base file carries its own run's data",
            cfg.dataset.display()
        )
    })?;
    // The model and its loss curves are written as one set: an earlier run's plot never
    // stays beside a new model as if it were its curves. A plot that cannot be drawn is
    // told, not the training's failure, and the earlier plot goes.
    let plot_path = loss_plot_path(out);
    let plot = loss_plot(&plot_path, trained).unwrap_or_else(|e| {
        eprintln!("warning: the loss curves were not plotted: {e:#}");
        None
    });
    let mut files: Vec<(&Path, &[u8])> = vec![(out, &bytes)];
    if let Some(png) = &plot {
        files.push((&plot_path, png));
    }
    // The training is not lost with the files: its last checkpoints hold it, and a
    // resumed run at its plan's end only exports (a full disk here gave no way on).
    scatter_sim::output::write_atomic_set(&files).map_err(|(p, e)| {
        anyhow::anyhow!(
            "cannot write {}: {e}; the training's checkpoints in {} are complete: once \
             the output can be written, `{}` writes it without training again",
            p.display(),
            cfg.checkpoint_dir.display(),
            resume_command(a)
        )
    })?;
    eprintln!(
        "trained in {seconds:.0} s{} ({}); wrote {} ({} bytes)",
        if a.resume { " this run" } else { "" },
        // A note may name the --base file.
        scatter_sim::ranges::printable(&notes.join("; ")),
        crate::paths::shown(out),
        bytes.len()
    );
    match plot {
        Some(_) => eprintln!("loss curves: {}", crate::paths::shown(&plot_path)),
        None if plot_path.is_file() => match std::fs::remove_file(&plot_path) {
            Ok(()) => eprintln!(
                "note: removed {}: an earlier run's loss curves (this run has none to \
                 plot)",
                crate::paths::shown(&plot_path)
            ),
            Err(e) => eprintln!(
                "warning: {} is an earlier run's loss curves and could not be removed: {e}",
                crate::paths::shown(&plot_path)
            ),
        },
        None => {}
    }
    // `render` reads the shipped models/default.stcvae unless told otherwise, and the
    // default training config no longer overwrites it: say how to use what was written.
    eprintln!(
        "render with it: stcvae render --model {}",
        scatter_sim::ranges::printable(&crate::paths::shell_word(out))
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    /// A named pipe where the lock file goes is refused by name (opening it waited for a
    /// reader for ever).
    #[cfg(unix)]
    #[test]
    fn a_named_pipe_as_the_lock_file_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let mkfifo = |p: &std::path::Path| {
            let ok = std::process::Command::new("mkfifo").arg(p).status();
            assert!(ok.is_ok_and(|s| s.success()), "mkfifo {}", p.display());
        };
        mkfifo(&d.path().join(super::CHECKPOINT_LOCK));
        let e = super::lock_checkpoint_dir(d.path(), std::path::Path::new("t.toml")).unwrap_err();
        let e = format!("{e:#}");
        assert!(e.contains(".train.lock") && e.contains("named pipe"), "{e}");
    }

    use super::{loss_plot_path, loss_rose, scaled_model};

    /// A model file's ranges bound every decoder in it, so decoders taken from elsewhere
    /// narrow them to what both trainings saw: each condition's range to its intersection
    /// with the same condition's, at both ends (here each end comes from one side or the
    /// other). Ranges that do not meet are refused, naming the source and the condition.
    /// g narrowed by the other side's φ range passed the CLI tests: their datasets' g
    /// spans [-0.999, 0.999], where they do not check the file's g range, or is fixed at
    /// 0.25, inside the shipped model's φ range of about [0, 1].
    #[test]
    fn ranges_narrow_to_what_both_trainings_saw() {
        use cvae::model_file::TrainingInfo;
        use cvae::train::data::ConditionRanges;
        let mut info = TrainingInfo {
            tau_range: [0.0, 30.0],
            g_range: [-0.9, 0.9],
            albedo_range: [0.1, 1.0],
            notes: String::new(),
        };
        let other = ConditionRanges {
            tau: [0.5, 300.0],
            g: [-0.5, 0.95],
            albedo: [0.0, 0.8],
        };
        super::narrow(&mut info, other, "--base b.stcvae").unwrap();
        assert_eq!(
            (info.tau_range, info.g_range, info.albedo_range),
            ([0.5, 30.0], [-0.5, 0.9], [0.1, 0.8])
        );
        let apart = ConditionRanges {
            tau: [0.5, 30.0],
            g: [-0.5, 0.9],
            albedo: [0.9, 1.0],
        };
        let e = super::narrow(&mut info, apart, "x")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("x: its albedo range and the dataset's do not overlap"),
            "{e}"
        );
    }

    /// A dataset that holds part of its dataset_config's run (the first half of it, a
    /// shard) is not that run, and `train` says so: pieces of the run are the whole run only
    /// when their rows add up to its size. The whole run, in one piece or two, is not warned
    /// about. (The CLI test changes the config's seed, which no piece then shares.)
    #[test]
    fn part_of_the_configs_run_is_not_the_run() {
        use scatter_sim::dataset::{Header, Piece};
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("data.toml");
        std::fs::write(&config, "walks = 100\nseed = 5\n").unwrap();
        let sampler = crate::generate::load_config(&config).unwrap().conditions;
        let piece = |first: u64, count: u64| Piece {
            seed: 5,
            sampler: sampler.clone(),
            total_walks: 100,
            first_walk: first,
            count,
            simulator: None,
        };
        let check = |pieces: Vec<Piece>| {
            super::not_the_configs_run(std::path::Path::new("d.bin"), &config, &Header::new(pieces))
        };
        assert_eq!(check(vec![piece(0, 100)]), None);
        assert_eq!(check(vec![piece(0, 50), piece(50, 50)]), None);
        let w = check(vec![piece(0, 50)]).expect("half of the run taken for the run");
        assert!(
            w.contains(
                "it holds 50 walks of a run with seed 5, 100 walks, the config's conditions"
            ),
            "{w}"
        );
    }

    /// NAME.stcvae plots to NAME.loss.png; any other name keeps its whole self, so models
    /// m.v1 and m.v2 get plots of their own.
    #[test]
    fn each_model_file_has_its_own_loss_plot() {
        use std::path::Path;
        for (model, plot) in [
            ("models/trained.stcvae", "models/trained.loss.png"),
            ("m.v1", "m.v1.loss.png"),
            ("m.v2", "m.v2.loss.png"),
            ("m", "m.loss.png"),
        ] {
            assert_eq!(loss_plot_path(Path::new(model)), Path::new(plot));
        }
    }

    /// A written warm-up stands at scale 1, however long; scaled runs cap it at a quarter
    /// of their steps; an unwritten one follows the steps (`ModelConfig::warmup`).
    #[test]
    fn a_written_warmup_is_kept_unless_scaled() {
        let text = "lengthgen = { latent = 2, hidden = [8], steps = 200, lr = 1e-3, \
                    lr_final = 1e-4, warmup = 150 }";
        #[derive(serde::Deserialize)]
        struct One {
            lengthgen: cvae::train::ModelConfig,
        }
        let m = toml::from_str::<One>(text).unwrap().lengthgen;
        let kept = scaled_model(&m, 1.0);
        assert_eq!((kept.steps, kept.warmup()), (200, 150));
        let half = scaled_model(&m, 0.5);
        assert_eq!((half.steps, half.warmup()), (100, 25));
        let unwritten = cvae::train::ModelConfig { warmup: None, ..m };
        assert_eq!(scaled_model(&unwritten, 1.0).warmup(), 50);
    }

    /// A loss that ends above its start by more than the margin is reported with its
    /// start; one that fell, or rose within the first batch's noise, is not.
    #[test]
    fn a_rising_loss_is_told_from_noise() {
        assert_eq!(
            loss_rose(&[(1, 6.07), (500, 2.1), (3000, 21916.0)]),
            Some(6.07)
        );
        assert_eq!(loss_rose(&[(1, 6.07), (3000, 2.98)]), None);
        assert_eq!(loss_rose(&[(1, 6.0), (3000, 6.5)]), None);
        assert_eq!(loss_rose(&[(1, -3.0), (3000, -1.0)]), Some(-3.0));
        assert_eq!(loss_rose(&[(1, 0.05), (30, 0.12)]), None);
        assert_eq!(loss_rose(&[]), None);
    }

    /// The loss plot's dashed curve is the held-out walks' loss. Two histories alike but
    /// for their held-out losses give two plots, and one history one plot. The held-out
    /// values stay within the training losses' 2 to 5, so the axes are the same and only
    /// the dashed curve can tell the plots apart.
    #[test]
    fn the_loss_plots_dashed_curve_is_the_held_out_loss() {
        use cvae::train::validation::ValidationPoint;
        let plot = |held_out: [f32; 3]| {
            let validation = [1u64, 100, 1000]
                .into_iter()
                .zip([5.0f32, 3.0, 2.0])
                .zip(held_out)
                .map(|((step, train), h)| ValidationPoint {
                    step,
                    train: (train, 0.01),
                    held_out: (h, 0.01),
                    gap_z: 0.0,
                })
                .collect();
            let info = cvae::train::trainer::CheckpointInfo {
                feature_version: cvae::features::FEATURE_VERSION,
                step: 1000,
                seconds: 1.0,
                norm: cvae::train::data::Standardisation {
                    cond_shift: Vec::new(),
                    cond_scale: Vec::new(),
                    out_shift: Vec::new(),
                    out_scale: Vec::new(),
                },
                history: vec![(1, 5.0), (1000, 2.0)],
                crc32: None,
                single_scattering: None,
                ranges: None,
                stream: None,
                validation,
                plan: None,
            };
            let decoder = cvae::decoder::Decoder {
                cond: 0,
                latent: 0,
                out: 0,
                layers: Vec::new(),
                cond_shift: Vec::new(),
                cond_scale: Vec::new(),
                out_shift: Vec::new(),
                out_scale: Vec::new(),
            };
            let trained = cvae::train::Trained {
                kind: cvae::train::ModelKind::LengthGen,
                decoder,
                info,
            };
            super::loss_plot(std::path::Path::new("m.loss.png"), &[trained])
                .unwrap()
                .expect("a history with validation losses is plotted")
        };
        let near = plot([5.0, 3.5, 2.5]);
        assert!(near == plot([5.0, 3.5, 2.5]), "one history, two plots");
        assert!(
            near != plot([5.0, 4.5, 3.5]),
            "the held-out losses are not drawn"
        );
    }
}
