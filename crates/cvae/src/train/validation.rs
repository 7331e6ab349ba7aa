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
use scatter_sim::stats::{mann_whitney_z, mean_and_sem};

use super::data::Table;
use super::network::Cvae;
use crate::sampler::normals;

/// Rows of each half, at most: a rank test over 2 × 2,048 rows tells a shift of a sixteenth
/// of the losses' spread at about 2 z; the evaluation costs about two training batches' forward
/// passes per 500 steps.
pub const VALIDATION_ROWS: usize = 2048;

/// The two losses at one step, with their standard errors.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidationPoint {
    pub step: u64,
    /// Mean negative ELBO over the fixed sample of training walks, and its standard error.
    pub train: (f32, f32),
    /// The same over the held-out walks.
    pub held_out: (f32, f32),
    /// How far the held-out walks' losses rank above the training walks' (Mann–Whitney,
    /// as a z-score: N(0, 1) while the model generalises). A rank test, not the means'
    /// difference: a memorising model's held-out mean is ruled by a few walks it finds
    /// absurd (a loss of 728 against −0.29), whose spread hid the gap from a z of means.
    pub gap_z: f32,
}

/// One fixed evaluation batch: conditions, targets and reparameterisation normals.
struct Fixed {
    rows: usize,
    cond: Vec<f32>,
    target: Vec<f32>,
    eps: Vec<f32>,
}

impl Fixed {
    fn new(
        rows: usize,
        cond: Vec<f32>,
        target: Vec<f32>,
        latent: usize,
        rng: &mut WalkRng,
    ) -> Self {
        let mut eps = vec![0f32; rows * latent];
        normals(rng, &mut eps);
        Self {
            rows,
            cond,
            target,
            eps,
        }
    }
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
        // The held-out rows in order (the first n); as many training rows, drawn.
        let (mut cond, mut target) = (Vec::new(), Vec::new());
        held.all_rows(&mut rng, &mut cond, &mut target);
        cond.truncate(n * held.kind.cond());
        target.truncate(n * held.kind.out());
        let held_out = Fixed::new(n, cond, target, latent, &mut rng);
        let (mut cond, mut target) = (Vec::new(), Vec::new());
        train.batch(n, &mut rng, &mut cond, &mut target);
        let train = Fixed::new(n, cond, target, latent, &mut rng);
        Some(Self { train, held_out })
    }

    /// Both losses of `model` (on any device: the caller passes its inference copy).
    pub fn evaluate(&self, model: &Cvae, step: u64, device: &Device) -> ValidationPoint {
        let (c, p, l) = (model.cond, model.out, model.latent);
        let losses = |f: &Fixed| -> Vec<f64> {
            let t = |v: &[f32], w: usize| {
                Tensor::<2>::from_data(TensorData::new(v.to_vec(), [f.rows, w]), device)
            };
            let rows = model.row_losses(t(&f.cond, c), t(&f.target, p), t(&f.eps, l));
            rows.into_iter().map(f64::from).collect()
        };
        let (train, held) = (losses(&self.train), losses(&self.held_out));
        let mean_se = |v: &[f64]| {
            let (m, se) = mean_and_sem(v);
            (m as f32, se as f32)
        };
        ValidationPoint {
            step,
            train: mean_se(&train),
            held_out: mean_se(&held),
            gap_z: mann_whitney_z(&train, &held) as f32,
        }
    }
}
