//! Markdown tables of an evaluation.

use super::{
    Columns, PAIRS, QUANTITIES, SHELLS, SURFACE_SIDES, SURVIVAL_ALBEDOS, SettingReport,
    edge_distance,
};

/// Thin bands of 1 − |X| for [`fine_shells_table`]: where the version-2 EventGens went
/// from over- to under-filling.
pub const FINE_SHELLS: [[f64; 2]; 7] = [
    [0.05, 0.1],
    [0.02, 0.05],
    [0.01, 0.02],
    [0.005, 0.01],
    [0.002, 0.005],
    [0.001, 0.002],
    [0.0, 0.001],
];

/// A Markdown table of how many representative events fall in each band of
/// [`FINE_SHELLS`], the simulator's count and the model's over it.
pub fn fine_shells_table(model: &Columns, sim: &Columns, tau: f64, g: f64, albedo: f64) -> String {
    let count = |c: &Columns, [lo, hi]: [f64; 2]| {
        c.1.iter()
            .filter(|&&(_, _, x, _)| {
                let d = edge_distance(x);
                lo <= d && d < hi
            })
            .count()
    };
    let mut s = format!(
        "\nEvents by distance 1 − |X| from the sphere's surface, τ = {}, g = {}, φ = {} \
         (simulator's count; model / simulator):\n\n|",
        scatter_sim::ranges::num(tau),
        scatter_sim::ranges::num(g),
        scatter_sim::ranges::num(albedo)
    );
    for [lo, hi] in FINE_SHELLS {
        s += &format!(" {lo}–{hi} |");
    }
    s += "\n|";
    s += &"---|".repeat(FINE_SHELLS.len());
    s += "\n|";
    for band in FINE_SHELLS {
        let (m, n) = (count(model, band), count(sim, band));
        s += &if n > 0 {
            format!(" {n}: {:.2} |", m as f64 / n as f64)
        } else {
            format!(" 0: {m} model events |")
        };
    }
    s + "\n"
}

/// The Markdown table of a grid evaluation.
pub fn markdown_table(reports: &[SettingReport]) -> String {
    let mut s = String::from("| τ | g | φ |");
    for q in QUANTITIES {
        s += &format!(" {q} KS / W1 |");
    }
    for (q, ..) in PAIRS {
        s += &format!(" {q} 2-D KS / sliced W1 |");
    }
    s += " E[Λ(N)] model/sim − 1 |";
    for a in SURVIVAL_ALBEDOS {
        s += &format!(" E[{a}^N] model/sim − 1 |");
    }
    s += " sphere NEE model/sim − 1 |";
    for side in SURFACE_SIDES {
        s += &format!(" half-space NEE, surface {side}, model/sim − 1 |");
    }
    for [lo, hi] in SHELLS {
        s += &format!(
            " events {}–{} % from the edge, model/sim − 1 |",
            100.0 * lo,
            100.0 * hi
        );
    }
    s += "\n|---|---|---|";
    s += &"---|".repeat(QUANTITIES.len() + PAIRS.len());
    s += &"---|".repeat(2 + SURVIVAL_ALBEDOS.len() + SURFACE_SIDES.len() + SHELLS.len());
    s += "\n";
    let num = scatter_sim::ranges::num::<f64>;
    for r in reports {
        s += &format!("| {} | {} | {} |", num(r.tau), num(r.g), num(r.albedo));
        for q in QUANTITIES.into_iter().chain(PAIRS.map(|p| p.0)) {
            match r.metrics.iter().find(|m| m.quantity == q) {
                Some(m) => s += &format!(" {:.3} / {:.3} |", m.ks, m.w1),
                None => s += " – |",
            }
        }
        let sides = r.half_space;
        for r in [r.nee_weight]
            .into_iter()
            .chain(r.survival)
            .chain([r.sphere_nee])
            .chain(sides)
            .chain(r.shells)
        {
            if let (true, Some(value), Some(se)) = (r.resolved, r.value, r.se) {
                s += &format!(" {:+.1} % ± {:.1} % |", 100.0 * value, 100.0 * se);
            } else {
                s += " too rare to resolve |";
            }
        }
        s += "\n";
    }
    s
}
