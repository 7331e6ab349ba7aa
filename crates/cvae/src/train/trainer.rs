//! The training loop of one CVAE: minibatches from a table, negative ELBO, Adamax with
//! warm-up and cosine learning-rate decay, periodic checkpoints, resume and clean stop.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use scatter_sim::WalkRng;
use scatter_sim::ranges::{num, whole_in, whole_list_in, whole_range};

use super::adamax::Adamax;
use super::data::{ConditionRanges, ModelKind, Standardisation, Table};
use super::network::{Architecture, Cvae};
use super::validation::{Validation, ValidationPoint};
use crate::decoder::Decoder;
use crate::sampler::normals;

/// Training settings of one model (a `[lengthgen]`, `[pathgen]` or `[eventgen]` table
/// of the training config).
/// (Its absent options are not serialized as null, which their readers refuse.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    #[serde(deserialize_with = "read_latent")]
    pub latent: usize,
    #[serde(deserialize_with = "read_hidden")]
    pub hidden: Vec<usize>,
    #[serde(
        default,
        deserialize_with = "read_encoder_hidden",
        skip_serializing_if = "Option::is_none"
    )]
    pub encoder_hidden: Option<Vec<usize>>,
    #[serde(deserialize_with = "read_steps")]
    pub steps: u64,
    #[serde(default = "default_batch", deserialize_with = "read_batch")]
    pub batch_size: usize,
    /// Peak learning rate (after warm-up).
    pub lr: f64,
    /// Learning rate at the last step (cosine decay from `lr`).
    pub lr_final: f64,
    /// Linear warm-up steps; default: 500, or a quarter of `steps` when that is fewer.
    #[serde(
        default,
        deserialize_with = "read_warmup",
        skip_serializing_if = "Option::is_none"
    )]
    pub warmup: Option<u64>,
}

/// Most rows a training batch may have (its activations' memory is bounded again by
/// [`MAX_BATCH_FLOATS`]).
pub const MAX_BATCH: usize = 1 << 20;
/// Widest layer an encoder may have.
pub const MAX_ENCODER_WIDTH: usize = 1024;

// The whole-number fields read with their own ranges, so that a value the type cannot
// hold (`batch_size = -1`) is refused with the range `validate` then checks ("[1,
// 1048576]"), not the type's ("at least 0", where 0 is refused as well).
fn read_latent<'de, D: serde::Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    whole_in(d, 1, crate::decoder::MAX_LATENT as u64)
}
fn read_hidden<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<usize>, D::Error> {
    whole_list_in(d, 1, crate::decoder::MAX_WIDTH as u64)
}
fn read_encoder_hidden<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Option<Vec<usize>>, D::Error> {
    whole_list_in(d, 1, MAX_ENCODER_WIDTH as u64).map(Some)
}
fn read_steps<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    whole_in(d, 1, MAX_STEPS)
}
fn read_batch<'de, D: serde::Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    whole_in(d, 1, MAX_BATCH as u64)
}
fn read_warmup<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
    whole_in(d, 0, MAX_STEPS).map(Some)
}

fn default_batch() -> usize {
    1024
}
const DEFAULT_WARMUP: u64 = 500;

/// Most hidden layers an encoder may have (the decoders': [`crate::decoder::MAX_HIDDEN_LAYERS`]).
pub const MAX_ENCODER_LAYERS: usize = 8;

/// Most floats one layer's activations may hold in a training batch (batch × width).
pub const MAX_BATCH_FLOATS: usize = 1 << 25;

impl ModelConfig {
    pub fn architecture(&self) -> Architecture {
        Architecture {
            latent: self.latent,
            hidden: self.hidden.clone(),
            encoder_hidden: self.encoder_hidden.clone(),
        }
    }

    /// The warm-up's length: as given, else the default (at most a quarter of the run, so
    /// that a short run without a `warmup` line still reaches `lr` and decays).
    pub fn warmup(&self) -> u64 {
        self.warmup.unwrap_or(DEFAULT_WARMUP.min(self.steps / 4))
    }

    /// Linear warm-up to `lr`, then cosine decay that would reach `lr_final` at step
    /// `steps`, one past the last step taken (steps count from 0): the last step's rate is
    /// above `lr_final` by (lr − lr_final)·(π/2)²/(steps − warmup)², nothing a run
    /// notices, and the shipped model was trained so.
    pub fn learning_rate(&self, step: u64) -> f64 {
        let warmup = self.warmup();
        if step < warmup {
            return self.lr * (step + 1) as f64 / warmup as f64;
        }
        let span = (self.steps.saturating_sub(warmup)).max(1) as f64;
        let t = ((step - warmup) as f64 / span).min(1.0);
        self.lr_final + 0.5 * (self.lr - self.lr_final) * (1.0 + (std::f64::consts::PI * t).cos())
    }

    pub fn validate(&self, name: &str) -> Result<(), String> {
        let bad = |f: &str, why: &str| Err(format!("{name}.{f}: {why}"));
        if self.steps == 0 || self.steps > MAX_STEPS {
            return bad(
                "steps",
                &format!(
                    "{} is out of range: allowed {} (0 would train nothing and export an \
                     untrained model)",
                    self.steps,
                    whole_range(1, MAX_STEPS)
                ),
            );
        }
        if self.latent == 0 || self.latent > crate::decoder::MAX_LATENT {
            return bad(
                "latent",
                &format!(
                    "{} is out of range: allowed {}",
                    self.latent,
                    whole_range(1, crate::decoder::MAX_LATENT as u64)
                ),
            );
        }
        if let Some(why) = layers_out_of_range(
            &self.hidden,
            crate::decoder::MAX_HIDDEN_LAYERS,
            crate::decoder::MAX_WIDTH,
        ) {
            return bad("hidden", &why);
        }
        // Depth bounded too: the batch check below is per tensor, and 64 layers of 1,024
        // at the largest batch it allows asked tens of GiB and aborted on allocation.
        if let Some(why) = self
            .encoder_hidden
            .as_deref()
            .and_then(|e| layers_out_of_range(e, MAX_ENCODER_LAYERS, MAX_ENCODER_WIDTH))
        {
            return bad("encoder_hidden", &why);
        }
        // A batch's activations are batch_size × widest layer floats per layer; beyond
        // 2^20 rows the gradients average out anyway and the memory does not.
        if self.batch_size == 0 || self.batch_size > MAX_BATCH {
            return bad(
                "batch_size",
                &format!(
                    "{} is out of range: allowed {}",
                    self.batch_size,
                    whole_range(1, MAX_BATCH as u64)
                ),
            );
        }
        // Each layer's activations and their gradients hold batch_size × width floats: a
        // batch of 2^20 with 1,024-wide encoder layers asked 4 GiB per tensor and aborted
        // on allocation. 2^25 floats (128 MiB a tensor) keeps a step within a few GiB.
        let widest = self
            .hidden
            .iter()
            .chain(self.encoder_hidden.iter().flatten())
            .copied()
            .max()
            .unwrap_or(1);
        let floats = self.batch_size.saturating_mul(widest);
        if floats > MAX_BATCH_FLOATS {
            return bad(
                "batch_size",
                &format!(
                    "{} × the widest layer's {widest} = {floats} floats a tensor, beyond \
                     {MAX_BATCH_FLOATS} (2^25): lower batch_size or the layer widths",
                    self.batch_size
                ),
            );
        }
        if !(self.lr > 0.0 && self.lr < 1.0) {
            return bad(
                "lr",
                &format!("{} is out of range: allowed (0, 1)", num(self.lr)),
            );
        }
        if !(self.lr_final >= 0.0 && self.lr_final <= self.lr) {
            return bad(
                "lr_final",
                &format!(
                    "{} is out of range: allowed [0, lr = {}]",
                    num(self.lr_final),
                    num(self.lr)
                ),
            );
        }
        // A warm-up longer than the run never reaches lr, nor decays to lr_final.
        if let Some(w) = self.warmup
            && w > self.steps
        {
            return bad(
                "warmup",
                &format!("{w} is out of range: allowed [0, steps = {}]", self.steps),
            );
        }
        Ok(())
    }
}

/// Why a list of layer widths is refused, naming the part that is wrong (the count, or the
/// first width out of range) so that a long list is not echoed whole.
fn layers_out_of_range(widths: &[usize], max_layers: usize, max_width: usize) -> Option<String> {
    let allowed = format!(
        "allowed {} layers, each of width {}",
        whole_range(1, max_layers as u64),
        whole_range(1, max_width as u64)
    );
    if widths.is_empty() || widths.len() > max_layers {
        return Some(format!("{} layers, out of range: {allowed}", widths.len()));
    }
    let (i, w) = widths
        .iter()
        .enumerate()
        .find(|&(_, &w)| w == 0 || w > max_width)?;
    Some(format!(
        "width {w} (layer {}) is out of range: {allowed}",
        i + 1
    ))
}

#[derive(Debug, Error)]
pub enum TrainError {
    #[error("interrupted: checkpoints saved in {0}; run the same command with --resume to go on")]
    Interrupted(PathBuf),
    #[error("{path}: {msg}")]
    Checkpoint { path: PathBuf, msg: String },
    #[error(
        "{0}: the loss or the weights became non-finite (or beyond the model file's bound) \
         at step {1}; lower the learning rate (its last checkpoint, if this run saved one, is \
         from before)"
    )]
    Diverged(&'static str, u64),
    /// A panic inside burn or the optimiser while training, caught by the caller and told
    /// in one line.
    #[error("{0}")]
    Failed(String),
}

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
        // report step, or a resume of a record saved before streams were kept). Twice that is refused: an edited
        // step of 999,999,999 on a run stopped at 4,366 was taken for a finished run, and
        // its model written with that step count.
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

/// The most steps a model may train for, as configured or after `--steps-scale`, and so
/// the most a checkpoint record may say it has taken (`CheckpointInfo::check`). At
/// ~1 µs a step 2^40 is 13 days; the bound keeps step counts exact in f64 and in the
/// learning-rate schedule.
pub const MAX_STEPS: u64 = 1 << 40;

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

/// A finished model.
pub struct Trained {
    pub kind: ModelKind,
    pub decoder: Decoder,
    pub info: CheckpointInfo,
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

fn paths(dir: &Path, kind: ModelKind) -> (PathBuf, PathBuf, PathBuf) {
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
fn save_checkpoint(
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

/// The loss is read every LOG_EVERY steps (reading synchronises, so not every step) and
/// the mean of those readings is reported and kept in the history every REPORT_EVERY.
const LOG_EVERY: u64 = 10;
const REPORT_EVERY: u64 = 500;

/// What `train_model` tells its caller at each report: the model, the step, the mean
/// training loss since the last report and the validation losses when it reads them.
pub type Report<'a> = dyn Fn(ModelKind, u64, f32, Option<&ValidationPoint>) + Sync + 'a;

/// A run's record before its first step (or a checkpoint to resume from).
fn fresh_info(table: &Table, cfg: &ModelConfig, seed: u64) -> CheckpointInfo {
    CheckpointInfo {
        feature_version: crate::features::FEATURE_VERSION,
        step: 0,
        seconds: 0.0,
        norm: table.norm.clone(),
        history: Vec::new(),
        crc32: None,
        single_scattering: Some(table.mode),
        ranges: Some(table.ranges),
        stream: None,
        validation: Vec::new(),
        plan: Some(Plan::of(cfg, seed)),
    }
}

/// A report at `info.step`: the held-out losses of `model` (the training copy) read on
/// its inference copy (when there is a `validation`), the caller told, and the mean
/// training loss kept in the history.
fn record_report(
    kind: ModelKind,
    info: &mut CheckpointInfo,
    mean: f32,
    model: &Cvae,
    validation: Option<&Validation>,
    eval_device: &Device,
    report: &Report<'_>,
) {
    if let Some(v) = validation {
        info.validation
            .push(v.evaluate(&model.valid(), info.step, eval_device));
    }
    report(
        kind,
        info.step,
        mean,
        validation.and(info.validation.last()),
    );
    info.history.push((info.step, mean));
}

/// Trains one model. `report(kind, step, loss, validation)` is called every few steps
/// (with the validation losses when `validation` is given), and once at the start of a
/// resumed run with the checkpoint's step and last readings; `cancel` stops after the
/// current step with a checkpoint.
#[allow(clippy::too_many_arguments)]
pub fn train_model(
    kind: ModelKind,
    table: &Table,
    cfg: &ModelConfig,
    seed: u64,
    device: &Device,
    checkpoint_dir: &Path,
    checkpoint_every: u64,
    resume: bool,
    cancel: &AtomicBool,
    validation: Option<&Validation>,
    report: &Report<'_>,
) -> Result<Trained, TrainError> {
    let mut rng = WalkRng::for_walk(seed, kind as u64);
    let mut model = Cvae::new(
        kind.cond(),
        kind.out(),
        &cfg.architecture(),
        &mut rng,
        device,
    );
    let mut optim = Adamax::default().init();
    let mut info = fresh_info(table, cfg, seed);
    let (.., record) = paths(checkpoint_dir, kind);
    if resume && record.exists() {
        (info, model, optim, rng) =
            resume_from(kind, table, cfg, seed, checkpoint_dir, model, optim)?;
    }
    // The stream where the checkpoint left it; one saved before streams were kept goes on
    // with the fresh stream above.
    let (mut acc, mut acc_n) = (0f64, 0u64);
    if let Some(state) = info.stream.take() {
        rng = state.rng;
        (acc, acc_n) = state.pending_loss;
    }
    // A resumed run says at once where it stands, at the checkpoint's step (a Ctrl-C lands
    // between reports) with the last loss read: its first report would otherwise come up
    // to REPORT_EVERY steps later, and a progress bar sat at 0 until then.
    if let Some(&(_, loss)) = info.history.last() {
        report(kind, info.step, loss, info.validation.last());
    }
    let eval_device = device.clone().inner();
    let start = Instant::now();
    let base_seconds = info.seconds;
    let (c, p, l) = (kind.cond(), kind.out(), cfg.latent);
    let b = cfg.batch_size;
    let (mut cond, mut target) = (Vec::new(), Vec::new());
    let mut eps = vec![0f32; b * l];
    while info.step < cfg.steps {
        table.batch(b, &mut rng, &mut cond, &mut target);
        normals(&mut rng, &mut eps);
        let tc = Tensor::<2>::from_data(TensorData::new(cond.clone(), [b, c]), device);
        let tt = Tensor::<2>::from_data(TensorData::new(target.clone(), [b, p]), device);
        let te = Tensor::<2>::from_data(TensorData::new(eps.clone(), [b, l]), device);
        let terms = model.loss(tc, tt, te);
        // Step 0 is always logged: it is the untrained model's loss; so is the last step,
        // whose report is the final loss (a run shorter than LOG_EVERY steps otherwise
        // reported its first step's loss as the final one); and the step before a report
        // whose window has no reading yet (a finished run resumed with more steps 1 to 9
        // steps before a report step skipped that report). Only such a window changes.
        let log_now = info.step.is_multiple_of(LOG_EVERY)
            || info.step + 1 == cfg.steps
            || (acc_n == 0 && (info.step + 1).is_multiple_of(REPORT_EVERY));
        if log_now {
            let v = terms.loss.clone().into_scalar::<f32>();
            if !v.is_finite() {
                return Err(TrainError::Diverged(kind.name(), info.step));
            }
            acc += v as f64;
            acc_n += 1;
        }
        let grads = GradientsParams::from_grads(terms.loss.backward(), &model);
        model = optim.step(cfg.learning_rate(info.step), model, grads);
        info.step += 1;
        if info.step.is_multiple_of(REPORT_EVERY) || info.step == 1 || info.step == cfg.steps {
            if acc_n > 0 {
                let mean = (acc / acc_n as f64) as f32;
                record_report(
                    kind,
                    &mut info,
                    mean,
                    &model,
                    validation,
                    &eval_device,
                    report,
                );
            }
            acc = 0.0;
            acc_n = 0;
        }
        let stop = cancel.load(Ordering::Relaxed);
        if stop || (checkpoint_every > 0 && info.step.is_multiple_of(checkpoint_every)) {
            // The loss is read every LOG_EVERY steps only: a checkpoint must not replace
            // the last good one with weights that have gone non-finite since.
            if !exportable(&model, &table.norm) {
                return Err(TrainError::Diverged(kind.name(), info.step));
            }
            info.seconds = base_seconds + start.elapsed().as_secs_f64();
            info.stream = Some(StreamState {
                rng: rng.clone(),
                pending_loss: (acc, acc_n),
            });
            save_checkpoint(checkpoint_dir, kind, &model, &optim, &info)?;
            if stop {
                return Err(TrainError::Interrupted(checkpoint_dir.into()));
            }
        }
    }
    // The encoder too: the final save is what `--resume` with more steps goes on from.
    if !exportable(&model, &table.norm) {
        return Err(TrainError::Diverged(kind.name(), info.step));
    }
    let decoder = model.valid().export(&table.norm);
    info.seconds = base_seconds + start.elapsed().as_secs_f64();
    // A finished run's stream too: `--resume` with more steps goes on from it.
    info.stream = Some(StreamState {
        rng,
        pending_loss: (acc, acc_n),
    });
    save_checkpoint(checkpoint_dir, kind, &model, &optim, &info)?;
    Ok(Trained {
        kind,
        decoder,
        info,
    })
}

/// Whether a decoder's weights are all finite and within what a model file may hold
/// ([`crate::model_file::MAX_WEIGHT`]): beyond it `train` would write a file that every
/// reader refuses.
fn within_bounds(d: &Decoder) -> bool {
    d.layers.iter().all(|l| {
        l.weight
            .iter()
            .chain(&l.bias)
            .all(|v| v.abs() <= crate::model_file::MAX_WEIGHT)
    })
}

/// Whether a checkpoint may replace the last good one: the decoder as [`within_bounds`],
/// and the encoder finite as well (a `--resume` from NaN encoder weights diverged at
/// once). Adamax's moments are not read: a non-finite gradient makes its parameter's
/// update, and so the parameter, non-finite in the same step (u = max(β₂u, |g|) = ∞ or
/// NaN, and m/u = NaN).
fn exportable(model: &Cvae, norm: &Standardisation) -> bool {
    within_bounds(&model.valid().export(norm))
        && model
            .encoder
            .to_dense()
            .iter()
            .all(|l| l.weight.iter().chain(&l.bias).all(|v| v.is_finite()))
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
fn resume_from(
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

    fn config(steps: u64, warmup: Option<u64>) -> ModelConfig {
        ModelConfig {
            latent: 2,
            hidden: vec![4],
            encoder_hidden: None,
            steps,
            batch_size: 8,
            lr: 1e-2,
            lr_final: 1e-4,
            warmup,
        }
    }

    /// A config written out reads back as it was, its absent options included (written as
    /// null, they were refused by the range-checking readers), and a negative width or
    /// batch is refused with the field's range.
    #[test]
    fn a_model_config_round_trips_and_states_its_ranges() {
        for c in [config(100, None), config(100, Some(7))] {
            let text = serde_json::to_string(&c).unwrap();
            assert_eq!(
                serde_json::from_str::<ModelConfig>(&text).unwrap(),
                c,
                "{text}"
            );
        }
        let bad = |json: &str| {
            serde_json::from_str::<ModelConfig>(json)
                .unwrap_err()
                .to_string()
        };
        let base = r#""latent": 2, "steps": 10, "lr": 0.01, "lr_final": 0.001"#;
        let e = bad(&format!(r#"{{{base}, "hidden": [4, -1]}}"#));
        assert!(e.contains("expected a whole number in [1, 64]"), "{e}");
        let e = bad(&format!(r#"{{{base}, "hidden": [4], "batch_size": -1}}"#));
        assert!(e.contains("expected a whole number in [1, 1048576]"), "{e}");
    }

    /// Without a `warmup` line a short run warms up over a quarter of its steps (the
    /// default 500 would outlast it: lr never reached, never decayed); a given warm-up
    /// longer than the run is refused, naming the model and the field.
    #[test]
    fn the_warm_up_fits_the_run() {
        let short = config(100, None);
        assert_eq!(short.warmup(), 25);
        assert!(short.validate("m").is_ok());
        assert_eq!(short.learning_rate(24), 1e-2);
        assert!((short.learning_rate(100) - 1e-4).abs() < 1e-12);
        assert!(short.learning_rate(60) < 1e-2 && short.learning_rate(60) > 1e-4);
        assert_eq!(config(100_000, None).warmup(), 500);
        let e = config(100, Some(101)).validate("pathgen").unwrap_err();
        assert_eq!(
            e,
            "pathgen.warmup: 101 is out of range: allowed [0, steps = 100]"
        );
    }

    /// The schedule at its landmarks against the formula worked by hand, with lr = 1e-2,
    /// lr_final = 1e-4 and a warm-up of 25 of 125 steps (a decay over 100): lr/25 = 4e-4
    /// at step 0; lr at the warm-up's last step (24) and at the decay's first (25), never
    /// above it; lr_final + (lr − lr_final)(1 + cos π/4)/2 = 8.550179e-3 a quarter into the
    /// decay (step 50); (lr + lr_final)/2 = 5.05e-3 halfway (step 75); lr_final at step 125.
    /// Within 1e-12 relative: f64 rounding (cos π/2 = 6e-17). The test above checks step 24,
    /// the end and that step 60 lies between the two rates, which a decay from
    /// lr + 2·lr_final (the difference written as a sum: 1.02e-2 at step 25, 5.15e-3 at 75)
    /// passed, as did a warm-up one step too long (lr·26/25 at step 25).
    #[test]
    fn the_schedule_meets_its_landmarks() {
        let c = config(125, Some(25));
        let (lr, fin) = (1e-2, 1e-4);
        for (step, want) in [
            (0, lr / 25.0),
            (24, lr),
            (25, lr),
            (
                50,
                fin + 0.5 * (lr - fin) * (1.0 + std::f64::consts::FRAC_1_SQRT_2),
            ),
            (75, 0.5 * (lr + fin)),
            (125, fin),
        ] {
            let got = c.learning_rate(step);
            assert!(
                (got - want).abs() <= 1e-12 * want,
                "step {step}: {got} against {want}"
            );
        }
        // Rising through the warm-up, falling after it, never above lr.
        for s in 0..125 {
            let (a, b) = (c.learning_rate(s), c.learning_rate(s + 1));
            assert!(a <= lr * (1.0 + 1e-12), "step {s}: {a}");
            if s < 24 {
                assert!(b > a, "warm-up step {s}: {a} then {b}");
            } else {
                assert!(b <= a * (1.0 + 1e-12), "decay step {s}: {a} then {b}");
            }
        }
    }

    /// A refused layer list names its count or its first bad width, not the whole list.
    #[test]
    fn layer_lists_name_what_is_out_of_range() {
        let mut c = config(100, None);
        let allowed = "allowed [1, 8] layers, each of width [1, 64]";
        for (hidden, why) in [
            (vec![], "0 layers, out of range".to_string()),
            (
                vec![16, 0, 16],
                "width 0 (layer 2) is out of range".to_string(),
            ),
            (vec![65], "width 65 (layer 1) is out of range".to_string()),
            (vec![1; 10_000], "10000 layers, out of range".to_string()),
        ] {
            c.hidden = hidden;
            let e = c.validate("lengthgen").unwrap_err();
            assert_eq!(e, format!("lengthgen.hidden: {why}: {allowed}"));
        }
        c.hidden = vec![64; 8];
        assert!(c.validate("lengthgen").is_ok());
    }

    /// A batch whose widest layer's activations would pass 2^25 floats is refused, naming
    /// the field; exactly 2^25 passes.
    #[test]
    fn a_batch_too_large_for_memory_is_refused() {
        let mut c = config(100, None);
        c.hidden = vec![32];
        c.encoder_hidden = Some(vec![1024, 1024]);
        c.batch_size = MAX_BATCH_FLOATS / 1024;
        assert!(c.validate("pathgen").is_ok());
        c.batch_size += 1;
        let e = c.validate("pathgen").unwrap_err();
        assert!(
            e.starts_with("pathgen.batch_size: ") && e.contains("1024"),
            "{e}"
        );
        // The check is per tensor: the depth is bounded apart.
        c.batch_size = MAX_BATCH_FLOATS / 1024;
        c.encoder_hidden = Some(vec![1024; MAX_ENCODER_LAYERS]);
        assert!(c.validate("pathgen").is_ok());
        c.encoder_hidden = Some(vec![1024; MAX_ENCODER_LAYERS + 1]);
        let e = c.validate("pathgen").unwrap_err();
        assert_eq!(
            e,
            "pathgen.encoder_hidden: 9 layers, out of range: allowed [1, 8] layers, each of \
             width [1, 1024]"
        );
    }

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
            norm: Standardisation {
                cond_shift: vec![0.0; kind.cond()],
                cond_scale: vec![1.0; kind.cond()],
                out_shift: vec![0.0; kind.out()],
                out_scale: vec![1.0; kind.out()],
            },
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

    /// A run whose loss turns non-finite stops with `Diverged`, naming the model and the
    /// step and advising a lower rate, and leaves the last checkpoint as it was. The
    /// divergence is forced by resuming from a checkpoint whose encoder holds one weight
    /// of 1e30 (finite, so the checkpoint loads; no rate within the config's bounds
    /// diverges reliably): the first loss read, at the checkpoint's step, overflows. A
    /// NaN weight instead, which no run saves, is refused as a damaged checkpoint naming
    /// its file before any step (it read as a divergence blamed on the learning rate).
    #[test]
    fn a_non_finite_loss_stops_the_run_and_keeps_the_checkpoint() {
        let d = tempfile::tempdir().unwrap();
        let kind = ModelKind::LengthGen;
        let device = Device::flex().autodiff();
        let sampler = scatter_sim::ConditionSampler::authors();
        let rows: Vec<_> = (0..400)
            .map(|i| scatter_sim::dataset::walk_row(9, &sampler, i).0)
            .collect();
        let table = Table::build(kind, &rows, crate::SingleScattering::Exact);
        let cfg = config(40, Some(0));
        let resume_from = |w0: f32, in_decoder: bool| {
            let mut rng = WalkRng::from_seed(5);
            let mut model = Cvae::new(
                kind.cond(),
                kind.out(),
                &cfg.architecture(),
                &mut rng,
                &device,
            );
            let mlp = if in_decoder {
                &mut model.decoder
            } else {
                &mut model.encoder
            };
            let [i, o] = mlp.layers[0].weight.val().dims();
            let mut w: Vec<f32> = mlp.layers[0].weight.val().try_into_vec_as::<f32>().unwrap();
            w[0] = w0;
            mlp.layers[0].weight =
                burn::module::Param::from_data(TensorData::new(w, [i, o]), &device);
            let info = CheckpointInfo {
                feature_version: crate::features::FEATURE_VERSION,
                step: 10,
                seconds: 0.0,
                norm: table.norm.clone(),
                history: vec![(1, 2.0), (10, 1.0)],
                crc32: None,
                single_scattering: Some(table.mode),
                ranges: Some(table.ranges),
                stream: None,
                validation: Vec::new(),
                plan: None,
            };
            save_checkpoint(d.path(), kind, &model, &Adamax::default().init(), &info).unwrap();
            let (_, _, j) = paths(d.path(), kind);
            let before = std::fs::read(&j).unwrap();
            let e = train_model(
                kind,
                &table,
                &cfg,
                1,
                &device,
                d.path(),
                5,
                true,
                &AtomicBool::new(false),
                None,
                &|_, _, _, _| {},
            )
            .err()
            .expect("a run from such weights trains on");
            assert_eq!(
                std::fs::read(&j).unwrap(),
                before,
                "the checkpoint was replaced"
            );
            e
        };
        let e = resume_from(1e30, false);
        assert!(matches!(e, TrainError::Diverged("lengthgen", 10)), "{e}");
        assert!(
            e.to_string()
                .contains("at step 10; lower the learning rate"),
            "{e}"
        );
        for in_decoder in [false, true] {
            let e = resume_from(f32::NAN, in_decoder).to_string();
            assert!(
                e.contains("lengthgen.bpk")
                    && e.contains("not finite")
                    && e.contains("--fresh --model lengthgen"),
                "{e}"
            );
        }
        // The decoder alone, taken into a model file another run exports, is refused too.
        let e = load_decoder(d.path(), kind, &cfg.architecture())
            .expect_err("a NaN decoder weight was taken")
            .to_string();
        assert!(
            e.contains("lengthgen.bpk") && e.contains("not finite"),
            "{e}"
        );
    }

    /// A checkpoint or model is written only with weights a model file can hold: a fresh
    /// network's pass; one NaN weight, or one beyond MAX_WEIGHT, fails (a checkpoint of
    /// such weights replaced the last good one; a final one gave a file every reader
    /// refuses).
    #[test]
    fn only_finite_bounded_weights_are_saved() {
        let mut rng = WalkRng::from_seed(3);
        let kind = ModelKind::PathGen;
        let arch = config(10, None).architecture();
        let model = Cvae::new(kind.cond(), kind.out(), &arch, &mut rng, &Device::flex());
        let norm = Standardisation {
            cond_shift: vec![0.0; kind.cond()],
            cond_scale: vec![1.0; kind.cond()],
            out_shift: vec![0.0; kind.out()],
            out_scale: vec![1.0; kind.out()],
        };
        assert!(exportable(&model, &norm));
        let good = model.valid().export(&norm);
        for bad in [
            f32::NAN,
            f32::INFINITY,
            -2.0 * crate::model_file::MAX_WEIGHT,
        ] {
            let mut d = good.clone();
            let last = d.layers.len() - 1;
            let l = &d.layers[last];
            let mut w = l.weight.clone();
            w[0] = bad;
            d.layers[last] = crate::decoder::Dense::new(l.inputs, l.outputs, w, l.bias.clone());
            assert!(!within_bounds(&d), "{bad}");
        }
        // A NaN in the encoder alone (the decoder still finite) is refused too.
        let mut broken = model.clone();
        let first = &broken.encoder.layers[0];
        let [i, o] = first.weight.val().dims();
        let mut w: Vec<f32> = first.weight.val().try_into_vec_as::<f32>().unwrap();
        w[1] = f32::NAN;
        broken.encoder.layers[0].weight =
            burn::module::Param::from_data(TensorData::new(w, [i, o]), &Device::flex());
        assert!(within_bounds(&broken.valid().export(&norm)));
        assert!(!exportable(&broken, &norm));
    }
}
