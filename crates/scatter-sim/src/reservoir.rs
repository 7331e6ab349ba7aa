//! Choice of the representative scattering event for next-event estimation (design §2).
//!
//! Among the events k = 1..N of a walk, event k is chosen with probability φ^k / Λ(N),
//! Λ(N) = Σ_{i≤N} φ^i. A weighted reservoir of size one does this in one pass, replacing
//! the choice at event k with probability φ^k / Λ(k). Drawing that coin at every event
//! would cost a random number per event (walks reach 10⁵ events), so instead we draw,
//! after each replacement at k, the index of the *next* replacement directly: the
//! chance that none of k+1..m replaces is Π Λ(j−1)/Λ(j) = Λ(k)/Λ(m), hence with
//! u ~ U(0, 1] the next replacement is the first m with Λ(m) > Λ(k)/u. Same
//! distribution, one random number per replacement (O(log N) of them when φ = 1).

use crate::rng::WalkRng;

/// Sentinel for "never replaced again".
const NEVER: u64 = u64::MAX;

#[derive(Clone, Debug)]
pub struct Reservoir {
    ln_phi: f64,
    chosen: u64,
    next: u64,
}

impl Reservoir {
    /// Starts with event 1 chosen (its probability Λ(1)/Λ(1) = 1).
    pub fn new(albedo: f64, rng: &mut WalkRng) -> Self {
        let mut r = Self {
            ln_phi: albedo.ln(),
            chosen: 1,
            next: NEVER,
        };
        r.next = r.next_after(1, rng);
        r
    }

    /// The index of the event chosen so far.
    #[inline]
    pub fn chosen(&self) -> u64 {
        self.chosen
    }

    /// Offers event `k` (called with k = 2, 3, … in order); true if it becomes the choice.
    #[inline]
    pub fn offer(&mut self, k: u64, rng: &mut WalkRng) -> bool {
        if k == self.next {
            self.chosen = k;
            self.next = self.next_after(k, rng);
            true
        } else {
            false
        }
    }

    /// The first m > k with Λ(m) > Λ(k)/u.
    fn next_after(&self, k: u64, rng: &mut WalkRng) -> u64 {
        let u = rng.uniform_open0();
        let m = if self.ln_phi == 0.0 {
            // φ = 1: Λ(m) = m.
            (k as f64 / u).floor()
        } else {
            // Λ(m) > Λ(k)/u  ⇔  φ^m < R = 1 − (1 − φ^k)/u; written with expm1/ln1p so that
            // φ within 1e-6 of 1 keeps its precision.
            let one_minus_phik = -(k as f64 * self.ln_phi).exp_m1();
            let x = -one_minus_phik / u;
            if x <= -1.0 {
                return NEVER;
            }
            // m > ln R / ln φ (both logs ≤ 0).
            (x.ln_1p() / self.ln_phi).floor()
        };
        if !(m < 9.0e18) {
            return NEVER;
        }
        (m as u64 + 1).max(k + 1)
    }
}
