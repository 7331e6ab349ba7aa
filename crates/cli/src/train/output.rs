//! The model file: its path checked before the training, its decoders gathered from
//! this run, `--base` or checkpoints, its recorded ranges, and its writing.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use cvae::model_file::{ModelSet, TrainingInfo};
use cvae::train::ModelKind;
use cvae::train::data::ConditionRanges;

use super::checkpoints::CheckpointDecoder;
use super::config::TrainConfig;
use super::losses::{loss_plot, loss_plot_path, trained_note};
use super::{Args, resume_command, scaled_model};

/// Narrows the file's ranges to what a decoder from elsewhere (`source`) was trained on:
/// the file's ranges bound every decoder in it (the renderer's default max_tau is
/// `tau_range[1]`), so with decoders from two trainings, only what both saw.
pub(super) fn narrow(info: &mut TrainingInfo, other: ConditionRanges, source: &str) -> Result<()> {
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
pub(super) fn model_out(a: &Args, cfg: &TrainConfig) -> Result<PathBuf> {
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
pub(super) fn load_base(
    a: &Args,
    cfg: &TrainConfig,
    out: &Path,
) -> Result<Option<(String, ModelSet)>> {
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

/// The model file's set: the decoders trained now, the others from `--base` or from their
/// checkpoints (read before the training), with the notes that say where each came from.
/// Warns where a trained model's losses show it learned the dataset's walks (one whose
/// loss rose is refused by [`refuse_diverged`](super::losses::refuse_diverged)).
pub(super) fn model_set(
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

/// What the model file records of its training: the dataset's condition ranges, narrowed
/// to those of the decoders taken from `--base` or from checkpoints, and checked as every
/// reader of the file will check them (here, not after hours of training). Warns where the
/// dataset holds one value of a condition.
pub(super) fn training_info(
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
    // Checked before the training, as the modes are (`load_base`, `checkpoint_decoder`).
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

/// Checks the trained set as its readers will, then writes it with its loss curves as one
/// set, and says where they went.
pub(super) fn write_model(
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
