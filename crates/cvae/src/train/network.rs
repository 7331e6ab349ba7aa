//! The CVAE networks in burn: encoder and decoder MLPs with softplus between hidden
//! layers and linear [mean | log-variance] heads, and the negative-ELBO loss.

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::softplus;
use scatter_sim::WalkRng;

use crate::decoder::{Decoder, Dense, LOGVAR_CLAMP};

/// A fully connected network: softplus after every layer but the last.
#[derive(Module, Debug)]
pub struct Mlp {
    pub layers: Vec<Linear>,
}

impl Mlp {
    /// Weights drawn from U(±1/√fan_in) (PyTorch's Linear default, which the authors
    /// used) with our own per-model stream: burn's generator is one process-wide stream,
    /// which would make concurrent training runs irreproducible.
    pub fn new(widths: &[usize], rng: &mut WalkRng, device: &Device) -> Self {
        let layers = widths
            .windows(2)
            .map(|w| {
                let (i, o) = (w[0], w[1]);
                let a = 1.0 / (i as f64).sqrt();
                let mut draw = |k: usize| -> Vec<f32> {
                    (0..k)
                        .map(|_| (a * (2.0 * rng.uniform() - 1.0)) as f32)
                        .collect()
                };
                let weight = draw(i * o);
                let bias = draw(o);
                Linear {
                    weight: Param::from_data(TensorData::new(weight, [i, o]), device),
                    bias: Some(Param::from_data(TensorData::new(bias, [o]), device)),
                }
            })
            .collect();
        Self { layers }
    }

    pub fn forward(&self, mut x: Tensor<2>) -> Tensor<2> {
        let last = self.layers.len() - 1;
        for (i, l) in self.layers.iter().enumerate() {
            x = l.forward(x);
            if i < last {
                x = softplus(x, 1.0);
            }
        }
        x
    }

    /// The layers as plain-Rust dense layers (burn stores W as [in, out]; the model file
    /// stores it row-major `[out][in]`).
    pub fn to_dense(&self) -> Vec<Dense> {
        self.layers
            .iter()
            .map(|l| {
                let [i, o] = l.weight.val().dims();
                let w: Vec<f32> = l
                    .weight
                    .val()
                    .try_into_vec_as::<f32>()
                    .expect("f32 weights");
                let mut weight = vec![0f32; i * o];
                for r in 0..i {
                    for c in 0..o {
                        weight[c * i + r] = w[r * o + c];
                    }
                }
                let bias = match &l.bias {
                    Some(b) => b.val().try_into_vec_as::<f32>().expect("f32 bias"),
                    None => vec![0.0; o],
                };
                Dense::new(i, o, weight, bias)
            })
            .collect()
    }
}

/// Sizes of one CVAE.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Architecture {
    pub latent: usize,
    /// Hidden layer widths of the decoder (the part that runs at render time).
    pub hidden: Vec<usize>,
    /// Hidden layer widths of the encoder (training only; defaults to the decoder's).
    #[serde(default)]
    pub encoder_hidden: Option<Vec<usize>>,
}

#[derive(Module, Debug)]
pub struct Cvae {
    pub encoder: Mlp,
    pub decoder: Mlp,
    pub cond: usize,
    pub out: usize,
    pub latent: usize,
}

/// Loss terms of a batch (means over the batch).
pub struct LossTerms {
    pub loss: Tensor<1>,
    pub nll: Tensor<1>,
    pub kl: Tensor<1>,
}

impl Cvae {
    pub fn new(
        cond: usize,
        out: usize,
        arch: &Architecture,
        rng: &mut WalkRng,
        device: &Device,
    ) -> Self {
        let enc_hidden = arch
            .encoder_hidden
            .clone()
            .unwrap_or_else(|| arch.hidden.clone());
        let enc: Vec<usize> = std::iter::once(cond + out)
            .chain(enc_hidden)
            .chain([2 * arch.latent])
            .collect();
        let dec: Vec<usize> = std::iter::once(cond + arch.latent)
            .chain(arch.hidden.iter().copied())
            .chain([2 * out])
            .collect();
        Self {
            encoder: Mlp::new(&enc, rng, device),
            decoder: Mlp::new(&dec, rng, device),
            cond,
            out,
            latent: arch.latent,
        }
    }

    /// Negative ELBO: Gaussian NLL of the target under the decoder (constant dropped)
    /// plus KL(q(z|x,c) ‖ N(0, I)); `eps` are the reparameterisation normals [B, latent].
    pub fn loss(&self, cond: Tensor<2>, target: Tensor<2>, eps: Tensor<2>) -> LossTerms {
        let (nll, kl) = self.row_terms(cond, target, eps);
        let (nll, kl) = (nll.mean(), kl.mean());
        LossTerms {
            loss: nll.clone() + kl.clone(),
            nll,
            kl,
        }
    }

    /// Each row's negative ELBO, shape `[B]` (a validation loss's mean and standard error).
    pub fn row_losses(&self, cond: Tensor<2>, target: Tensor<2>, eps: Tensor<2>) -> Vec<f32> {
        let (nll, kl) = self.row_terms(cond, target, eps);
        (nll + kl)
            .into_data()
            .try_to_vec::<f32>()
            .expect("the loss is f32")
    }

    /// Each row's NLL and KL, [B, 1] each.
    fn row_terms(
        &self,
        cond: Tensor<2>,
        target: Tensor<2>,
        eps: Tensor<2>,
    ) -> (Tensor<2>, Tensor<2>) {
        let (l, p) = (self.latent, self.out);
        let h = self
            .encoder
            .forward(Tensor::cat(vec![cond.clone(), target.clone()], 1));
        let mu_z = h.clone().narrow(1, 0, l);
        let lv_z = h.narrow(1, l, l).clamp(-LOGVAR_CLAMP, LOGVAR_CLAMP);
        let z = mu_z.clone() + lv_z.clone().mul_scalar(0.5).exp() * eps;
        let d = self.decoder.forward(Tensor::cat(vec![cond, z], 1));
        let mu = d.clone().narrow(1, 0, p);
        let lv = d.narrow(1, p, p).clamp(-LOGVAR_CLAMP, LOGVAR_CLAMP);
        let nll = (lv.clone() + (target - mu).square() * lv.neg().exp())
            .mul_scalar(0.5)
            .sum_dim(1);
        let kl = (mu_z.square() + lv_z.clone().exp() - lv_z)
            .sub_scalar(1.0)
            .mul_scalar(0.5)
            .sum_dim(1);
        (nll, kl)
    }

    /// The decoder as a plain-Rust [`Decoder`] with the given standardisation.
    pub fn export(&self, norm: &crate::train::data::Standardisation) -> Decoder {
        Decoder {
            cond: self.cond,
            latent: self.latent,
            out: self.out,
            layers: self.decoder.to_dense(),
            cond_shift: norm.cond_shift.clone(),
            cond_scale: norm.cond_scale.clone(),
            out_shift: norm.out_shift.clone(),
            out_scale: norm.out_scale.clone(),
        }
    }
}
