//! Burn-free evaluation of a CVAE decoder: an MLP with softplus between hidden layers and
//! a linear head producing [mean | log-variance], in plain f32 Rust.

use crate::fastmath::{Fused, Madd, Separate};

/// Decoder log-variances are clamped to this range (the authors' clamp): a model that
/// predicts a huge variance for an input it never saw cannot blow up a renderer.
pub const LOGVAR_CLAMP: f32 = 16.0;

/// One fully connected layer, y = W x + b with W stored row-major as `[out][in]` (each
/// output is one dot product — the layout the model file and the WGSL kernels use).
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    pub inputs: usize,
    pub outputs: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
    /// The same weights column by column, each column zero-padded to a multiple of 8
    /// outputs: the CPU evaluates y += x_i · column_i, eight outputs per vector
    /// operation, instead of one short dot product per output.
    columns: Vec<f32>,
    /// The bias zero-padded likewise.
    bias_padded: Vec<f32>,
}

/// Outputs rounded up to whole 8-lane chunks.
#[inline]
fn padded(outputs: usize) -> usize {
    outputs.div_ceil(8) * 8
}

impl Dense {
    /// `weight` is row-major `[outputs][inputs]`; lengths must match.
    pub fn new(inputs: usize, outputs: usize, weight: Vec<f32>, bias: Vec<f32>) -> Self {
        assert_eq!(weight.len(), inputs * outputs, "weight shape");
        assert_eq!(bias.len(), outputs, "bias shape");
        let p = padded(outputs);
        let mut columns = vec![0f32; inputs * p];
        for o in 0..outputs {
            for i in 0..inputs {
                columns[i * p + o] = weight[o * inputs + i];
            }
        }
        let mut bias_padded = vec![0f32; p];
        bias_padded[..outputs].copy_from_slice(&bias);
        Self {
            inputs,
            outputs,
            weight,
            bias,
            columns,
            bias_padded,
        }
    }

    /// y[..padded] = W x + b (padding lanes come out 0 before the activation).
    #[inline(always)]
    fn apply<M: Madd>(&self, x: &[f32], y: &mut [f32]) {
        match self.bias_padded.len() / 8 {
            1 => self.apply_chunks::<M, 1>(x, y),
            2 => self.apply_chunks::<M, 2>(x, y),
            3 => self.apply_chunks::<M, 3>(x, y),
            4 => self.apply_chunks::<M, 4>(x, y),
            5 => self.apply_chunks::<M, 5>(x, y),
            6 => self.apply_chunks::<M, 6>(x, y),
            7 => self.apply_chunks::<M, 7>(x, y),
            _ => self.apply_chunks::<M, 8>(x, y),
        }
    }

    /// The layer with C eight-output chunks, all accumulated at once, each in two
    /// partial sums (even and odd inputs). The decoders are small (8–16 wide) and so
    /// bound by the latency of the accumulation chains, not by arithmetic: one chain
    /// per chunk, as before, left the FMA units idle three cycles in four.
    #[inline(always)]
    fn apply_chunks<M: Madd, const C: usize>(&self, x: &[f32], y: &mut [f32]) {
        let p = C * 8;
        debug_assert_eq!(p, self.bias_padded.len());
        let x = &x[..self.inputs];
        let cols = &self.columns[..self.inputs * p];
        let mut even = [[0f32; 8]; C];
        let mut odd = [[0f32; 8]; C];
        for (c, acc) in even.iter_mut().enumerate() {
            acc.copy_from_slice(&self.bias_padded[c * 8..c * 8 + 8]);
        }
        let mut pairs = x.chunks_exact(2);
        let mut wpairs = cols.chunks_exact(2 * p);
        for (xs, ws) in (&mut pairs).zip(&mut wpairs) {
            for c in 0..C {
                for k in 0..8 {
                    even[c][k] = M::madd(xs[0], ws[c * 8 + k], even[c][k]);
                    odd[c][k] = M::madd(xs[1], ws[p + c * 8 + k], odd[c][k]);
                }
            }
        }
        if let ([xl], ws) = (pairs.remainder(), wpairs.remainder()) {
            for c in 0..C {
                for k in 0..8 {
                    even[c][k] = M::madd(*xl, ws[c * 8 + k], even[c][k]);
                }
            }
        }
        for c in 0..C {
            for k in 0..8 {
                y[c * 8 + k] = even[c][k] + odd[c][k];
            }
        }
    }
}

impl Dense {
    /// The layer for L draws at once, one per SIMD lane (`x[i][lane]`): every
    /// multiply-add serves L draws, and blocks of eight outputs keep eight independent
    /// accumulation chains going (one draw alone is bound by the chains' latency).
    #[inline(always)]
    fn apply_lanes<M: Madd, const L: usize>(&self, x: &[[f32; L]], y: &mut [[f32; L]]) {
        let x = &x[..self.inputs];
        let mut o = 0;
        while o + 8 <= self.outputs {
            self.block::<M, L, 8>(x, y, o);
            o += 8;
        }
        while o + 4 <= self.outputs {
            self.block::<M, L, 4>(x, y, o);
            o += 4;
        }
        while o < self.outputs {
            self.block::<M, L, 1>(x, y, o);
            o += 1;
        }
    }

    /// Outputs o0..o0 + B of [`Dense::apply_lanes`].
    #[inline(always)]
    fn block<M: Madd, const L: usize, const B: usize>(
        &self,
        x: &[[f32; L]],
        y: &mut [[f32; L]],
        o0: usize,
    ) {
        let n = self.inputs;
        let rows: [&[f32]; B] =
            std::array::from_fn(|b| &self.weight[(o0 + b) * n..(o0 + b + 1) * n]);
        let mut acc: [[f32; L]; B] = std::array::from_fn(|b| [self.bias[o0 + b]; L]);
        for (i, xi) in x.iter().enumerate() {
            for b in 0..B {
                let w = rows[b][i];
                for l in 0..L {
                    acc[b][l] = M::madd(w, xi[l], acc[b][l]);
                }
            }
        }
        y[o0..o0 + B].copy_from_slice(&acc);
    }
}

/// Most outputs of any decoder (EventGen's six); a head holds twice as many.
pub const MAX_OUT: usize = 8;
/// Largest latent size a training config may ask for.
pub const MAX_LATENT: usize = 16;
/// Most inputs (conditions + latent) of any decoder: EventGen's conditions plus the
/// largest latent size (with room to spare: 7 + 16 = 23).
pub const MAX_INPUT: usize = 24;
const _: () = assert!(crate::features::EVENT_COND + MAX_LATENT <= MAX_INPUT);

/// One decoder draw set up but not yet evaluated: its standardised input row and its
/// output noise. A draw in three parts (set up, evaluate, read out) lets a renderer
/// evaluate the draws of many paths together ([`Decoder::outputs`]).
#[derive(Clone, Copy, Debug)]
pub struct Draw {
    pub input: [f32; MAX_INPUT],
    pub eps: [f32; MAX_OUT],
}

impl Default for Draw {
    fn default() -> Self {
        Self {
            input: [0.0; MAX_INPUT],
            eps: [0.0; MAX_OUT],
        }
    }
}

/// A decoder's raw output for one draw: [mean | log-variance], standardised.
pub type Head = [f32; 2 * MAX_OUT];

/// A draw's result: the de-standardised outputs, mean + exp(½ logvar)·eps.
pub type Output = [f32; MAX_OUT];

/// softplus(x) = ln(1 + eˣ) with libm, the reference the fast layer-wide version
/// ([`crate::fastmath::softplus`]) is tested against.
pub fn softplus(x: f32) -> f32 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// A decoder with its input/output standardisation.
#[derive(Clone, Debug, PartialEq)]
pub struct Decoder {
    /// Conditioning inputs (before the latent variables).
    pub cond: usize,
    pub latent: usize,
    /// Predicted variables (the head has 2× as many outputs: mean and log-variance).
    pub out: usize,
    pub layers: Vec<Dense>,
    /// Standardisation of the conditioning features: (c − shift) / scale.
    pub cond_shift: Vec<f32>,
    pub cond_scale: Vec<f32>,
    /// De-standardisation of the outputs: v · scale + shift.
    pub out_shift: Vec<f32>,
    pub out_scale: Vec<f32>,
}

/// Widest layer any shipped decoder may have (fixed-size stack buffers, no allocation).
pub const MAX_WIDTH: usize = 64;
/// Most hidden layers of a decoder. The paper's have 2–3 (the shipped ones too); the GPU
/// kernels unroll every layer into straight-line WGSL, and a model file claiming 1,000
/// layers took 31 s and 690 MB to compile on lavapipe (100,000 did not finish).
pub const MAX_HIDDEN_LAYERS: usize = 8;

impl Decoder {
    /// Raw network: input [standardised cond | z] → [mean | logvar] in standardised units.
    ///
    /// On x86-64 CPUs with AVX2 and FMA (checked at run time; std caches the answer) the
    /// same code is compiled 8 lanes wide with fused multiply-adds: the decoders are most
    /// of ST-CVAE's time and the portable build only assumes SSE2. The two differ by
    /// f32 rounding only.
    pub fn forward(&self, input: &[f32], out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above).
            unsafe { self.forward_avx2(input, out) };
            return;
        }
        self.forward_with::<Separate>(input, out);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn forward_avx2(&self, input: &[f32], out: &mut [f32]) {
        self.forward_with::<Fused>(input, out);
    }

    #[inline(always)]
    fn forward_with<M: Madd>(&self, input: &[f32], out: &mut [f32]) {
        // Two activation buffers used in turn (swapping the arrays would copy them).
        let mut buf = [[0f32; MAX_WIDTH]; 2];
        buf[0][..input.len()].copy_from_slice(input);
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            let [a, b] = &mut buf;
            let (src, dst) = if i % 2 == 0 { (&*a, b) } else { (&*b, a) };
            layer.apply::<M>(src, dst);
            if i < last {
                crate::fastmath::softplus_in_place::<M>(&mut dst[..padded(layer.outputs)]);
            }
        }
        out.copy_from_slice(&buf[self.layers.len() % 2][..2 * self.out]);
    }

    /// Draws the outputs given raw conditioning features, latent normals `z` (len
    /// `latent`) and output normals `eps` (len `out`); writes de-standardised values.
    pub fn sample(&self, cond: &[f64], z: &[f32], eps: &[f32], result: &mut [f64]) {
        let out = self.output(&self.draw(cond, z, eps));
        for (r, v) in result[..self.out].iter_mut().zip(out) {
            *r = v as f64;
        }
    }

    /// The result of one draw ([`Decoder::outputs`] for a batch of one).
    pub fn output(&self, draw: &Draw) -> Output {
        let mut out = [[0f32; MAX_OUT]];
        self.outputs(std::slice::from_ref(draw), &mut out);
        out[0]
    }

    /// The head of one draw.
    pub fn head(&self, draw: &Draw) -> Head {
        let mut head = [0f32; 2 * MAX_OUT];
        self.forward(
            &draw.input[..self.cond + self.latent],
            &mut head[..2 * self.out],
        );
        head
    }

    /// Sets up a draw: standardised conditions, latent normals `z`, output normals `eps`.
    pub fn draw(&self, cond: &[f64], z: &[f32], eps: &[f32]) -> Draw {
        let mut d = Draw::default();
        let standardised = cond[..self.cond]
            .iter()
            .zip(self.cond_shift.iter().zip(&self.cond_scale))
            .map(|(&c, (shift, scale))| (c as f32 - shift) / scale);
        for (x, v) in d.input.iter_mut().zip(standardised) {
            *x = v;
        }
        d.input[self.cond..self.cond + self.latent].copy_from_slice(&z[..self.latent]);
        d.eps[..self.out].copy_from_slice(&eps[..self.out]);
        d
    }

    /// The antithetic partner of a draw: the same condition with its latent and output
    /// normals negated, which are standard normal too. Two draws averaged this way keep
    /// their mean and, where the output moves monotonically with the noise, lose variance.
    pub fn mirrored(&self, d: &Draw) -> Draw {
        let mut m = *d;
        for v in &mut m.input[self.cond..self.cond + self.latent] {
            *v = -*v;
        }
        for v in &mut m.eps[..self.out] {
            *v = -*v;
        }
        m
    }

    /// The de-standardised outputs of a draw from its head, one draw at a time: the
    /// definition [`Decoder::outputs`] computes in SIMD lanes (tests compare the two).
    pub fn read_out(&self, head: &Head, draw: &Draw) -> Output {
        let mut out = [0f32; MAX_OUT];
        for j in 0..self.out {
            let logvar = head[self.out + j].clamp(-LOGVAR_CLAMP, LOGVAR_CLAMP);
            let v = head[j] + crate::fastmath::exp(0.5 * logvar) * draw.eps[j];
            out[j] = v * self.out_scale[j] + self.out_shift[j];
        }
        out
    }

    /// The results of many draws, evaluated with the draws in SIMD lanes: 16 at a time on
    /// CPUs with AVX-512, 8 with AVX2 + FMA (both checked at run time), 8 in portable
    /// code. Equal to [`Decoder::read_out`] of [`Decoder::head`] draw by draw up to f32
    /// rounding (sums taken in another order). A renderer collects one draw from each of
    /// its paths between two sphere steps; evaluated together they cost a fraction of
    /// one-by-one evaluation, whose short dependent chains leave the arithmetic units
    /// mostly idle. The read-out's exponentials run in the lanes too (scalar, they were
    /// 2–3 % of the renderer's time).
    pub fn outputs(&self, draws: &[Draw], out: &mut [Output]) {
        assert_eq!(draws.len(), out.len(), "one output per draw");
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F (checked just above).
                unsafe { self.outputs_avx512(draws, out) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                unsafe { self.outputs_avx2(draws, out) };
                return;
            }
        }
        self.outputs_with::<Separate, 8>(draws, out);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    fn outputs_avx512(&self, draws: &[Draw], out: &mut [Output]) {
        self.outputs_with::<Fused, 16>(draws, out);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn outputs_avx2(&self, draws: &[Draw], out: &mut [Output]) {
        self.outputs_with::<Fused, 8>(draws, out);
    }

    /// [`Decoder::outputs`] with L lanes (a multiple of 8).
    #[inline(always)]
    fn outputs_with<M: Madd, const L: usize>(&self, draws: &[Draw], out: &mut [Output]) {
        let mut buf = [[[0f32; L]; MAX_WIDTH]; 2];
        for (group, out) in draws.chunks(L).zip(out.chunks_mut(L)) {
            let rows = self.group_heads::<M, L>(group, &mut buf);
            for j in 0..self.out {
                let mut eps = [0f32; L];
                for (e, d) in eps.iter_mut().zip(group) {
                    *e = d.eps[j];
                }
                let (scale, shift) = (self.out_scale[j], self.out_shift[j]);
                let mut v = [0f32; L];
                for l in 0..L {
                    let logvar = rows[self.out + j][l].clamp(-LOGVAR_CLAMP, LOGVAR_CLAMP);
                    let sd = crate::fastmath::exp_with::<M>(0.5 * logvar);
                    v[l] = M::madd(M::madd(sd, eps[l], rows[j][l]), scale, shift);
                }
                for (o, x) in out.iter_mut().zip(v) {
                    o[j] = x;
                }
            }
        }
    }

    /// The heads of many draws with L lanes: what [`Decoder::outputs`] computes before
    /// its read-out (tests compare every lane width with one-by-one evaluation).
    #[cfg(test)]
    fn heads_with<M: Madd, const L: usize>(&self, draws: &[Draw], heads: &mut [Head]) {
        let mut buf = [[[0f32; L]; MAX_WIDTH]; 2];
        for (group, out) in draws.chunks(L).zip(heads.chunks_mut(L)) {
            let rows = self.group_heads::<M, L>(group, &mut buf);
            for (l, h) in out.iter_mut().enumerate() {
                for (hj, row) in h.iter_mut().zip(rows) {
                    *hj = row[l];
                }
            }
        }
    }

    /// Up to L draws through the network, one per lane; returns the head's rows (2·out
    /// of them). Lanes past the group's end hold whatever `buf` held before: finite values
    /// whose results are never read.
    #[inline(always)]
    fn group_heads<'b, M: Madd, const L: usize>(
        &self,
        group: &[Draw],
        buf: &'b mut [[[f32; L]; MAX_WIDTH]; 2],
    ) -> &'b [[f32; L]] {
        let inputs = self.cond + self.latent;
        let last = self.layers.len() - 1;
        for (l, d) in group.iter().enumerate() {
            for (row, &x) in buf[0].iter_mut().zip(&d.input[..inputs]) {
                row[l] = x;
            }
        }
        for (i, layer) in self.layers.iter().enumerate() {
            let [a, b] = &mut *buf;
            let (src, dst) = if i % 2 == 0 { (&*a, b) } else { (&*b, a) };
            layer.apply_lanes::<M, L>(src, dst);
            if i < last {
                crate::fastmath::softplus_chunks::<M, L>(dst[..layer.outputs].as_flattened_mut());
            }
        }
        &buf[self.layers.len() % 2][..2 * self.out]
    }

    /// Number of parameters.
    pub fn parameters(&self) -> usize {
        self.layers
            .iter()
            .map(|l| l.weight.len() + l.bias.len())
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every variant `outputs` runs (separate multiply-adds on 8 lanes: portable builds;
    /// fused on 8: AVX2; fused on 16: AVX-512), and separate ones on 16, equal one-by-one
    /// evaluation on batches that end mid-group.
    /// Tolerance as in `tests/model_file.rs`: f32 rounding of sums taken in another order
    /// is a few ulps of O(1–10) values; a wrong lane or weight is O(0.1–1).
    #[test]
    fn every_lane_width_equals_single_draws() {
        assert_lanes_equal_single_draws(&[12, 12, 12, 12, 12], 5, 37, 1, |_| 1.5);
    }

    /// A decoder of layers `widths` (7 conditions and `latent` latent inputs first, 6
    /// outputs' means and log-variances last), weights uniform in ±`half_range(fan-in)`/2
    /// from an LCG seeded with `seed`, evaluated on `n` random draws one by one (`head`) and
    /// by every lane variant (`heads_with`): each head must be finite and agree within
    /// 1e-4 of max(|head|, 1).
    fn assert_lanes_equal_single_draws(
        widths: &[usize],
        latent: usize,
        n: usize,
        seed: u32,
        half_range: impl Fn(usize) -> f32,
    ) {
        let mut seed = seed;
        let mut next = move || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5
        };
        let layers = widths
            .windows(2)
            .map(|w| {
                let a = half_range(w[0]);
                let weight = (0..w[0] * w[1]).map(|_| a * next()).collect();
                let bias = (0..w[1]).map(|_| next()).collect();
                Dense::new(w[0], w[1], weight, bias)
            })
            .collect();
        let d = Decoder {
            cond: 7,
            latent,
            out: 6,
            layers,
            cond_shift: vec![0.0; 7],
            cond_scale: vec![1.0; 7],
            out_shift: vec![0.0; 6],
            out_scale: vec![1.0; 6],
        };
        let draws: Vec<Draw> = (0..n)
            .map(|_| {
                let cond: Vec<f64> = (0..7).map(|_| 4.0 * next() as f64).collect();
                let z: Vec<f32> = (0..latent).map(|_| 3.0 * next()).collect();
                d.draw(&cond, &z, &[0.0; 6])
            })
            .collect();
        let single: Vec<Head> = draws.iter().map(|x| d.head(x)).collect();
        let mut heads = vec![[0f32; 2 * MAX_OUT]; draws.len()];
        for width in 0..4 {
            // Poisoned, so a lane a variant leaves unwritten fails the comparison below
            // instead of showing the previous variant's value.
            heads.fill([f32::NAN; 2 * MAX_OUT]);
            match width {
                0 => d.heads_with::<Separate, 8>(&draws, &mut heads),
                1 => d.heads_with::<Separate, 16>(&draws, &mut heads),
                2 => d.heads_with::<Fused, 8>(&draws, &mut heads),
                _ => d.heads_with::<Fused, 16>(&draws, &mut heads),
            }
            for (a, b) in single.iter().zip(&heads) {
                for j in 0..12 {
                    assert!(
                        a[j].is_finite() && (a[j] - b[j]).abs() <= 1e-4 * a[j].abs().max(1.0),
                        "variant {width}, output {j}: one draw {} vs lanes {}",
                        a[j],
                        b[j]
                    );
                }
            }
        }
    }

    /// The one-draw path (`head`: `Dense::apply`, columns of 8 outputs, inputs in pairs)
    /// equals the lane path (`heads_with`: rows) for every chunk count `apply` dispatches
    /// on and for odd input counts, which leave `apply_chunks` a last input without a
    /// partner. Layers of 20, 27, 33, 41, 49, 57 and 64 outputs take 3, 4, 5, 6, 7, 8 and
    /// 8 chunks; the inputs 11 (7 conditions + 4 latent), 27, 33, 41, 49 and 57 are odd,
    /// feeding layers of 3 and 5–8 chunks. The other tests' decoders are 4–16 wide with
    /// even inputs (1–2 chunks, no lone input), and the 64-wide ones of the model-file
    /// tests are only checked for finite outputs. Weights uniform in ±1.7/√fan-in keep the
    /// activations O(1) through the eight layers, so f32 rounding stays near 1e-6 against
    /// the 1e-4 allowed (as in `every_lane_width_equals_single_draws`); a chunk count taken
    /// for another is off by O(1), a lone input's weight read from the first chunk by up
    /// to 0.095, 0.08 of max(|head|, 1) (replayed in f64).
    #[test]
    fn every_chunk_count_and_odd_inputs_equal_the_lanes() {
        let widths = [11, 20, 27, 33, 41, 49, 57, 64, 12];
        assert_lanes_equal_single_draws(&widths, 4, 21, 7, |fan_in| 3.4 / (fan_in as f32).sqrt());
    }
}
