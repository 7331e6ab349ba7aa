//! The shipped model stays within the KS bounds documented in docs/TRAINING.md at three
//! settings of the paper's grid, so a regression in the sampling code (transforms,
//! frames, the exact branches) is caught without retraining.

use std::path::Path;

use cvae::ModelSet;
use cvae::eval::evaluate_setting;

#[test]
fn shipped_model_quick_eval() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.stcvae");
    let m = ModelSet::load(&path).unwrap();
    // 10,000 vs 10,000 samples, as `stcvae eval`. Under the null the KS statistic
    // exceeds 0.027 with probability < 0.2 %, so a bound of 0.05 fails only on a real
    // misfit; the shipped model's values at these settings are in docs/TRAINING.md. The
    // event marginals fit less well: at this seed their KS is at most 0.051 (event radius,
    // τ = 25; 2026-11-27), so their bound is 0.07, which an EventGen sampling regression
    // that doubled the misfit would exceed (it was 0.10, twice the measured values).
    for (tau, g, albedo) in [(5.0, 0.4, 1.0), (25.0, 0.0, 1.0), (125.0, -0.7, 1.0)] {
        let r = evaluate_setting(&m, tau, g, albedo, 10_000, 1);
        for q in ["n", "cos_theta", "alpha", "beta"] {
            let ks = r.ks(q).unwrap();
            assert!(ks <= 0.05, "τ = {tau}, g = {g}: KS({q}) = {ks:.3} > 0.05");
        }
        for q in ["event_radius", "event_z", "event_wz"] {
            let ks = r.ks(q).unwrap();
            assert!(ks <= 0.07, "τ = {tau}, g = {g}: KS({q}) = {ks:.3} > 0.07");
        }
    }
}
