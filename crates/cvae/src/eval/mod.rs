//! Distribution fidelity of the models against fresh simulator walks (paper §5.3).
//!
//! For each setting, `samples` model walks and `samples` simulator walks are compared
//! marginal by marginal with the two-sample Kolmogorov–Smirnov statistic and the
//! Wasserstein-1 distance. KS is invariant under monotone maps, so KS(N) = KS(log N);
//! W1 is reported for both.
//!
//! Expectations a renderer integrates are compared as well, model over simulator: the
//! NEE weight E[Λ(N)]; the survival weight E[φ^N] a sphere step leaves a path with, at
//! [`SURVIVAL_ALBEDOS`]; the NEE a walk's representative event would collect if the
//! sphere's own boundary were the surface ([`sphere_nee`]); the same for a flat surface
//! touching the sphere behind, beside or ahead of the walk ([`half_space_nee`]), and the
//! share of events near the sphere's surface ([`SHELLS`]). Small KS values can hide a
//! few per cent in these, which is what an image shows (docs/BENCHMARKS.md).

use std::sync::atomic::{AtomicBool, Ordering};

use serde::Serialize;

use scatter_sim::stats::{ks_two_sample, ks_two_sample_2d, sliced_wasserstein1, wasserstein1};

use crate::model_file::ModelSet;

mod columns;
mod expectations;
mod tables;
#[cfg(test)]
mod tests;

use columns::edge_distance;
pub use columns::{
    Columns, WalkSummary, model_columns, model_columns_until, model_rng, simulator_columns,
    simulator_columns_until,
};
pub use expectations::{SURFACE_SIDES, half_space_nee, sphere_nee};
pub use tables::{FINE_SHELLS, fine_shells_table, markdown_table};

/// The paper's grid.
pub const TAUS: [f64; 4] = [1.0, 5.0, 25.0, 125.0];
pub const GS: [f64; 4] = [-0.7, 0.0, 0.4, 0.9];
pub const ALBEDOS: [f64; 2] = [1.0, 0.9];

/// The marginals compared, in report order.
pub const QUANTITIES: [&str; 8] = [
    "n",
    "log_n",
    "cos_theta",
    "alpha",
    "beta",
    "event_radius",
    "event_z",
    "event_wz",
];

/// The joint distributions compared (paper §5.3, design notes): the exit direction's
/// angles against the exit point's cos θ, by their columns in [`QUANTITIES`]. Their KS is
/// the 2-D statistic ([`ks_two_sample_2d`]), their W1 the sliced one
/// ([`sliced_wasserstein1`], [`SLICES`] directions; cos θ, α and β, all cosines in
/// [−1, 1], as they are). Measured where the marginals are (φ = 1).
pub const PAIRS: [(&str, usize, usize); 2] = [("cos_theta_alpha", 2, 3), ("cos_theta_beta", 2, 4)];

/// Directions of the sliced W1: the mean over 64 of them is within ~0.1 % of the
/// integral over all for distributions as smooth as these (checked against 720 on the
/// shipped model's settings: the third digit of the table stays put).
pub const SLICES: usize = 64;

#[derive(Clone, Debug, Serialize)]
pub struct Metric {
    pub quantity: String,
    pub ks: f64,
    pub w1: f64,
}

/// model / simulator − 1 for a mean, with its standard error (delta method). Where the
/// simulator's mean is 0 there is no ratio: `value` and `se` are None (null in
/// metrics.json, which once held 2·10³⁰⁶ and an infinite error there) and the two means
/// tell what was seen.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct RatioError {
    pub value: Option<f64>,
    pub se: Option<f64>,
    /// The model's and the simulator's means of the statistic.
    pub model_mean: f64,
    pub sim_mean: f64,
    /// Whether the simulator's mean is known to 10 %: at large τ the sphere statistic
    /// rests on the rare events within ~1/τ of the boundary, and 10⁴ walks see too few of
    /// them for a ratio to mean anything.
    pub resolved: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct SettingReport {
    pub tau: f64,
    pub g: f64,
    pub albedo: f64,
    pub metrics: Vec<Metric>,
    /// E[Λ(N)], model over simulator.
    pub nee_weight: RatioError,
    /// E[φ^N] at each of [`SURVIVAL_ALBEDOS`], model over simulator.
    pub survival: [RatioError; 2],
    /// E[[`sphere_nee`]], model over simulator.
    pub sphere_nee: RatioError,
    /// E[[`half_space_nee`]] per side ([`SURFACE_SIDES`]), model over simulator.
    pub half_space: [RatioError; 3],
    /// The share of representative events 0.5–10 % of the radius from the sphere's
    /// surface, then within 0.5 % of it ([`SHELLS`]), model over simulator.
    pub shells: [RatioError; 2],
}

/// Albedos of the survival weight E[φ^N] compared at every setting. N does not depend on
/// the setting's φ (only EventGen is conditioned on it), so these come from LengthGen's N
/// at (τ, g). They weigh long walks: at φ = 0.99, τ = 80, the shipped LengthGen's N a few
/// per cent short in the mean gave E[φ^N] 6 % high (a review; the renders' bias stays
/// below 1 % since such paths carry little light), which KS on N and E[Λ(N)] at φ = 0.9
/// (saturated near 9) do not show.
pub const SURVIVAL_ALBEDOS: [f64; 2] = [0.99, 0.95];

/// Distances 1 − |X| of the representative event from the sphere's surface, as
/// half-open bands [lo, hi): where EventGen's fit matters for an image and has been worst
/// (a step that touches the object's surface collects its NEE from events there; the
/// atanh map of feature version 2 over-filled the first and under-filled the second).
pub const SHELLS: [[f64; 2]; 2] = [[0.005, 0.1], [0.0, 0.005]];

/// Mean and standard error of the mean.
fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(2) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// model / simulator − 1 of two samples' means, with the delta method's standard error.
pub fn ratio_error(model: &[f64], sim: &[f64]) -> RatioError {
    // Both samples in units of the simulator's largest value: values of 1e-200 (light
    // through hundreds of free paths) have squared deviations that underflow to 0, which
    // made the standard error 0 or NaN. The ratio does not depend on the unit.
    let unit = sim.iter().fold(0f64, |a, &x| a.max(x.abs()));
    let unit = if unit > 0.0 && unit.is_finite() {
        unit
    } else {
        1.0
    };
    let scaled = |v: &[f64]| v.iter().map(|x| x / unit).collect::<Vec<f64>>();
    let (mm, sm) = mean_se(&scaled(model));
    let (ms, ss) = mean_se(&scaled(sim));
    // A simulator mean of 0 (no event in a thin shell; light that never gets out) says
    // nothing a ratio could use: unresolved, whatever its standard error.
    let ratio = mm / ms;
    let se = ((sm / ms).powi(2) + ((ss / ms) * ratio).powi(2)).sqrt();
    let defined = ms > 0.0 && ratio.is_finite() && se.is_finite();
    RatioError {
        value: defined.then_some(ratio - 1.0),
        se: defined.then_some(se),
        model_mean: mm * unit,
        sim_mean: ms * unit,
        resolved: defined && ss < 0.1 * ms,
    }
}

impl SettingReport {
    pub fn ks(&self, quantity: &str) -> Option<f64> {
        self.metrics
            .iter()
            .find(|m| m.quantity == quantity)
            .map(|m| m.ks)
    }
}

/// Compares the columns; `which` selects quantities by index into [`QUANTITIES`].
pub fn compare(model: &Columns, sim: &Columns, which: &[usize]) -> Vec<Metric> {
    compare_until(model, sim, which, &AtomicBool::new(false)).expect("never stopped")
}

/// As [`compare`], or None once `stop` is set (looked at before each quantity).
fn compare_until(
    model: &Columns,
    sim: &Columns,
    which: &[usize],
    stop: &AtomicBool,
) -> Option<Vec<Metric>> {
    which
        .iter()
        .map(|&q| {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            let (mut a, mut b) = (model.0[q].clone(), sim.0[q].clone());
            let ks = ks_two_sample(&mut a, &mut b);
            let w1 = wasserstein1(&mut a, &mut b);
            Some(Metric {
                quantity: QUANTITIES[q].to_string(),
                ks,
                w1,
            })
        })
        .collect()
}

/// Compares the joint distributions of [`PAIRS`].
pub fn compare_pairs(model: &Columns, sim: &Columns) -> Vec<Metric> {
    compare_pairs_until(model, sim, &AtomicBool::new(false)).expect("never stopped")
}

/// As [`compare_pairs`], or None once `stop` is set (looked at before each pair: the 2-D
/// tests of a million samples take seconds each).
fn compare_pairs_until(model: &Columns, sim: &Columns, stop: &AtomicBool) -> Option<Vec<Metric>> {
    PAIRS
        .iter()
        .map(|&(name, x, y)| {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            let zip = |c: &Columns| -> Vec<(f64, f64)> {
                c.0[x].iter().copied().zip(c.0[y].iter().copied()).collect()
            };
            let (a, b) = (zip(model), zip(sim));
            Some(Metric {
                quantity: name.to_string(),
                ks: ks_two_sample_2d(&a, &b),
                w1: sliced_wasserstein1(&a, &b, SLICES),
            })
        })
        .collect()
}

/// Evaluates one (τ, g, φ) setting. At φ = 1 every quantity is compared; at other
/// albedos only the representative event (the only part that depends on φ).
pub fn evaluate_setting(
    m: &ModelSet,
    tau: f64,
    g: f64,
    albedo: f64,
    samples: usize,
    seed: u64,
) -> SettingReport {
    let sim = simulator_columns(tau, g, albedo, samples, seed);
    let model = model_columns(m, tau, g, albedo, samples, seed);
    compare_setting(&model, &sim, tau, g, albedo)
}

/// The report of one setting from its model and simulator samples.
pub fn compare_setting(
    model: &Columns,
    sim: &Columns,
    tau: f64,
    g: f64,
    albedo: f64,
) -> SettingReport {
    compare_setting_until(model, sim, (tau, g, albedo), &AtomicBool::new(false))
        .expect("never stopped")
}

/// As [`compare_setting`], or None once `stop` is set, looked at between its parts: at a
/// million samples the comparison took ~30 s after the walks, and a Ctrl-C then waited for
/// all of it.
pub fn compare_setting_until(
    model: &Columns,
    sim: &Columns,
    (tau, g, albedo): (f64, f64, f64),
    stop: &AtomicBool,
) -> Option<SettingReport> {
    let go_on = || (!stop.load(Ordering::Relaxed)).then_some(());
    go_on()?;
    let (model_nee, sim_nee) = (
        model.nee_samples(tau, g, albedo),
        sim.nee_samples(tau, g, albedo),
    );
    go_on()?;
    let (model_shells, sim_shells) = (model.shell_samples(), sim.shell_samples());
    let (model_survival, sim_survival) = (model.survival_samples(), sim.survival_samples());
    go_on()?;
    let (model_half, sim_half) = (
        model.half_space_samples(tau, g, albedo),
        sim.half_space_samples(tau, g, albedo),
    );
    go_on()?;
    let which: Vec<usize> = if albedo == 1.0 {
        (0..QUANTITIES.len()).collect()
    } else {
        vec![5, 6, 7]
    };
    let mut metrics = compare_until(model, sim, &which, stop)?;
    if albedo == 1.0 {
        metrics.extend(compare_pairs_until(model, sim, stop)?);
    }
    go_on()?;
    Some(SettingReport {
        tau,
        g,
        albedo,
        metrics,
        nee_weight: ratio_error(&model_nee[0], &sim_nee[0]),
        survival: [0, 1].map(|k| ratio_error(&model_survival[k], &sim_survival[k])),
        sphere_nee: ratio_error(&model_nee[1], &sim_nee[1]),
        half_space: [0, 1, 2].map(|k| ratio_error(&model_half[k], &sim_half[k])),
        shells: [0, 1].map(|k| ratio_error(&model_shells[k], &sim_shells[k])),
    })
}

/// The full grid: 16 settings at φ = 1 plus the 16 EventGen settings at φ = 0.9.
/// `progress(done, total)` is told after each setting; where it returns false, or `stop`
/// is set (checked within a setting's walks too), the grid stops and the settings done so
/// far are returned (a stop request). `seen` gets
/// each setting's (τ, g, φ) and its model and simulator samples (for plots, which then
/// need not draw them again).
pub fn evaluate_grid(
    m: &ModelSet,
    samples: usize,
    seed: u64,
    stop: &AtomicBool,
    mut progress: impl FnMut(usize, usize) -> bool,
    mut seen: impl FnMut((f64, f64, f64), &Columns, &Columns),
) -> Vec<SettingReport> {
    let settings: Vec<(f64, f64, f64)> = ALBEDOS
        .iter()
        .flat_map(|&a| {
            TAUS.iter()
                .flat_map(move |&t| GS.iter().map(move |&g| (t, g, a)))
        })
        .collect();
    let total = settings.len();
    let mut reports = Vec::with_capacity(total);
    for (i, &(t, g, a)) in settings.iter().enumerate() {
        let seed = seed.wrapping_add(i as u64);
        let Some(sim) = simulator_columns_until((t, g, a), samples, seed, stop) else {
            break;
        };
        let Some(model) = model_columns_until(m, (t, g, a), samples, seed, stop) else {
            break;
        };
        let Some(report) = compare_setting_until(&model, &sim, (t, g, a), stop) else {
            break;
        };
        reports.push(report);
        seen((t, g, a), &model, &sim);
        if !progress(i + 1, total) {
            break;
        }
    }
    reports
}

/// Largest KS of `quantity` over the reports that have it; None where none has (at φ < 1
/// only the event marginals are measured), rather than a perfect-looking 0.
pub fn max_ks(reports: &[SettingReport], quantity: &str) -> Option<f64> {
    reports
        .iter()
        .filter_map(|r| r.ks(quantity))
        .reduce(f64::max)
}
