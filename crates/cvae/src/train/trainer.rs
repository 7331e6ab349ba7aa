//! The training loop of one CVAE: minibatches from a table, negative ELBO, Adamax with
//! warm-up and cosine learning-rate decay (config.rs), periodic checkpoints, resume and
//! clean stop (checkpoint.rs).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use burn::optim::GradientsParams;
use burn::prelude::*;
use thiserror::Error;

use scatter_sim::WalkRng;

use super::adamax::Adamax;
use super::checkpoint::{CheckpointInfo, Plan, StreamState, paths, resume_from, save_checkpoint};
use super::config::ModelConfig;
use super::data::{ModelKind, Standardisation, Table};
use super::network::Cvae;
use super::validation::{Validation, ValidationPoint};
use crate::decoder::Decoder;
use crate::sampler::normals;

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

/// A finished model.
pub struct Trained {
    pub kind: ModelKind,
    pub decoder: Decoder,
    pub info: CheckpointInfo,
}

/// The loss is read every LOG_EVERY steps (reading synchronises, so not every step) and
/// the mean of those readings is reported and kept in the history every REPORT_EVERY.
pub(super) const LOG_EVERY: u64 = 10;

pub(super) const REPORT_EVERY: u64 = 500;

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
pub(super) fn within_bounds(d: &Decoder) -> bool {
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
pub(super) fn exportable(model: &Cvae, norm: &Standardisation) -> bool {
    within_bounds(&model.valid().export(norm))
        && model
            .encoder
            .to_dense()
            .iter()
            .all(|l| l.weight.iter().chain(&l.bias).all(|v| v.is_finite()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::checkpoint::load_decoder;
    use crate::train::config::config;

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
        let norm = Standardisation::identity(kind);
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
