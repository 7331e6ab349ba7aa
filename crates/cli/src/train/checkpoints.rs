//! The checkpoint folder: its lock, the checkpoints a run resumes or refuses, and the
//! decoders taken from them.

use std::path::Path;

use anyhow::{Context, Result, bail};
use cvae::train::ModelKind;
use cvae::train::data::ConditionRanges;

use super::config::TrainConfig;
use super::losses::loss_rise;
use super::{Args, scaled_steps};

/// A decoder read from its checkpoint: the decoder, its feature version, the condition
/// ranges it was trained on (None for checkpoints that predate recording them), its step,
/// and its loss's rise where it rose ([`loss_rise`]).
pub(super) type CheckpointDecoder = (
    cvae::decoder::Decoder,
    u32,
    Option<ConditionRanges>,
    u64,
    Option<String>,
);

/// The decoder of `k` from the config's checkpoint folder, for a model file whose other
/// decoders are trained now (see [`CheckpointDecoder`]).
pub(super) fn checkpoint_decoder(
    cfg: &TrainConfig,
    k: ModelKind,
    steps_scale: f64,
) -> Result<CheckpointDecoder> {
    let (d, info) =
        cvae::train::checkpoint::load_decoder(&cfg.checkpoint_dir, k, &cfg.model(k).architecture())
            .with_context(|| {
                // A checkpoint that is there but cannot be read is damaged or from another
                // architecture: training it "first" is not the advice then.
                if cvae::train::checkpoint::has_checkpoint(&cfg.checkpoint_dir, k) {
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

/// The lock file a training run holds in its checkpoint_dir.
pub(super) const CHECKPOINT_LOCK: &str = ".train.lock";

/// Holds `dir` for this run (an advisory lock, released when the process ends however it
/// ends). Two runs sharing a checkpoint_dir deleted each other's temporaries when they
/// started and then took turns overwriting the same checkpoints, whose checksums still
/// matched: a later --resume continued whichever saved last. A file system without locks
/// is warned about, not refused.
pub(super) fn lock_checkpoint_dir(dir: &Path, config: &Path) -> Result<std::fs::File> {
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

/// The models of `kinds` this run continues from their checkpoints, after refusing what
/// would lose or misread a checkpoint: a record without its JSON, `--resume` with nothing
/// to continue, or a new run over checkpoints it would replace (neither `--resume` nor
/// `--fresh`).
pub(super) fn checkpoints_to_resume(
    a: &Args,
    cfg: &TrainConfig,
    kinds: &[ModelKind],
) -> Result<Vec<ModelKind>> {
    if !a.fresh
        && let Some(p) = kinds
            .iter()
            .find_map(|&k| cvae::train::checkpoint::orphan_record(&cfg.checkpoint_dir, k))
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
        .filter(|&k| a.resume && cvae::train::checkpoint::has_checkpoint(&cfg.checkpoint_dir, k))
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
            .filter(|&&k| cvae::train::checkpoint::has_checkpoint(&cfg.checkpoint_dir, k))
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

/// A decoder whose checkpoint records a loss that rose
/// ([`refuse_diverged`](super::losses::refuse_diverged)) would go into the file as it is:
/// refused before any training (a diverged run refused, then `--model lengthgen`, wrote
/// the diverged PathGen with exit status 0), unless `--keep-diverged` asks.
pub(super) fn refuse_diverged_checkpoints(
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
