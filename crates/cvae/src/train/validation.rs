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
use scatter_sim::stats::{mean_and_sem, welch_z};

use super::data::Table;
use super::network::Cvae;
use crate::sampler::normals;

/// Rows of each half, at most: over 2 × 2,048 rows the gap's z reads a shift of a sixteenth
/// of the losses' spread as 2; the evaluation costs four forward passes of a
/// default training batch (1,024 rows) every 500 steps.
pub const VALIDATION_ROWS: usize = 2048;

/// Fewer rows a side than this and no validation is read: the gap's z is N(0, 1) only
/// for a few dozen rows and more (Student's t below).
pub const MIN_VALIDATION_ROWS: usize = 20;

/// A row's loss beyond this (or not finite) is read as this: a memorising model finds some
/// held-out walks absurd, and an overflow to infinity or a NaN would make the mean
/// non-finite, which a checkpoint's JSON cannot hold (serde_json writes null and refuses
/// to read it back). Far above any loss a learning model has (single digits).
const LOSS_CAP: f64 = 1e30;

/// The two losses at one step, with their standard errors.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidationPoint {
    pub step: u64,
    /// Mean negative ELBO over the fixed sample of training walks, and its standard error.
    pub train: (f32, f32),
    /// The same over the held-out walks.
    pub held_out: (f32, f32),
    /// How far the held-out walks' losses lie above the training walks': Welch's z of
    /// the difference of their means after asinh (`tempered`), N(0, 1) while the model
    /// generalises. Tempered because a memorising model's held-out mean is ruled by a few
    /// walks it finds absurd (a mean of 728 against −0.29), whose spread hid the gap
    /// from a z of the plain means; a rank test, blind to how far those few lie, was
    /// weaker still (z 4.0 and 5.6 where this reads 4.9 and 11.4).
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
    /// `held` must be standardised like `train` ([`Table::like`]). Each side is `n`
    /// distinct rows drawn at random, n = the smaller table's rows up to
    /// [`VALIDATION_ROWS`]: distinct, so a small training table's rows do not count
    /// twice (the gap's z would spread wider than N(0, 1)); at random, so held-out
    /// walks simulated stream by stream are not the first streams' alone. `None` with
    /// fewer than [`MIN_VALIDATION_ROWS`] a side. The draws come from `seed` alone, not
    /// from the training's stream, so reading the loss changes nothing in the training.
    pub fn new(train: &Table, held: &Table, latent: usize, seed: u64) -> Option<Self> {
        let n = held.rows.min(train.rows).min(VALIDATION_ROWS);
        if n < MIN_VALIDATION_ROWS {
            return None;
        }
        let mut rng = WalkRng::for_walk(seed, 0x76a1_1da7 ^ train.kind as u64);
        let mut side = |table: &Table| {
            let rows = distinct(table.rows, n, &mut rng);
            let (mut cond, mut target) = (Vec::new(), Vec::new());
            table.rows_at(&rows, &mut rng, &mut cond, &mut target);
            Fixed::new(n, cond, target, latent, &mut rng)
        };
        let held_out = side(held);
        let train = side(train);
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
            rows.into_iter()
                .map(|v| match f64::from(v) {
                    v if v.is_finite() => v.clamp(-LOSS_CAP, LOSS_CAP),
                    _ => LOSS_CAP,
                })
                .collect()
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
            // Every loss equal (all capped, say): no evidence either way.
            gap_z: Some(welch_z(&tempered(&train), &tempered(&held)) as f32)
                .filter(|z| z.is_finite())
                .unwrap_or(0.0),
        }
    }
}

/// The losses through asinh: monotone, linear near 0 and logarithmic in the tail, where a
/// memorising model's few absurd held-out losses (hundreds) would otherwise widen the
/// standard error more than they move the mean, and hide the gap.
fn tempered(losses: &[f64]) -> Vec<f64> {
    losses.iter().map(|v| v.asinh()).collect()
}

/// `n` distinct indices below `len`, drawn uniformly (Floyd's algorithm: `n` draws, however
/// large `len` is), in increasing order.
fn distinct(len: usize, n: usize, rng: &mut WalkRng) -> Vec<usize> {
    let mut chosen = std::collections::BTreeSet::new();
    for j in len - n..len {
        let t = (rng.next_u64() % (j as u64 + 1)) as usize;
        if !chosen.insert(t) {
            chosen.insert(j);
        }
    }
    chosen.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Floyd's draws are distinct, in range and uniform: over 30,000 draws of 3 of 10 each
    /// index is drawn Binomial(30,000, 0.3) times (mean 9,000, sd 79); every count lies
    /// within 5 sd (noise alone leaves it with probability ~6·10⁻⁶ for the ten). Uniform
    /// over subsets too, which the counts alone do not show (three consecutive indices
    /// from a uniform start pass them): each of the 120 subsets expects 250 draws, and
    /// Pearson's χ² with 119 degrees of freedom stays below 185, its 10⁻⁴ quantile
    /// (Wilson–Hilferty). All of a table is all of it.
    #[test]
    fn distinct_draws_are_uniform() {
        let mut rng = WalkRng::from_seed(4);
        let mut counts = [0u32; 10];
        let mut subsets = [0u32; 1 << 10];
        for _ in 0..30_000 {
            let d = distinct(10, 3, &mut rng);
            assert_eq!(d.len(), 3);
            assert!(d.windows(2).all(|w| w[0] < w[1]) && d[2] < 10, "{d:?}");
            d.iter().for_each(|&i| counts[i] += 1);
            subsets[d.iter().map(|&i| 1usize << i).sum::<usize>()] += 1;
        }
        for c in counts {
            assert!((c as f64 - 9000.0).abs() < 5.0 * 79.4, "{counts:?}");
        }
        let chi2: f64 = (0..1usize << 10)
            .filter(|m| m.count_ones() == 3)
            .map(|m| (subsets[m] as f64 - 250.0).powi(2) / 250.0)
            .sum();
        assert!(chi2 < 185.0, "χ² over the 120 subsets = {chi2:.1}");
        assert_eq!(distinct(5, 5, &mut rng), [0, 1, 2, 3, 4]);
    }
}
