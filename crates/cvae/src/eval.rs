//! Distribution fidelity of the models against fresh simulator walks (paper §5.3).
//!
//! For each setting, `samples` model walks and `samples` simulator walks are compared
//! marginal by marginal with the two-sample Kolmogorov–Smirnov statistic and the
//! Wasserstein-1 distance. KS is invariant under monotone maps, so KS(N) = KS(log N);
//! W1 is reported for both.

use rayon::prelude::*;
use serde::Serialize;

use glam::DVec3;
use scatter_sim::frame::CanonicalExit;
use scatter_sim::stats::{ks_two_sample, wasserstein1};
use scatter_sim::{WalkRng, simulate_walk};

use crate::model_file::ModelSet;

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

#[derive(Clone, Debug, Serialize)]
pub struct Metric {
    pub quantity: String,
    pub ks: f64,
    pub w1: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct SettingReport {
    pub tau: f64,
    pub g: f64,
    pub albedo: f64,
    pub metrics: Vec<Metric>,
}

impl SettingReport {
    pub fn ks(&self, quantity: &str) -> Option<f64> {
        self.metrics
            .iter()
            .find(|m| m.quantity == quantity)
            .map(|m| m.ks)
    }
}

/// Samples of every quantity for one setting, one column per entry of [`QUANTITIES`].
#[derive(Clone, Debug, Default)]
pub struct Columns(pub [Vec<f64>; 8]);

impl Columns {
    fn from_walks(walks: Vec<(u64, CanonicalExit, DVec3, DVec3)>) -> Self {
        let mut c = Columns::default();
        for (n, e, x, w) in walks {
            c.push(n, e.cos_theta, e.alpha, e.beta, x, w);
        }
        c
    }

    fn push(&mut self, n: u64, cos: f64, alpha: f64, beta: f64, x: glam::DVec3, w: glam::DVec3) {
        let v = [
            n as f64,
            (n as f64).ln(),
            cos,
            alpha,
            beta,
            x.length(),
            x.z,
            w.z,
        ];
        for (c, v) in self.0.iter_mut().zip(v) {
            c.push(v);
        }
    }
}

/// `count` simulator walks at fixed conditions (stream `seed`, one per walk).
pub fn simulator_columns(tau: f64, g: f64, albedo: f64, count: usize, seed: u64) -> Columns {
    let walks: Vec<_> = (0..count as u64)
        .into_par_iter()
        .map(|i| {
            let mut rng = WalkRng::for_walk(seed, i);
            simulate_walk(tau, g, albedo, &mut rng).canonical()
        })
        .map(|w| (w.n, w.exit, w.event_pos, w.event_dir))
        .collect();
    Columns::from_walks(walks)
}

/// `count` model walks at fixed conditions.
pub fn model_columns(
    m: &ModelSet,
    tau: f64,
    g: f64,
    albedo: f64,
    count: usize,
    seed: u64,
) -> Columns {
    let walks: Vec<_> = (0..count as u64)
        .into_par_iter()
        .map(|i| {
            let mut rng = WalkRng::for_walk(seed ^ 0x6d6f_64656c, i);
            m.sample_walk(tau, g, albedo, true, &mut rng)
        })
        .map(|w| (w.n, w.exit, w.event_pos, w.event_dir))
        .collect();
    Columns::from_walks(walks)
}

/// Compares the columns; `which` selects quantities by index into [`QUANTITIES`].
pub fn compare(model: &Columns, sim: &Columns, which: &[usize]) -> Vec<Metric> {
    which
        .iter()
        .map(|&q| {
            let (mut a, mut b) = (model.0[q].clone(), sim.0[q].clone());
            let ks = ks_two_sample(&mut a, &mut b);
            let w1 = wasserstein1(&mut a, &mut b);
            Metric {
                quantity: QUANTITIES[q].to_string(),
                ks,
                w1,
            }
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
    let which: Vec<usize> = if albedo == 1.0 {
        (0..QUANTITIES.len()).collect()
    } else {
        vec![5, 6, 7]
    };
    SettingReport {
        tau,
        g,
        albedo,
        metrics: compare(&model, &sim, &which),
    }
}

/// The full grid: 16 settings at φ = 1 plus the 16 EventGen settings at φ = 0.9.
pub fn evaluate_grid(
    m: &ModelSet,
    samples: usize,
    seed: u64,
    mut progress: impl FnMut(usize, usize),
) -> Vec<SettingReport> {
    let settings: Vec<(f64, f64, f64)> = ALBEDOS
        .iter()
        .flat_map(|&a| {
            TAUS.iter()
                .flat_map(move |&t| GS.iter().map(move |&g| (t, g, a)))
        })
        .collect();
    let total = settings.len();
    settings
        .iter()
        .enumerate()
        .map(|(i, &(t, g, a))| {
            let r = evaluate_setting(m, t, g, a, samples, seed + i as u64);
            progress(i + 1, total);
            r
        })
        .collect()
}

/// Largest KS of `quantity` over the reports that have it.
pub fn max_ks(reports: &[SettingReport], quantity: &str) -> f64 {
    reports
        .iter()
        .filter_map(|r| r.ks(quantity))
        .fold(0.0, f64::max)
}

/// The Markdown table of a grid evaluation.
pub fn markdown_table(reports: &[SettingReport]) -> String {
    let mut s = String::from("| τ | g | φ |");
    for q in QUANTITIES {
        s += &format!(" {q} KS / W1 |");
    }
    s += "\n|---|---|---|";
    for _ in QUANTITIES {
        s += "---|";
    }
    s += "\n";
    for r in reports {
        s += &format!("| {} | {} | {} |", r.tau, r.g, r.albedo);
        for q in QUANTITIES {
            match r.metrics.iter().find(|m| m.quantity == q) {
                Some(m) => s += &format!(" {:.3} / {:.3} |", m.ks, m.w1),
                None => s += " – |",
            }
        }
        s += "\n";
    }
    s
}
