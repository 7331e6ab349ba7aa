//! A model's checkpoints: the weights, the optimiser's state and the record beside them
//! (step, plan, losses, checksums), saved as one set, checked and resumed.

use std::path::{Path, PathBuf};

use burn::optim::ModuleOptimizer;
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use scatter_sim::WalkRng;
use scatter_sim::ranges::num;

use super::config::{MAX_STEPS, ModelConfig};
use super::data::{ConditionRanges, ModelKind, Standardisation, Table};
use super::network::{Architecture, Cvae};
use super::trainer::{LOG_EVERY, REPORT_EVERY, TrainError, exportable, within_bounds};
use super::validation::ValidationPoint;
use crate::decoder::Decoder;

/// Progress of a model, saved beside its weights.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CheckpointInfo {
    /// The feature version of the targets it was trained on. Checkpoints written before
    /// version 3 lack it and read as 2; those of version 1 (before commit fb07877) differ
    /// in their standardisation, which a resume checks.
    #[serde(default = "feature_version_2")]
    pub feature_version: u32,
    pub step: u64,
    pub seconds: f64,
    pub norm: Standardisation,
    /// (step, mean loss over the preceding reporting interval); the first entry (step 1)
    /// is the untrained model's loss.
    pub history: Vec<(u64, f32)>,
    /// CRC-32 of the weights file and of the optimiser state file as saved: burn's
    /// record files carry none, and a damaged one loaded without complaint. Absent in
    /// checkpoints written before it existed (then not checked).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crc32: Option<[u32; 2]>,
    /// How N = 1 was treated in training, and the conditions of the dataset trained on:
    /// a decoder taken from a checkpoint into a model file must have been trained the
    /// way the file says and within its ranges. Absent in checkpoints written before
    /// they existed (then taken on trust).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_scattering: Option<crate::model_file::SingleScattering>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranges: Option<ConditionRanges>,
    /// Where the batch stream stood, and the loss readings taken since the last report:
    /// a resumed run draws the batches the uninterrupted one would have drawn, so the
    /// weights do not depend on when a Ctrl-C came. (The f64 sum survives JSON exactly:
    /// serde_json's float_roundtrip.) Checkpoints written before it existed
    /// resume on a fresh stream.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream: Option<StreamState>,
    /// The validation losses read at each report ([`super::validation`]); empty in
    /// checkpoints written before they were read.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub validation: Vec<ValidationPoint>,
    /// The schedule the run was started with. Absent in checkpoints written before it
    /// existed (then not checked).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plan: Option<Plan>,
}

impl CheckpointInfo {
    /// What a record of `kind` written by a run always satisfies, which its checksums do
    /// not cover (they cover the weight files): an edited step or time (u64::MAX steps,
    /// −1e308 s) went on into the reports and the model file's notes, an emptied history
    /// into a final loss of NaN, and an edited standardisation was reported only when the
    /// model file was written, under the model file's name.
    fn check(&self, kind: ModelKind) -> Result<(), String> {
        if !(self.seconds.is_finite() && self.seconds >= 0.0) {
            return Err(format!(
                "seconds = {} is not a training time (finite, >= 0)",
                scatter_sim::ranges::num(self.seconds)
            ));
        }
        // No run takes more steps than a model may be given (after --steps-scale, which
        // is held to the same limit); the history's steps are the run's own, in order,
        // with finite losses.
        if self.step > MAX_STEPS {
            return Err(format!("step = {} is beyond 2^40", self.step));
        }
        let mut last = 0;
        for &(step, loss) in &self.history {
            if step < last || step > self.step || !loss.is_finite() {
                return Err(format!(
                    "history entry ({step}, {loss}) is not a step up to {} in order with a \
                     finite loss",
                    self.step
                ));
            }
            last = step;
        }
        // Step 1's loss (the untrained model's) is the first entry of every run's history.
        if self.step > 0 && self.history.first().map(|h| h.0) != Some(1) {
            return Err(format!(
                "history does not begin at step 1 although the run is at step {}",
                self.step
            ));
        }
        // A run reports every REPORT_EVERY steps and at its last, and saves after its
        // report, so a record is less than REPORT_EVERY steps past its history's last entry,
        // but for a skipped report: one whose steps since the last read no loss adds no
        // entry, and the gap then reaches up to 2·REPORT_EVERY − 1. Runs since 2026-12-07
        // read the step before a report whose window has none; records saved before may
        // hold such gaps (a finished run resumed with more steps 1 to 9 steps before a
        // report step, or a resume of a record saved before streams were kept). Twice
        // that is refused: an edited step of 999,999,999 on a run stopped at 4,366 was
        // taken for a finished run, and its model written with that step count.
        if let Some(&(last, _)) = self.history.last()
            && self.step - last >= 2 * REPORT_EVERY
        {
            return Err(format!(
                "step = {} is {} or more past the history's last entry (step {last}), where \
                 a run keeps one every {REPORT_EVERY} steps",
                self.step,
                2 * REPORT_EVERY
            ));
        }
        // Xoshiro never leaves the all-zero state (every draw 0): the latent noise's normal
        // sampler looped on it for ever, deaf to Ctrl-C.
        if let Some(s) = &self.stream {
            if s.rng.is_degenerate() {
                return Err("stream.rng is the all-zero state, which no run saves".into());
            }
            // Its mean is the next report's loss, in f32. A reading is taken every
            // LOG_EVERY steps and at a run's last; the readings are summed from the last
            // report, at most REPORT_EVERY steps back.
            let (sum, count) = s.pending_loss;
            let most = REPORT_EVERY / LOG_EVERY + 1;
            let mean = (sum / count.max(1) as f64) as f32;
            if !(sum.is_finite() && mean.is_finite() && count <= most && (count > 0 || sum == 0.0))
            {
                return Err(format!(
                    "stream.pending_loss = ({}, {count}) is not a sum of at most {most} loss \
                     readings with a finite mean (0 for none)",
                    scatter_sim::ranges::num(sum)
                ));
            }
        }
        // The ranges become the model file's, bounding the renderers' τ_max: an edited
        // [5, 1] was reported as not overlapping the dataset's, and [-5, 5] taken.
        if let Some(r) = &self.ranges {
            crate::model_file::check_ranges(
                ["ranges.tau", "ranges.g", "ranges.albedo"],
                [r.tau, r.g, r.albedo],
            )?;
        }
        let n = &self.norm;
        crate::model_file::check_norm(
            [&n.cond_shift, &n.cond_scale, &n.out_shift, &n.out_scale],
            kind.cond(),
            kind.out(),
        )
        .map_err(|e| format!("norm: {e}"))
    }
}

/// What a run's batches and learning rates follow, as run (after `--steps-scale`): an
/// unfinished run resumed under another plan jumped in learning rate mid-decay (a run
/// started with `--steps-scale 0.25` and resumed without it trained 4× as long) and was no
/// longer the run an uninterrupted one would have been; a finished one may go on under a
/// new plan (more steps).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub steps: u64,
    pub warmup: u64,
    pub batch_size: usize,
    pub lr: f64,
    pub lr_final: f64,
    /// The run's seed, which also draws its validation walks.
    pub seed: u64,
}

impl Plan {
    pub fn of(cfg: &ModelConfig, seed: u64) -> Self {
        Self {
            steps: cfg.steps,
            warmup: cfg.warmup(),
            batch_size: cfg.batch_size,
            lr: cfg.lr,
            lr_final: cfg.lr_final,
            seed,
        }
    }

    /// The settings that differ from `other`'s, as `name = value` of this plan.
    fn differences(&self, other: &Plan) -> Vec<String> {
        [
            ("steps", self.steps != other.steps, self.steps.to_string()),
            (
                "warmup",
                self.warmup != other.warmup,
                self.warmup.to_string(),
            ),
            (
                "batch_size",
                self.batch_size != other.batch_size,
                self.batch_size.to_string(),
            ),
            ("lr", self.lr != other.lr, num(self.lr)),
            (
                "lr_final",
                self.lr_final != other.lr_final,
                num(self.lr_final),
            ),
            ("seed", self.seed != other.seed, self.seed.to_string()),
        ]
        .into_iter()
        .filter(|d| d.1)
        .map(|(name, _, v)| format!("{name} = {v}"))
        .collect()
    }
}

/// The part of a run's state that is not in burn's records.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StreamState {
    pub rng: WalkRng,
    /// Sum and count of the loss readings since the last report.
    pub pending_loss: (f64, u64),
}

fn crc_of(path: &Path) -> std::io::Result<u32> {
    Ok(crc32fast::hash(&read_checkpoint_file(path)?))
}

/// A checkpoint file's bytes, refused first if it is a named pipe or device (reading one
/// without a writer blocks for ever; `scatter_sim::output::check_input`).
fn read_checkpoint_file(path: &Path) -> std::io::Result<Vec<u8>> {
    scatter_sim::output::check_input(path)?;
    std::fs::read(path)
}

/// Compares the weights (and, when given, the optimiser state) with the CRC-32s saved in
/// `info` (not checked for checkpoints saved without them).
/// One model's damaged checkpoint is that model's to redo: `--fresh` alone restarts all
/// three (the damaged record's message already named the model).
fn check_crcs(info: &CheckpointInfo, files: &[&Path], kind: ModelKind) -> Result<(), TrainError> {
    let Some(crcs) = info.crc32 else {
        return Ok(());
    };
    for (&path, want) in files.iter().zip(crcs) {
        let got = crc_of(path).map_err(|e| TrainError::Checkpoint {
            path: path.into(),
            msg: if e.kind() == std::io::ErrorKind::NotFound {
                format!(
                    "missing beside its checkpoint record: the checkpoint is incomplete; start \
                     over with --fresh --model {}",
                    kind.name()
                )
            } else {
                e.to_string()
            },
        })?;
        if got != want {
            return Err(TrainError::Checkpoint {
                path: path.into(),
                msg: format!(
                    "checksum {got:08x} differs from the {want:08x} saved with the checkpoint: \
                     the file is damaged or was replaced, or its save was cut short; start \
                     over with --fresh --model {}",
                    kind.name()
                ),
            });
        }
    }
    Ok(())
}

fn feature_version_2() -> u32 {
    2
}

/// Removes what an aborted save of `kind`'s checkpoint can leave in `dir`: the hidden
/// temporaries of its three files ([`scatter_sim::output::remove_stale_temporaries_of`]),
/// and an earlier version's staging folder (`.NAME-saving…`); a save killed between its
/// renames is put back first ([`scatter_sim::output::restore_killed_sets`]).
pub fn remove_stale_temporaries(dir: &Path, kind: ModelKind) {
    scatter_sim::output::restore_killed_sets(dir);
    let (m, o, j) = paths(dir, kind);
    for p in [&m, &o, &j] {
        scatter_sim::output::remove_stale_temporaries_of(p);
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let staging = format!(".{}-saving", kind.name());
    for e in entries.flatten() {
        if e.file_name().to_string_lossy().starts_with(&staging) && e.path().is_dir() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Removes `kind`'s checkpoint from `dir` (a `--fresh` run replaces it from the start: a
/// run that diverged before its first save left the earlier run's checkpoint, which
/// `--resume` then continued as if it were this run's).
pub fn remove_checkpoint(dir: &Path, kind: ModelKind) -> Result<(), TrainError> {
    let (m, o, j) = paths(dir, kind);
    // The JSON first: without it no resume reads the other two.
    for p in [&j, &m, &o] {
        match std::fs::remove_file(p) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(TrainError::Checkpoint {
                    path: p.clone(),
                    msg: format!("cannot remove it for --fresh: {e}"),
                });
            }
            _ => {}
        }
    }
    Ok(())
}

/// Whether `dir` holds a checkpoint of `kind` that `resume` would continue from.
pub fn has_checkpoint(dir: &Path, kind: ModelKind) -> bool {
    paths(dir, kind).2.exists()
}

/// A model or optimiser record of `kind` in `dir` without the JSON that makes it a
/// checkpoint (the JSON removed by hand, or a kill between a first save's renames): no
/// resume can read it, and a new run would write over it without a word.
pub fn orphan_record(dir: &Path, kind: ModelKind) -> Option<PathBuf> {
    let (m, o, j) = paths(dir, kind);
    if j.exists() {
        return None;
    }
    [m, o].into_iter().find(|p| p.exists())
}

pub(super) fn paths(dir: &Path, kind: ModelKind) -> (PathBuf, PathBuf, PathBuf) {
    let n = kind.name();
    (
        dir.join(format!("{n}.bpk")),
        dir.join(format!("{n}-optim.bpk")),
        dir.join(format!("{n}.json")),
    )
}

/// Writes the model, the optimiser state and the JSON that holds their checksums as one
/// set: the two records are made in memory and the three files renamed into place only
/// once all are written, a failed rename putting back the ones before it. Saved one by
/// one, a failure while writing (a full disk, a folder in the way) left a new model beside
/// the old JSON, whose checksum then refused the resume, and the run was lost. (burn wrote
/// the records into a staging folder first: a full disk's error then named its hidden
/// temporary, behind two prefixes of burn's.) A kill between the three renames (a window
/// of microseconds) mixes the sets until the next run puts the earlier one back
/// ([`remove_stale_temporaries`]; on a local file system, whose locks tell a killed run's
/// save from a live one).
pub(super) fn save_checkpoint(
    dir: &Path,
    kind: ModelKind,
    model: &Cvae,
    optim: &ModuleOptimizer,
    info: &CheckpointInfo,
) -> Result<(), TrainError> {
    let (m, o, j) = paths(dir, kind);
    let err = |p: &Path, e: String| TrainError::Checkpoint {
        path: p.into(),
        msg: e,
    };
    let mbytes = model
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| err(&m, e.to_string()))?;
    let obytes = optim.into_bytes().map_err(|e| err(&o, e.to_string()))?;
    let mut info = info.clone();
    info.crc32 = Some([crc32fast::hash(&mbytes), crc32fast::hash(&obytes)]);
    let json = serde_json::to_vec_pretty(&info).expect("serialisable");
    scatter_sim::output::write_atomic_set(&[
        (m.as_path(), &mbytes[..]),
        (o.as_path(), &obytes[..]),
        (j.as_path(), json.as_slice()),
    ])
    .map_err(|(p, e)| err(&p, e.to_string()))
}

/// The decoder of a model's last checkpoint (for exporting a set in which only some
/// models were retrained), and the checkpoint's record (feature version, mode, ranges).
pub fn load_decoder(
    dir: &Path,
    kind: ModelKind,
    arch: &Architecture,
) -> Result<(Decoder, CheckpointInfo), TrainError> {
    let (m, _, j) = paths(dir, kind);
    let err = |p: &Path, e: String| TrainError::Checkpoint {
        path: p.into(),
        msg: e,
    };
    let text = read_checkpoint_file(&j).map_err(|e| err(&j, e.to_string()))?;
    let info: CheckpointInfo = serde_json::from_slice(&text).map_err(|e| err(&j, e.to_string()))?;
    info.check(kind)
        .map_err(|e| err(&j, format!("{e}: the file was edited or damaged")))?;
    check_crcs(&info, &[&m], kind)?;
    scatter_sim::output::check_input(&m).map_err(|e| err(&m, e.to_string()))?;
    let device = Device::flex();
    let mut rng = WalkRng::from_seed(0);
    let fresh = Cvae::new(kind.cond(), kind.out(), arch, &mut rng, &device);
    let model = loaded(kind, &m, || fresh.try_load_file(&m))?;
    // A record never resumed since the scale of a column without spread became 1.
    let decoder = model.export(&info.norm.clone().without_old_floor());
    if !within_bounds(&decoder) {
        return Err(err(&m, damaged_weights(kind)));
    }
    Ok((decoder, info))
}

/// Weights a run would not have saved, in a file whose checksum matches its record.
fn damaged_weights(kind: ModelKind) -> String {
    format!(
        "holds weights that are not finite or beyond ±{:e}, which no run saves: the \
         checkpoint was edited or damaged; start over with --fresh --model {}",
        crate::model_file::MAX_WEIGHT,
        kind.name()
    )
}

/// The run's state at its last checkpoint in `checkpoint_dir`: the record, the weights, the
/// optimiser and a stream, each checked against the run it is to go on with (the same
/// model, feature version, single-scattering mode, data and plan).
pub(super) fn resume_from(
    kind: ModelKind,
    table: &Table,
    cfg: &ModelConfig,
    seed: u64,
    checkpoint_dir: &Path,
    model: Cvae,
    optim: ModuleOptimizer,
) -> Result<(CheckpointInfo, Cvae, ModuleOptimizer, WalkRng), TrainError> {
    let (mpath, opath, jpath) = paths(checkpoint_dir, kind);
    let err = |p: &Path, e: String| TrainError::Checkpoint {
        path: p.into(),
        msg: e,
    };
    let text = read_checkpoint_file(&jpath).map_err(|e| err(&jpath, e.to_string()))?;
    let mut info: CheckpointInfo = serde_json::from_slice(&text).map_err(|e| {
        err(
            &jpath,
            format!(
                "not a readable checkpoint record ({e}): the save was cut short or the file \
                 edited; start over with --fresh --model {}",
                kind.name()
            ),
        )
    })?;
    info.check(kind).map_err(|e| {
        err(
            &jpath,
            format!(
                "{e}: the file was edited or damaged; start over with --fresh --model {}",
                kind.name()
            ),
        )
    })?;
    // Versions 2 and 3 differ only in EventGen's targets (whose standardisation would
    // differ too); LengthGen and PathGen go on as they were.
    if kind != ModelKind::EventGen
        && info.feature_version == crate::features::OLDEST_FEATURE_VERSION
    {
        info.feature_version = crate::features::FEATURE_VERSION;
    }
    if info.feature_version != crate::features::FEATURE_VERSION {
        return Err(err(
            &jpath,
            format!(
                "checkpoint has feature version {} (this build trains {}): start over \
                 with --fresh",
                info.feature_version,
                crate::features::FEATURE_VERSION
            ),
        ));
    }
    if let Some(m) = info.single_scattering
        && m != table.mode
    {
        return Err(err(
            &jpath,
            format!(
                "checkpoint was trained with single_scattering = {} and the config says {}: \
                 start over with --fresh, or restore the config",
                m.name(),
                table.mode.name()
            ),
        ));
    }
    if !info.norm.same_data(&table.norm) {
        return Err(err(
            &jpath,
            "checkpoint was trained on other data (standardisation differs): start over \
             with --fresh, or train on its dataset"
                .into(),
        ));
    }
    // The same data, but a column without spread may carry the old scale of 10⁻⁶, which
    // the run's saves would keep and `load_decoder` export (`column_stats`: a render 26 %
    // too bright at another g); the table's is the one the run trains with.
    info.norm = table.norm.clone();
    let plan = Plan::of(cfg, seed);
    if let Some(was) = &info.plan
        && info.step < was.steps
        && *was != plan
    {
        return Err(err(
            &jpath,
            format!(
                "the checkpoint's run stopped at step {} of {} and was started with {}; \
                 this run has {}: resume with the settings it was started with (the same \
                 config and --steps-scale), or start over with --fresh",
                info.step,
                was.steps,
                was.differences(&plan).join(", "),
                plan.differences(was).join(", ")
            ),
        ));
    }
    info.plan = Some(plan);
    check_crcs(&info, &[&mpath, &opath], kind)?;
    for p in [&mpath, &opath] {
        scatter_sim::output::check_input(p).map_err(|e| err(p, e.to_string()))?;
    }
    let model = loaded(kind, &mpath, || model.try_load_file(&mpath))?;
    // A run never saves such weights ([`exportable`]): resumed, they read as a
    // divergence at the first loss, blamed on the learning rate.
    if !exportable(&model, &info.norm) {
        return Err(err(&mpath, damaged_weights(kind)));
    }
    let optim = loaded(kind, &opath, || optim.load(&opath))?;
    // Same mode (checked above) and same data (the standardisation matched).
    info.single_scattering = Some(table.mode);
    info.ranges = Some(table.ranges);
    let rng = WalkRng::for_walk(seed ^ info.step.rotate_left(32), kind as u64);
    Ok((info, model, optim, rng))
}

/// What burn's loader makes of the record file `path`, its error or its panic (a tensor
/// of another type or rank, a damaged parameter id) as a checkpoint error naming the file.
fn loaded<T, E: std::fmt::Display>(
    kind: ModelKind,
    path: &Path,
    load: impl FnOnce() -> Result<T, E>,
) -> Result<T, TrainError> {
    let msg = match scatter_sim::quiet::quietly(load) {
        Ok(Ok(v)) => return Ok(v),
        Ok(Err(e)) => record_error(kind, e.to_string()),
        Err(panic) => format!(
            "cannot be read ({}): the checkpoint was edited or damaged; start over with \
             --fresh --model {}",
            scatter_sim::quiet::panic_text(&*panic),
            kind.name()
        ),
    };
    Err(TrainError::Checkpoint {
        path: path.into(),
        msg,
    })
}

/// burn's error for a checkpoint whose tensors do not fit the network lists every
/// mismatched shape (a thousand characters and more); a changed architecture is the usual
/// cause, so say that in one line.
fn record_error(kind: ModelKind, msg: String) -> String {
    if msg.contains("shape mismatch") {
        format!(
            "its layer shapes differ from the config's [{}] (latent, hidden, encoder_hidden \
             changed since it was written?): start over with --fresh, or restore the config",
            kind.name()
        )
    } else {
        msg
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::adamax::Adamax;
    use crate::train::config::config;

    /// A checkpoint's three files are replaced as a set: when one cannot be written (here
    /// the optimiser's path became a folder) the model and the JSON keep their earlier
    /// bytes, so the model still matches the checksum its JSON holds; saved one by one, the
    /// new model sat beside the old JSON and the resume was refused. Nothing else is left
    /// behind either way.
    #[test]
    fn a_failed_checkpoint_save_keeps_the_previous_set() {
        let d = tempfile::tempdir().unwrap();
        let kind = ModelKind::LengthGen;
        let device = Device::flex();
        let arch = config(10, None).architecture();
        let mut rng = WalkRng::from_seed(5);
        let first = Cvae::new(kind.cond(), kind.out(), &arch, &mut rng, &device);
        let second = Cvae::new(kind.cond(), kind.out(), &arch, &mut rng, &device);
        let optim = Adamax::default().init();
        let info = |step| CheckpointInfo {
            feature_version: crate::features::FEATURE_VERSION,
            step,
            seconds: 0.0,
            norm: Standardisation::identity(kind),
            history: Vec::new(),
            crc32: None,
            single_scattering: None,
            ranges: None,
            stream: None,
            validation: Vec::new(),
            plan: None,
        };
        save_checkpoint(d.path(), kind, &first, &optim, &info(1)).unwrap();
        let (m, o, j) = paths(d.path(), kind);
        let saved: CheckpointInfo = serde_json::from_slice(&std::fs::read(&j).unwrap()).unwrap();
        check_crcs(&saved, &[&m, &o], kind).unwrap();
        let (model_before, json_before) = (std::fs::read(&m).unwrap(), std::fs::read(&j).unwrap());
        std::fs::remove_file(&o).unwrap();
        std::fs::create_dir(&o).unwrap();
        // The error names the checkpoint's own file, not a temporary of the save.
        let e = save_checkpoint(d.path(), kind, &second, &optim, &info(2)).unwrap_err();
        assert!(
            e.to_string().starts_with(&format!("{}: ", o.display())),
            "{e}"
        );
        assert_eq!(std::fs::read(&m).unwrap(), model_before);
        assert_eq!(std::fs::read(&j).unwrap(), json_before);
        std::fs::remove_dir(&o).unwrap();
        save_checkpoint(d.path(), kind, &second, &optim, &info(2)).unwrap();
        assert_ne!(
            std::fs::read(&m).unwrap(),
            model_before,
            "a new model differs"
        );
        let saved: CheckpointInfo = serde_json::from_slice(&std::fs::read(&j).unwrap()).unwrap();
        assert_eq!(saved.step, 2);
        check_crcs(&saved, &[&m, &o], kind).unwrap();
        let mut left: Vec<String> = std::fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(
            left,
            ["lengthgen-optim.bpk", "lengthgen.bpk", "lengthgen.json"]
        );
        // A save killed between its renames: its mark left (noting the model it placed),
        // the model replaced (here by the step-1 one), the JSON not, and the replaced model
        // kept as a link. The next run's sweep puts it back, and the checkpoint reads whole
        // again (before, the sweep removed the link and the resume was refused for a
        // checksum).
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let step_2 = std::fs::read(&m).unwrap();
            let link = d.path().join(".lengthgen.bpk.Kil123.stcvae-previous");
            std::fs::hard_link(&m, link).unwrap();
            std::fs::write(d.path().join("new"), &model_before).unwrap();
            std::fs::rename(d.path().join("new"), &m).unwrap();
            let placed = std::fs::metadata(&m).unwrap().ino();
            std::fs::write(
                d.path().join(".stcvae-set.Kil123.renaming"),
                format!("{placed} lengthgen.bpk\n"),
            )
            .unwrap();
            assert!(check_crcs(&saved, &[&m, &o], kind).is_err());
            remove_stale_temporaries(d.path(), kind);
            assert_eq!(std::fs::read(&m).unwrap(), step_2);
            check_crcs(&saved, &[&m, &o], kind).unwrap();
        }
    }

    /// A record's history is its run's reports in order: one edited out of order (here
    /// step 300 after step 500) is refused by name, as the CLI test refuses an emptied one.
    /// A record whose history is in order, (1, 500, 600), passes, and the out-of-order
    /// entry is within every other bound (at most the record's step, a finite loss, 300
    /// steps before the record's step where 1,000 is refused), so only the order check can
    /// refuse it.
    #[test]
    fn a_history_out_of_order_is_refused() {
        let kind = ModelKind::LengthGen;
        let info = |history: Vec<(u64, f32)>| CheckpointInfo {
            feature_version: crate::features::FEATURE_VERSION,
            step: 600,
            seconds: 1.0,
            norm: Standardisation::identity(kind),
            history,
            crc32: None,
            single_scattering: None,
            ranges: None,
            stream: None,
            validation: Vec::new(),
            plan: None,
        };
        assert_eq!(
            info(vec![(1, 3.0), (500, 2.0), (600, 1.5)]).check(kind),
            Ok(())
        );
        let e = info(vec![(1, 3.0), (500, 2.0), (300, 1.5)])
            .check(kind)
            .unwrap_err();
        assert!(e.contains("history entry (300, 1.5)"), "{e}");
    }

    /// A decoder taken from a checkpoint into a model file (`train --model X` exports the
    /// other models with `load_decoder`) is checked against its record's checksum, as a
    /// resume is: a weights file replaced by another run's (valid, finite, of the same
    /// shapes) was exported into the model file under the record's step, mode and ranges.
    /// Two 20-step LengthGen runs (seeds 1 and 2); the first's decoder loads, and with the
    /// second's weights file in its place it is refused naming that file.
    #[test]
    fn a_replaced_weights_file_is_refused_when_its_decoder_is_taken() {
        use std::sync::atomic::AtomicBool;
        let kind = ModelKind::LengthGen;
        let sampler = scatter_sim::ConditionSampler::authors();
        let rows: Vec<_> = (0..400)
            .map(|i| scatter_sim::dataset::walk_row(9, &sampler, i).0)
            .collect();
        let table = Table::build(kind, &rows, crate::SingleScattering::Exact);
        let cfg = config(20, Some(0));
        let device = Device::flex().autodiff();
        let run = |dir: &Path, seed: u64| {
            crate::train::trainer::train_model(
                kind,
                &table,
                &cfg,
                seed,
                &device,
                dir,
                0,
                false,
                &AtomicBool::new(false),
                None,
                &|_, _, _, _| {},
            )
        };
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        assert_eq!(run(a.path(), 1).unwrap().info.step, 20);
        assert_eq!(run(b.path(), 2).unwrap().info.step, 20);
        let (weights_a, _, _) = paths(a.path(), kind);
        let (weights_b, _, _) = paths(b.path(), kind);
        let arch = cfg.architecture();
        let (_, info) = load_decoder(a.path(), kind, &arch).unwrap();
        assert_eq!(info.step, 20);
        let other = std::fs::read(&weights_b).unwrap();
        assert_ne!(
            std::fs::read(&weights_a).unwrap(),
            other,
            "two runs of other seeds hold other weights"
        );
        std::fs::write(&weights_a, &other).unwrap();
        match load_decoder(a.path(), kind, &arch) {
            Err(TrainError::Checkpoint { path, msg }) => assert!(
                path == weights_a && msg.contains("checksum"),
                "{}: {msg}",
                path.display()
            ),
            Err(e) => panic!("refused for another reason: {e}"),
            Ok(_) => panic!("another run's weights were taken as this checkpoint's"),
        }
    }
}
