//! Branch-free f32 `exp`/`ln` for the decoders' softplus and the latent normals.
//!
//! libm's `expf`/`logf` are calls the compiler cannot vectorise; they were a quarter of
//! the ST-CVAE renderer's time (`perf`, docs/BENCHMARKS.md). These are written only with
//! arithmetic and bit casts, so a loop over a layer's activations compiles to SIMD even
//! on baseline x86-64 (SSE2). Relative error ≲ 2e-7 — an f32 ulp or two — which the
//! tests check against f64.

/// 1.5·2^23: adding and subtracting it rounds an f32 of magnitude < 2^22 to the nearest
/// integer without SSE4.1's `roundps`.
const ROUND_MAGIC: f32 = 12_582_912.0;
/// The bits of ROUND_MAGIC (exponent 23, mantissa 0.5).
const ROUND_MAGIC_BITS: u32 = 0x4b40_0000;

/// ln 2 = LN2_HI + LN2_LO, the high part with its low 9 mantissa bits zero (so k·LN2_HI
/// is exact for |k| < 2^9, all of f32's exponent range), given by their bits:
/// 0.693145751953125 and 1.4286068e-6.
const LN2_HI: f32 = f32::from_bits(0x3f31_7200);
const LN2_LO: f32 = f32::from_bits(0x35bf_be8e);

/// e^x for x ∈ [−87, 87] (callers clamp; below −80 the result nears the subnormal
/// range and keeps fewer bits): 2^k · e^y with k = round(x·log₂e) and
/// |y| ≤ ln2/2, where a degree-7 Taylor polynomial is exact to ~5e-9.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let t = x * std::f32::consts::LOG2_E;
    let rounded = t + ROUND_MAGIC;
    let k = rounded - ROUND_MAGIC;
    // Cody–Waite: ln 2 in two parts, the first exact in few bits, so y keeps the
    // precision of x instead of the ~|x|·6e-8 error of a one-step reduction.
    let y = (x - k * LN2_HI) - k * LN2_LO;
    let p = 1.0
        + y * (1.0
            + y * (0.5
                + y * (1.0 / 6.0
                    + y * (1.0 / 24.0
                        + y * (1.0 / 120.0 + y * (1.0 / 720.0 + y * (1.0 / 5040.0)))))));
    // 2^k from the bits of `rounded` = 1.5·2^23 + k, whose mantissa holds k (two's
    // complement in the low bits): integer adds and shifts only. `k as i32` would be a
    // saturating conversion, which compiles to per-lane compares and keeps the layer's
    // softplus loop from vectorising.
    let scale = f32::from_bits(rounded.to_bits().wrapping_sub(ROUND_MAGIC_BITS - 127) << 23);
    p * scale
}

/// ln(1 + u) for u ∈ [0, 1] as 2·atanh(s), s = u/(2 + u) ≤ 1/3: the odd series to
/// s¹³ leaves a relative error below (1/9)^7/15 ≈ 2e-8, also for tiny u.
#[inline(always)]
fn ln_1p_unit(u: f32) -> f32 {
    let s = u / (2.0 + u);
    let s2 = s * s;
    let p = 1.0
        + s2 * (1.0 / 3.0
            + s2 * (1.0 / 5.0
                + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0 + s2 * (1.0 / 11.0 + s2 * (1.0 / 13.0))))));
    2.0 * s * p
}

/// softplus(x) = max(x, 0) + ln(1 + e^−|x|), branch-free.
#[inline(always)]
pub fn softplus(x: f32) -> f32 {
    let u = exp((-x.abs()).max(-87.0));
    x.max(0.0) + ln_1p_unit(u)
}

/// softplus over a slice whose length is a multiple of 8 (a padded layer).
#[inline(always)]
pub fn softplus_in_place(v: &mut [f32]) {
    for chunk in v.chunks_exact_mut(8) {
        for x in chunk {
            *x = softplus(*x);
        }
    }
}

/// ln(x) for a positive, finite, normal f32: exponent from the bits, mantissa by
/// [`ln_1p_unit`] (m − 1 is exact for m ∈ [1, 2)).
#[inline(always)]
pub fn ln(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    e as f32 * std::f32::consts::LN_2 + ln_1p_unit(m - 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Relative error against f64 over a dense sweep; 4e-7 is ~3 f32 ulps (the
    /// polynomials are exact to ~2e-8, the rest is f32 rounding of a few operations).
    #[test]
    fn exp_ln_softplus_match_f64() {
        let mut worst = [0f64; 3];
        for i in 0..=200_000 {
            let x = -80.0 + 160.0 * i as f64 / 200_000.0;
            let x = x as f32 as f64;
            let e = exp(x as f32) as f64;
            worst[0] = worst[0].max((e - x.exp()).abs() / x.exp());
            let y = 1e-30f64 * (1e60f64).powf(i as f64 / 200_000.0);
            let l = ln(y as f32) as f64;
            let r = (y as f32 as f64).ln();
            worst[1] = worst[1].max((l - r).abs() / r.abs().max(1.0));
            let s = -40.0 + 80.0 * i as f64 / 200_000.0;
            let sp = softplus(s as f32) as f64;
            let s = s as f32 as f64;
            let rs = s.max(0.0) + (-s.abs()).exp().ln_1p();
            worst[2] = worst[2].max((sp - rs).abs() / rs);
        }
        assert!(worst.iter().all(|w| *w < 4e-7), "relative errors {worst:?}");
    }
}
