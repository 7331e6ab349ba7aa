//! Exact facts of the unit-sphere walk (design §2) and the invariants of its canonical
//! record.

use glam::DVec3;
use rayon::prelude::*;
use scatter_sim::frame::{AzimuthRotation, exit_frame, from_canonical, to_canonical};
use scatter_sim::phase::hg_cos_cdf;
use scatter_sim::stats::{ks_one_sample, ks_p_value, mean_and_sem, proportion_z};
use scatter_sim::{Walk, WalkFrame, WalkRng, simulate_walk};

/// Walks `first..first+n` of a fixed-condition run, in parallel (each walk has its own
/// stream, so the result does not depend on the thread count).
fn walks(tau: f64, g: f64, albedo: f64, seed: u64, n: u64) -> Vec<Walk> {
    (0..n)
        .into_par_iter()
        .map(|i| {
            let mut rng = WalkRng::for_walk(seed, i);
            simulate_walk(tau, g, albedo, &mut rng)
        })
        .collect()
}

/// P(N = 1) = e^{−τ}: the first flight from the centre has optical length Exp(1) and
/// the sphere's optical radius is τ. With 200,000 walks the observed fraction has a
/// standard error of ≤ 0.0011; |z| < 4 fails a correct simulator with probability 6e-5
/// per τ, while an error in the flight length (e.g. rate 1/τ, or a missed boundary)
/// shifts the fraction by ≥ 0.01, i.e. z ≥ 9.
#[test]
fn single_scattering_probability_is_exp_minus_tau() {
    for (i, tau) in [0.5f64, 2.0, 5.0].into_iter().enumerate() {
        let n = 200_000;
        let hits = walks(tau, 0.3, 1.0, 10 + i as u64, n)
            .iter()
            .filter(|w| w.n == 1)
            .count() as u64;
        let z = proportion_z(hits, n, (-tau).exp());
        assert!(
            z.abs() < 4.0,
            "tau = {tau}: {hits}/{n} single-scattering walks, z = {z:.2}"
        );
    }
}

/// Given N = 1 the photon left the centre in the HG direction: the raw exit point equals
/// the exit direction (x = ω, up to the rounding of the exit's normalisation) and cos θ
/// follows HG(g). KS against the analytic CDF at the 0.1% level on the ~60,650 walks per g
/// (100,000·e^(−0.5)) that scatter once.
#[test]
fn single_scattering_exit_is_the_hg_direction() {
    for (i, g) in [-0.7f64, 0.0, 0.6].into_iter().enumerate() {
        let ws = walks(0.5, g, 1.0, 20 + i as u64, 100_000);
        let mut cos = Vec::new();
        for w in ws.iter().filter(|w| w.n == 1) {
            // On the walk itself, not its canonical record: canonical() sets α = β = 0
            // for N = 1 by construction, so only x = ω shows the walk went straight out.
            assert!(
                (w.exit_pos - w.exit_dir).length() <= 1e-9,
                "N = 1 exit point {:?} differs from its direction {:?}",
                w.exit_pos,
                w.exit_dir
            );
            let c = w.canonical();
            assert_eq!(
                c.event_pos,
                DVec3::ZERO,
                "N = 1: the representative event is the centre"
            );
            cos.push(c.exit.cos_theta);
        }
        // A sanity floor, not the test (P(N = 1) is checked above): 55,000 lies 36
        // standard deviations (√(n·p·(1 − p)) ≈ 154) below the expected count.
        assert!(
            cos.len() > 55_000,
            "expected ~60,650 single-scattering walks, got {}",
            cos.len()
        );
        let n = cos.len() as f64;
        let d = ks_one_sample(&mut cos, |m| hg_cos_cdf(g, m));
        let p = ks_p_value(d, n);
        assert!(p > 1e-3, "g = {g}: KS D = {d:.4}, p = {p:.2e}");
    }
}

/// τ → 0: the medium is transparent, every walk leaves after the centre event.
#[test]
fn transparent_sphere_has_only_single_scattering() {
    assert!(walks(1e-9, 0.5, 1.0, 3, 10_000).iter().all(|w| w.n == 1));
    assert!(walks(0.0, -0.2, 1.0, 3, 1_000).iter().all(|w| w.n == 1));
}

/// Invariants of every canonical record and the round trip canonical → world.
#[test]
fn canonical_frame_invariants_and_round_trip() {
    for (i, &(tau, g, albedo)) in [
        (0.3, 0.0, 1.0),
        (3.0, 0.8, 0.9),
        (20.0, -0.5, 0.999),
        (60.0, 0.95, 1.0),
    ]
    .iter()
    .enumerate()
    {
        for w in walks(tau, g, albedo, 30 + i as u64, 3000) {
            assert!((w.exit_pos.length() - 1.0).abs() < 1e-12);
            assert!(
                w.exit_dir.dot(w.exit_pos) >= 0.0,
                "exit direction points inward"
            );
            let c = w.canonical();
            let (e_n, e_b, e_t) = exit_frame(c.exit.cos_theta);
            // The aligning rotation takes the raw exit point onto the y–z half-plane with
            // y ≥ 0, where e_n(cos θ) of the canonical record puts it (y compared squared:
            // √(1 − cos²θ) against √(x² + y²) differs by up to √(1e-12) near the poles).
            let aligned = AzimuthRotation::aligning(w.exit_pos).apply(w.exit_pos);
            assert!(
                aligned.x.abs() < 1e-12
                    && aligned.y >= 0.0
                    && (aligned.z - e_n.z).abs() < 1e-12
                    && (aligned.y.powi(2) - e_n.y.powi(2)).abs() < 1e-11,
                "aligned exit {aligned} vs e_n {e_n}"
            );
            assert!(c.exit.alpha.powi(2) + c.exit.beta.powi(2) <= 1.0 + 1e-12);
            assert!(c.event_pos.length() <= 1.0 + 1e-12);
            assert!((c.event_dir.length() - 1.0).abs() < 1e-12);
            // e_b = normalize(ω_in × x) away from the poles.
            if e_n.y > 1e-6 {
                let eb = DVec3::Z.cross(e_n).normalize();
                assert!((eb - e_b).length() < 1e-12 && (e_b.cross(e_n) - e_t).length() < 1e-12);
            }
            // Round trip: rebuild (x, ω) from (cos θ, α, β) and undo the azimuth.
            let (xc, wc) = from_canonical(c.exit);
            let rot = AzimuthRotation::aligning(w.exit_pos).inverse();
            assert!((rot.apply(xc) - w.exit_pos).length() < 1e-9, "x round trip");
            assert!(
                (rot.apply(wc) - w.exit_dir).length() < 1e-9,
                "omega round trip"
            );
            if w.n == 1 {
                // canonical() sets α = β = 0 exactly; the raw transform leaves rounding.
                let (again, _) = to_canonical(w.exit_pos, w.exit_dir);
                assert_eq!(again.cos_theta, c.exit.cos_theta);
                assert!(again.alpha.abs() <= 1e-9 && again.beta.abs() <= 1e-9);
                assert_eq!((c.exit.alpha, c.exit.beta), (0.0, 0.0));
            }
        }
    }
}

/// WalkFrame: canonical +z goes to ω_in, the basis is orthonormal and right-handed, and
/// to_canonical inverts to_world.
#[test]
fn walk_frame_maps_canonical_to_world() {
    let mut rng = WalkRng::from_seed(5);
    for _ in 0..1000 {
        let w_in = DVec3::new(
            rng.uniform() - 0.5,
            rng.uniform() - 0.5,
            rng.uniform() - 0.5,
        )
        .normalize();
        let f = WalkFrame::new(w_in, rng.unit_circle());
        assert!((f.to_world(DVec3::Z) - w_in).length() < 1e-12);
        assert!((f.basis.determinant() - 1.0).abs() < 1e-12);
        let v = DVec3::new(0.2, -0.7, 0.4);
        assert!((f.to_canonical(f.to_world(v)) - v).length() < 1e-12);
    }
}

/// Model outputs out of range are repaired, never turned into NaN.
#[test]
fn from_canonical_repairs_out_of_range_values() {
    use scatter_sim::CanonicalExit;
    for exit in [
        CanonicalExit {
            cos_theta: 1.5,
            alpha: 0.9,
            beta: 0.9,
        },
        CanonicalExit {
            cos_theta: f64::NAN,
            alpha: f64::INFINITY,
            beta: 0.0,
        },
        CanonicalExit {
            cos_theta: -1.0,
            alpha: 0.0,
            beta: -3.0,
        },
    ] {
        let (x, w) = from_canonical(exit);
        assert!(x.is_finite() && w.is_finite());
        assert!((x.length() - 1.0).abs() < 1e-12 && (w.length() - 1.0).abs() < 1e-12);
        assert!(w.dot(x) >= -1e-12);
    }
}

/// Diffusion limit: mean N ≈ (1 − g)(τ + z_b)²/2 with z_b ≈ 0.71/(1 − g) the
/// extrapolated-boundary length of radiative transfer (Milne problem), so the ratio
/// mean N(100)/mean N(50) at g = 0 is (100.71/50.71)² = 3.944 from this formula; an
/// independent simulation gave 3.967 ± 0.025. The ratio checks the τ² growth: mean N
/// growing like τ (a walk without diffusion) gives ~2, like τ³ ~8, far outside
/// [3.85, 4.05] (−2.4 % / +2.7 % around 3.944). It is blind to an error that scales every
/// flight alike (the ratio stays 4); the absolute 2% band below catches those, since mean
/// N goes with the flight rate squared (a rate 5% off moves it ~10%). With 20,000 walks
/// per τ each mean has a relative standard error of ≈ 0.45%, the ratio ≈ 0.65% (±0.026).
/// The 2% band on the formula covers its O(1/τ²) error plus 3 standard errors.
#[test]
fn mean_events_grow_like_tau_squared() {
    let mean_n = |tau: f64, g: f64, seed: u64| {
        let ns: Vec<f64> = walks(tau, g, 1.0, seed, 20_000)
            .iter()
            .map(|w| w.n as f64)
            .collect();
        mean_and_sem(&ns)
    };
    let (m50, s50) = mean_n(50.0, 0.0, 61);
    let (m100, s100) = mean_n(100.0, 0.0, 62);
    let ratio = m100 / m50;
    assert!(
        (3.85..=4.05).contains(&ratio),
        "mean N(100)/mean N(50) = {ratio:.3} ({m100:.0}±{s100:.0} / {m50:.0}±{s50:.0})"
    );
    for (tau, g, seed) in [(50.0, 0.0, 61), (100.0, 0.0, 62), (60.0, 0.5, 63)] {
        let (m, _) = if tau == 50.0 {
            (m50, s50)
        } else if tau == 100.0 {
            (m100, s100)
        } else {
            mean_n(tau, g, seed)
        };
        let zb = 0.71 / (1.0 - g);
        let predicted = (1.0 - g) * (tau + zb).powi(2) / 2.0;
        assert!(
            (m / predicted - 1.0).abs() < 0.02,
            "tau = {tau}, g = {g}: mean N = {m:.1}, diffusion {predicted:.1}"
        );
    }
}
