//! The representative event: for a path of N events, event k is chosen with
//! probability φ^k / Λ(N).

use scatter_sim::WalkRng;
use scatter_sim::reservoir::Reservoir;
use scatter_sim::stats::{chi_square, chi_square_p_value};

/// Runs the reservoir over a fixed path of `n` events `trials` times; returns the
/// frequency of each chosen index (index 0 unused).
fn choose_counts(n: u64, albedo: f64, trials: u64, seed: u64) -> Vec<u64> {
    let mut counts = vec![0u64; n as usize + 1];
    let mut rng = WalkRng::from_seed(seed);
    for _ in 0..trials {
        let mut r = Reservoir::new(albedo, &mut rng);
        for k in 2..=n {
            r.offer(k, &mut rng);
        }
        counts[r.chosen() as usize] += 1;
    }
    counts
}

/// Chi-square of the chosen indices against φ^k/Λ(N), pooling indices whose expected
/// count is below 20. Threshold p > 1e-4 per case: a correct reservoir fails one of the
/// five statistical cases (N = 1 is checked exactly) with probability 5e-4; an off-by-one in the skip formula (choosing k+1
/// instead of k) or a wrong weight moves thousands of counts and gives p ≈ 0.
#[test]
fn chosen_index_follows_phi_k_over_lambda() {
    let cases = [
        (1u64, 0.5),
        (10, 0.8),
        (50, 1.0),
        (30, 0.95),
        (200, 1.0 - 1e-6),
        (40, 0.3),
    ];
    for (i, (n, albedo)) in cases.into_iter().enumerate() {
        let trials = 300_000u64;
        let counts = choose_counts(n, albedo, trials, 40 + i as u64);
        let weights: Vec<f64> = (1..=n).map(|k| albedo.powi(k as i32)).collect();
        let lambda: f64 = weights.iter().sum();
        let expected: Vec<f64> = weights.iter().map(|w| trials as f64 * w / lambda).collect();
        let observed = &counts[1..];
        if n == 1 {
            assert_eq!(observed, [trials]);
            continue;
        }
        // Pool the sparse tail (strong absorption makes late events rare).
        let (mut o, mut e) = (vec![], vec![]);
        let (mut ao, mut ae) = (0u64, 0.0);
        for (&ob, &ex) in observed.iter().zip(&expected) {
            ao += ob;
            ae += ex;
            if ae >= 20.0 {
                o.push(ao);
                e.push(ae);
                (ao, ae) = (0, 0.0);
            }
        }
        if let (Some(lo), Some(le)) = (o.last_mut(), e.last_mut()) {
            *lo += ao;
            *le += ae;
        }
        let stat = chi_square(&o, &e);
        let p = chi_square_p_value(stat, o.len() - 1);
        assert!(
            p > 1e-4,
            "N = {n}, phi = {albedo}: chi2 = {stat:.1}, dof {}, p = {p:.2e}",
            o.len() - 1
        );
    }
}

/// φ = 0: every weight after the first is zero, so the centre event is always chosen.
#[test]
fn zero_albedo_keeps_the_centre_event() {
    let counts = choose_counts(20, 0.0, 1000, 3);
    assert_eq!(counts[1], 1000);
}
