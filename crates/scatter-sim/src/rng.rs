//! Per-walk random streams.
//!
//! Every walk draws from its own generator seeded from (dataset seed, walk index), so a
//! walk's outcome does not depend on which thread ran it or which shard it fell in: this
//! is what makes generation byte-identical across thread counts and shardings.

use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// SplitMix64 finaliser: a bijective 64-bit mix, used to spread (seed, index) over the
/// 256-bit xoshiro state.
#[inline]
pub fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The random stream of one walk (xoshiro256++: fast, 2^256 period, good equidistribution).
/// Serialisable so that a training checkpoint can carry its stream's position: a resumed
/// run then draws the batches the uninterrupted run would have drawn.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WalkRng(Xoshiro256PlusPlus);

impl WalkRng {
    /// The stream of walk `index` of the dataset with seed `seed`.
    pub fn for_walk(seed: u64, index: u64) -> Self {
        let a = splitmix64(seed ^ 0x5354_4356_4145_0001);
        let b = splitmix64(index ^ a.rotate_left(17));
        let c = splitmix64(a ^ b);
        let d = splitmix64(c.wrapping_add(b));
        let mut bytes = [0u8; 32];
        for (chunk, w) in bytes.chunks_exact_mut(8).zip([a, b, c, d]) {
            chunk.copy_from_slice(&w.to_le_bytes());
        }
        // All-zero state is impossible in practice (four independent 64-bit hashes), but
        // xoshiro forbids it, so guard anyway.
        if bytes.iter().all(|&x| x == 0) {
            bytes[0] = 1;
        }
        Self(Xoshiro256PlusPlus::from_seed(bytes))
    }

    /// A stream for tests and tools that need one generator, not one per walk.
    pub fn from_seed(seed: u64) -> Self {
        Self::for_walk(seed, u64::MAX)
    }

    /// Whether this is xoshiro's forbidden all-zero state, which it never leaves (every
    /// draw 0): no stream made here is in it, but one read from a file may be. Four zero
    /// draws in a row from any other state have probability 2^-256.
    pub fn is_degenerate(&self) -> bool {
        let mut r = self.clone();
        (0..4).all(|_| r.next_u64() == 0)
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// A standard normal variate in f32 (rand_distr's ziggurat: one 64-bit draw and a
    /// table lookup almost always, no logarithm): the models' latent noise.
    #[inline]
    pub fn standard_normal(&mut self) -> f32 {
        rand_distr::Distribution::<f32>::sample(&rand_distr::StandardNormal, &mut self.0)
    }

    /// Uniform in [0, 1) with 53 random bits.
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in (0, 1]: safe to take the logarithm of.
    #[inline]
    pub fn uniform_open0(&mut self) -> f64 {
        ((self.next_u64() >> 11) + 1) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A uniformly distributed unit vector in the plane, as (cos ψ, sin ψ), without
    /// trigonometry (von Neumann's rejection method: ~1.27 tries on average).
    #[inline]
    pub fn unit_circle(&mut self) -> (f64, f64) {
        loop {
            let a = 2.0 * self.uniform() - 1.0;
            let b = 2.0 * self.uniform() - 1.0;
            let r2 = a * a + b * b;
            if r2 <= 1.0 && r2 > 1e-12 {
                return ((a * a - b * b) / r2, 2.0 * a * b / r2);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{WalkRng, splitmix64};

    /// `uniform_open0` is `uniform`'s draw one step of 2⁻⁵³ up, so in (0, 1] and never 0,
    /// which −ln takes: exactly, since k·2⁻⁵³ + 2⁻⁵³ = (k + 1)·2⁻⁵³ with k + 1 ≤ 2⁵³. And
    /// `splitmix64` is SplitMix64: its first three outputs from state 0, as the reference
    /// implementation gives them (prng.di.unimi.it/splitmix64.c).
    #[test]
    fn open0_is_uniform_one_step_up_and_splitmix_is_the_reference() {
        let step = 1.0 / (1u64 << 53) as f64;
        let mut a = WalkRng::from_seed(3);
        let mut b = a.clone();
        for _ in 0..1000 {
            assert_eq!(a.uniform_open0(), b.uniform() + step);
        }
        const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;
        assert_eq!(splitmix64(0), 0xE220_A839_7B1D_CDAF);
        assert_eq!(splitmix64(GAMMA), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(splitmix64(GAMMA.wrapping_mul(2)), 0x06C4_5D18_8009_454F);
    }
}
