//! A validation loss: the negative ELBO on walks the model never trained on, beside the
//! same loss on as many of its training walks, both with fixed draws.
//!
//! The training loss alone cannot show a model learning its dataset's particular walks
//! rather than their distribution (a small dataset trained long): the two fall together.
//! Held-out walks (the dataset's run's next walks, `scatter_sim::dataset::held_out_rows`)
//! can; and the loss on a fixed sample of training walks, read at the same moment with
//! the same kind of draws, is the like-for-like reference (the running training loss is a
//! mean over the last interval's changing weights and batches).

use burn::prelude::*;
use serde::{Deserialize, Serialize};

use scatter_sim::WalkRng;

use super::data::Table;
use super::network::Cvae;
use crate::sampler::normals;

/// Rows of each half, at most. Each loss is a mean over this many rows, so its standard
/// error is the rows' spread / 45; and the evaluation costs about one training batch's
/// forward pass per 500 steps.
pub const VALIDATION_ROWS: usize = 2048;

/// The two losses at one step, with their standard errors.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidationPoint {
    pub step: u64,
    /// Mean negative ELBO over the fixed sample of training walks, and its standard error.
    pub train: (f32, f32),
    /// The same over the held-out walks.
    pub held_out: (f32, f32),
}

impl ValidationPoint {
    /// How far the held-out loss lies above the training walks' loss, in standard errors
    /// of the difference (the two samples are independent).
    pub fn gap_z(&self) -> f32 {
        let se = (self.train.1.powi(2) + self.held_out.1.powi(2)).sqrt();
        (self.held_out.0 - self.train.0) / se.max(f32::MIN_POSITIVE)
    }
}

/// One fixed evaluation batch: conditions, targets and reparameterisation normals.
struct Fixed {
    rows: usize,
    cond: Vec<f32>,
    target: Vec<f32>,
    eps: Vec<f32>,
}

/// The fixed batches a model's validation loss is read on.
pub struct Validation {
    train: Fixed,
    held_out: Fixed,
}

impl Validation {
    /// `held` must be standardised like `train` ([`Table::like`]). `None` when `held` has
    /// no usable row (a dataset whose run draws none for this model). The draws come from
    /// `seed` alone, not from the training's stream, so reading the loss changes nothing
    /// in the training.
    pub fn new(train: &Table, held: &Table, latent: usize, seed: u64) -> Option<Self> {
        if held.rows == 0 || train.rows == 0 {
            return None;
        }
        let mut rng = WalkRng::for_walk(seed, 0x76a1_1da7 ^ train.kind as u64);
        let n = held.rows.min(VALIDATION_ROWS);
        let mut fixed =
            |rows: usize, fill: &mut dyn FnMut(&mut WalkRng, &mut Vec<f32>, &mut Vec<f32>)| {
                let (mut cond, mut target) = (Vec::new(), Vec::new());
                fill(&mut rng, &mut cond, &mut target);
                let mut eps = vec![0f32; rows * latent];
                normals(&mut rng, &mut eps);
                Fixed {
                    rows,
                    cond,
                    target,
                    eps,
                }
            };
        // The held-out rows in order (the first n); as many training rows, drawn.
        let held_out = fixed(n, &mut |rng, cond, target| {
            held.all_rows(rng, cond, target);
            cond.truncate(n * held.kind.cond());
            target.truncate(n * held.kind.out());
        });
        let train = fixed(n, &mut |rng, cond, target| {
            train.batch(n, rng, cond, target)
        });
        Some(Self { train, held_out })
    }

    /// Both losses of `model` (on any device: the caller passes its inference copy).
    pub fn evaluate(&self, model: &Cvae, step: u64, device: &Device) -> ValidationPoint {
        let (c, p, l) = (model.cond, model.out, model.latent);
        let mean_se = |f: &Fixed| {
            let t = |v: &[f32], w: usize| {
                Tensor::<2>::from_data(TensorData::new(v.to_vec(), [f.rows, w]), device)
            };
            let losses = model.row_losses(t(&f.cond, c), t(&f.target, p), t(&f.eps, l));
            let n = losses.len() as f64;
            let mean = losses.iter().map(|&v| v as f64).sum::<f64>() / n;
            let var = losses
                .iter()
                .map(|&v| (v as f64 - mean).powi(2))
                .sum::<f64>()
                / (n - 1.0).max(1.0);
            (mean as f32, (var / n).sqrt() as f32)
        };
        ValidationPoint {
            step,
            train: mean_se(&self.train),
            held_out: mean_se(&self.held_out),
        }
    }
}
