//! `stcvae train`: the three CVAEs from a dataset, concurrently, to a model file.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Result, bail};
use burn::prelude::Device;
use cvae::train::validation::{Validation, ValidationPoint};
use cvae::train::{ModelConfig, ModelKind, Table, TrainError, train_model};
use indicatif::{MultiProgress, ProgressBar};

use crate::{interrupt, progress};

mod checkpoints;
mod config;
mod dataset;
mod losses;
mod output;

use checkpoints::{
    checkpoint_decoder, checkpoints_to_resume, lock_checkpoint_dir, refuse_diverged_checkpoints,
};
use config::{DEFAULT_CONFIG, TrainConfig, load};
use dataset::{check_dataset_source, read_tables, validations};
use losses::refuse_diverged;
use output::{load_base, model_out, model_set, training_info, write_model};

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
    trains on) is read beside its loss on as many of its training walks (both with fixed \
    draws), shown on the progress bar, plotted beside the model file (NAME.loss.png), and a \
    held-out loss far above the training walks' is reported as memorising."
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
        cvae::train::checkpoint::remove_stale_temporaries(&cfg.checkpoint_dir, k);
        if a.fresh {
            cvae::train::checkpoint::remove_checkpoint(&cfg.checkpoint_dir, k)?;
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
        if steps > cvae::train::config::MAX_STEPS {
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
        mkfifo(&d.path().join(super::checkpoints::CHECKPOINT_LOCK));
        let e = super::checkpoints::lock_checkpoint_dir(d.path(), std::path::Path::new("t.toml"))
            .unwrap_err();
        let e = format!("{e:#}");
        assert!(e.contains(".train.lock") && e.contains("named pipe"), "{e}");
    }

    use super::losses::{loss_plot_path, loss_rose};
    use super::scaled_model;

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
        super::output::narrow(&mut info, other, "--base b.stcvae").unwrap();
        assert_eq!(
            (info.tau_range, info.g_range, info.albedo_range),
            ([0.5, 30.0], [-0.5, 0.9], [0.1, 0.8])
        );
        let apart = ConditionRanges {
            tau: [0.5, 30.0],
            g: [-0.5, 0.9],
            albedo: [0.9, 1.0],
        };
        let e = super::output::narrow(&mut info, apart, "x")
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
            super::dataset::not_the_configs_run(
                std::path::Path::new("d.bin"),
                &config,
                &Header::new(pieces),
            )
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
            let info = cvae::train::checkpoint::CheckpointInfo {
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
            super::losses::loss_plot(std::path::Path::new("m.loss.png"), &[trained])
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

    /// A model file's feature version says how its EventGen is read (versions 2 and 3
    /// differ there only), so where EventGen comes from a checkpoint the file takes that
    /// checkpoint's version, whatever the other decoders' are. The CLI test checks the
    /// version of an EventGen from `--base` only: written as this build's version, a
    /// version-2 EventGen checkpoint's decoder was read with the new radial map (events in
    /// the wrong places, a wrong render, without a word). The decoders are placeholders
    /// (model_set neither evaluates nor checks them); distinct `cond` tells them apart.
    #[test]
    fn a_model_file_takes_the_feature_version_of_its_eventgen_checkpoint() {
        use cvae::features::{FEATURE_VERSION, OLDEST_FEATURE_VERSION};
        use cvae::train::ModelKind;
        let model = "{ latent = 2, hidden = [4], steps = 10, lr = 1e-3, lr_final = 1e-4 }";
        let cfg: super::config::TrainConfig = toml::from_str(&format!(
            "dataset = \"d.bin\"\nout = \"m.stcvae\"\ncheckpoint_dir = \"ck\"\n\
             lengthgen = {model}\npathgen = {model}\neventgen = {model}\n"
        ))
        .unwrap();
        let a = super::Args {
            config: "train.toml".into(),
            model: None,
            base: None,
            resume: false,
            fresh: false,
            out: None,
            steps_scale: 1.0,
            backend: "flex".into(),
            keep_diverged: false,
        };
        let decoder = |cond: usize| cvae::decoder::Decoder {
            cond,
            latent: 0,
            out: 0,
            layers: Vec::new(),
            cond_shift: Vec::new(),
            cond_scale: Vec::new(),
            out_shift: Vec::new(),
            out_scale: Vec::new(),
        };
        let info = cvae::model_file::TrainingInfo {
            tau_range: [0.0, 30.0],
            g_range: [-0.9, 0.9],
            albedo_range: [0.0, 1.0],
            notes: String::new(),
        };
        let set_of = |length_version: u32, event_version: u32| {
            let from = vec![
                (
                    ModelKind::LengthGen,
                    (decoder(1), length_version, None, 7, None),
                ),
                (
                    ModelKind::PathGen,
                    (decoder(2), FEATURE_VERSION, None, 7, None),
                ),
                (
                    ModelKind::EventGen,
                    (decoder(3), event_version, None, 7, None),
                ),
            ];
            super::output::model_set(&a, &cfg, &[], &[], None, from, info.clone()).0
        };
        let set = set_of(FEATURE_VERSION, OLDEST_FEATURE_VERSION);
        assert_eq!(set.feature_version, OLDEST_FEATURE_VERSION);
        assert_eq!(set.event, decoder(3));
        assert!(
            set.training
                .notes
                .contains("eventgen: from checkpoint at step 7"),
            "{}",
            set.training.notes
        );
        // An old LengthGen beside a new EventGen: the file is of EventGen's version.
        let set = set_of(OLDEST_FEATURE_VERSION, FEATURE_VERSION);
        assert_eq!(set.feature_version, FEATURE_VERSION);
        assert_eq!(set.length, decoder(1));
    }
}
