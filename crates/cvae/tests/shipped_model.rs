//! The shipped model keeps its KS statistics (docs/TRAINING.md) at four settings (three of
//! the paper's grid at φ = 1, one at φ = 0.9), so a regression in the sampling code (transforms,
//! frames, the exact branches) is caught without retraining.

use std::path::Path;

use cvae::ModelSet;
use cvae::eval::{PAIRS, QUANTITIES, evaluate_setting};

/// A medium (τ, g, φ), its stored statistics' means and their spreads (sample standard
/// deviations) over the seeds.
type Setting = ((f64, f64, f64), &'static [f64], &'static [f64]);

/// The shipped model's KS statistics, each the mean and spread over seeds
/// 1–[`MEASURE_SEEDS`] ([`remeasure_the_stored_means`]; means 2026-12-02/03, spreads
/// printed again 2026-12-03 with the same means), per setting (τ, g, φ) and quantity: at
/// φ = 1 [`QUANTITIES`] but log N (whose statistic is N's: KS is unchanged by a monotone
/// map), then the 2-D statistics of [`PAIRS`]; at φ < 1 the representative event's three
/// (`eval` compares only those there: N and the exit do not depend on φ, the event's
/// choice among the walk's events does, through φ^k and EventGen's (1 − φ)^(1/6)).
const MEASURED: [Setting; 4] = [
    (
        (5.0, 0.4, 1.0),
        &[
            0.0183, 0.0333, 0.0127, 0.0125, 0.0243, 0.0263, 0.0142, 0.0347, 0.0354,
        ],
        &[
            0.0056, 0.0048, 0.0037, 0.0041, 0.0043, 0.0073, 0.0055, 0.0048, 0.0049,
        ],
    ),
    (
        (25.0, 0.0, 1.0),
        &[
            0.0165, 0.0306, 0.0130, 0.0143, 0.0555, 0.0299, 0.0143, 0.0333, 0.0331,
        ],
        &[
            0.0032, 0.0029, 0.0039, 0.0041, 0.0061, 0.0055, 0.0027, 0.0031, 0.0037,
        ],
    ),
    (
        (125.0, -0.7, 1.0),
        &[
            0.0184, 0.0302, 0.0109, 0.0144, 0.0456, 0.0352, 0.0159, 0.0325, 0.0326,
        ],
        &[
            0.0031, 0.0045, 0.0031, 0.0042, 0.0047, 0.0069, 0.0061, 0.0045, 0.0042,
        ],
    ),
    (
        (25.0, 0.0, 0.9),
        &[0.0402, 0.0161, 0.0186],
        &[0.0043, 0.0036, 0.0056],
    ),
];

/// Seeds the test averages each statistic over, and seeds the stored means were taken over
/// ([`remeasure_the_stored_means`]).
const TEST_SEEDS: u64 = 4;
const MEASURE_SEEDS: u64 = 24;

/// The statistics' names at albedo φ, in [`MEASURED`]'s order.
fn names(albedo: f64) -> Vec<&'static str> {
    if albedo < 1.0 {
        return QUANTITIES
            .into_iter()
            .filter(|q| q.starts_with("event_"))
            .collect();
    }
    QUANTITIES
        .into_iter()
        .filter(|q| *q != "log_n")
        .chain(PAIRS.map(|p| p.0))
        .collect()
}

/// Each statistic at one setting and seed: 10,000 model against 10,000 simulator samples,
/// as `stcvae eval`.
fn statistics(m: &ModelSet, (tau, g, albedo): (f64, f64, f64), seed: u64) -> Vec<f64> {
    let r = evaluate_setting(m, tau, g, albedo, 10_000, seed);
    names(albedo)
        .into_iter()
        .map(|q| {
            r.ks(q)
                .unwrap_or_else(|| panic!("eval reports no KS of {q} at φ = {albedo}"))
        })
        .collect()
}

fn shipped() -> ModelSet {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.stcvae");
    ModelSet::load(&path).unwrap()
}

/// The mean over [`TEST_SEEDS`] seeds of each KS statistic may exceed its stored mean over
/// [`MEASURE_SEEDS`] seeds by 5 of its own spreads, at least 0.005.
/// - What it is: a regression guard. The bar is the shipped model's own fit as measured
///   by this code (docs/TRAINING.md), not an independent reference; each statistic does
///   compare the model with fresh simulator walks, whose own tests hold them to analytic
///   references (scatter-sim).
/// - Why that is safe: most of these statistics measure the model's misfit, not only
///   noise; over 24 seeds their spread σ was 0.0027–0.0073. With the code unchanged the
///   test's seeds are among the measured ones and it repeats their figures exactly; the
///   case the margin is sized for is a change that only redraws the random numbers
///   (another order of draws), after which the mean of 4 seeds is independent of the
///   stored mean of 24 and differs from it by σ·√(1/4 + 1/24) = 0.54σ in spread. 5 of
///   those (a false alarm ~3·10⁻⁷ a statistic, ~10⁻⁵ over the 30) is 0.0073–0.0197. (Until
///   2026-12-05 the margin took the nested √(1/4 − 1/24) = 0.46σ, which holds only for the
///   unchanged draws; for a redraw it was 4.2 spreads, ~4·10⁻⁴ over the 30.) The floor
///   keeps a statistic whose spread was measured low from a bound tighter than its
///   estimate's own error (σ from 24 seeds is ±15 %).
///   (One margin of 0.02 for all, sized by the widest spread, was ~16σ of the difference
///   for the narrowest statistics; before that, one seed against its stored value plus
///   0.02 failed about one redraw in 40.)
/// - What it catches: a sampling regression (a wrong transform, frame or exact branch)
///   that raises any statistic's expectation by more than its margin, where the stored
///   means are 0.011–0.056: a 10 % scale error in α or β moves its KS by ~0.024, which
///   passed the flat 0.02 at the noise floor of 10,000 against 10,000 samples. (A misfit
///   the size of the noise adds less than itself to a statistic, so a small new misfit
///   can still pass.) The 2-D statistics catch what the marginals cannot: exit
///   directions right overall but paired with the wrong exit points.
#[test]
fn shipped_model_quick_eval() {
    let m = shipped();
    for (setting, stored, spread) in MEASURED {
        assert_eq!(stored.len(), spread.len(), "{setting:?}");
        // A statistic added to `names` without a stored mean would shift every later one
        // onto its neighbour's mean (the zip below pairs them by position).
        assert_eq!(names(setting.2).len(), stored.len(), "{setting:?}");
        let mut now = vec![0.0; stored.len()];
        for seed in 1..=TEST_SEEDS {
            for (n, v) in now.iter_mut().zip(statistics(&m, setting, seed)) {
                *n += v / TEST_SEEDS as f64;
            }
        }
        // The spread of (mean of the test's seeds − the stored mean) after a redraw.
        let redrawn = (1.0 / TEST_SEEDS as f64 + 1.0 / MEASURE_SEEDS as f64).sqrt();
        for (((q, ks), mean), sd) in names(setting.2)
            .into_iter()
            .zip(now)
            .zip(stored)
            .zip(spread)
        {
            let bound = mean + (5.0 * sd * redrawn).max(0.005);
            eprintln!("{setting:?} {q}: {ks:.4} (bound {bound:.4})");
            assert!(
                ks <= bound,
                "(τ, g, φ) = {setting:?}: KS({q}) averaged over {TEST_SEEDS} seeds = {ks:.4} \
                 > {bound:.4} (its mean over {MEASURE_SEEDS} seeds was {mean}, spread {sd})"
            );
        }
    }
}

/// Prints [`MEASURED`] anew, with each statistic's spread over the seeds (for the margin
/// above): `cargo test --release -p cvae --test shipped_model -- --ignored --nocapture`
/// after retraining the shipped model.
#[test]
#[ignore = "re-measures the stored means (~90 s); run by hand after retraining"]
fn remeasure_the_stored_means() {
    let m = shipped();
    for (setting, _, _) in MEASURED {
        let per_seed: Vec<Vec<f64>> = (1..=MEASURE_SEEDS)
            .map(|seed| statistics(&m, setting, seed))
            .collect();
        let n = per_seed.len() as f64;
        let k = per_seed[0].len();
        let mean: Vec<f64> = (0..k)
            .map(|k| per_seed.iter().map(|v| v[k]).sum::<f64>() / n)
            .collect();
        let sd: Vec<f64> = (0..k)
            .map(|k| {
                (per_seed
                    .iter()
                    .map(|v| (v[k] - mean[k]).powi(2))
                    .sum::<f64>()
                    / (n - 1.0))
                    .sqrt()
            })
            .collect();
        println!("{setting:?}");
        println!(
            "  mean {}",
            mean.iter()
                .map(|x| format!("{x:.4}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
        println!(
            "  sd   {}",
            sd.iter()
                .map(|x| format!("{x:.4}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
}
