//! Burn-free evaluation of a CVAE decoder: an MLP with softplus between hidden layers and
//! a linear head producing [mean | log-variance], in plain f32 Rust.

/// Decoder log-variances are clamped to this range (the authors' clamp): a model that
/// predicts a huge variance for an input it never saw cannot blow up a renderer.
pub const LOGVAR_CLAMP: f32 = 16.0;

/// One fully connected layer, y = W x + b with W stored row-major as [out][in] (each
/// output is one dot product — the layout the WGSL kernels read).
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    pub inputs: usize,
    pub outputs: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

impl Dense {
    #[inline]
    fn apply(&self, x: &[f32], y: &mut [f32]) {
        for (o, yo) in y.iter_mut().enumerate().take(self.outputs) {
            let row = &self.weight[o * self.inputs..(o + 1) * self.inputs];
            *yo = self.bias[o] + dot(row, &x[..self.inputs]);
        }
    }
}

/// Dot product with eight independent partial sums: a plain `sum()` is one serial chain
/// of dependent adds (the compiler may not reorder float additions), which made the
/// decoders the renderer's bottleneck.
#[inline]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut tail = 0f32;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

/// softplus(x) = ln(1 + eˣ), computed without overflow. `ln(1 + t)` rather than
/// `ln_1p(t)`: for t ≤ 1 its absolute error is below 1e-7, which is all that matters
/// next to max(x, 0), and glibc's log1pf was a sixth of the renderer's time.
#[inline]
pub fn softplus(x: f32) -> f32 {
    x.max(0.0) + (1.0 + (-x.abs()).exp()).ln()
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

impl Decoder {
    /// Raw network: input [standardised cond | z] → [mean | logvar] in standardised units.
    pub fn forward(&self, input: &[f32], out: &mut [f32]) {
        let mut a = [0f32; MAX_WIDTH];
        let mut b = [0f32; MAX_WIDTH];
        a[..input.len()].copy_from_slice(input);
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            layer.apply(&a[..layer.inputs], &mut b[..layer.outputs]);
            if i < last {
                for v in &mut b[..layer.outputs] {
                    *v = softplus(*v);
                }
            }
            std::mem::swap(&mut a, &mut b);
        }
        out.copy_from_slice(&a[..2 * self.out]);
    }

    /// Draws the outputs given raw conditioning features, latent normals `z` (len
    /// `latent`) and output normals `eps` (len `out`); writes de-standardised values.
    pub fn sample(&self, cond: &[f64], z: &[f32], eps: &[f32], result: &mut [f64]) {
        let mut input = [0f32; MAX_WIDTH];
        for i in 0..self.cond {
            input[i] = ((cond[i] as f32) - self.cond_shift[i]) / self.cond_scale[i];
        }
        input[self.cond..self.cond + self.latent].copy_from_slice(&z[..self.latent]);
        let mut head = [0f32; MAX_WIDTH];
        self.forward(&input[..self.cond + self.latent], &mut head[..2 * self.out]);
        for j in 0..self.out {
            let logvar = head[self.out + j].clamp(-LOGVAR_CLAMP, LOGVAR_CLAMP);
            let v = head[j] + (0.5 * logvar).exp() * eps[j];
            result[j] = (v * self.out_scale[j] + self.out_shift[j]) as f64;
        }
    }

    /// Number of parameters.
    pub fn parameters(&self) -> usize {
        self.layers
            .iter()
            .map(|l| l.weight.len() + l.bias.len())
            .sum()
    }
}
