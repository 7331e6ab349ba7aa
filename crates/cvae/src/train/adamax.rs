//! Adamax (Kingma & Ba 2015, Algorithm 2), which burn 0.22 lacks; the paper trained with it.
//!
//! m_t = β₁ m_{t−1} + (1 − β₁) g_t;  u_t = max(β₂ u_{t−1}, |g_t|);
//! θ_t = θ_{t−1} − (α / (1 − β₁ᵗ)) · m_t / u_t.
//! `epsilon` is added to u_t in the denominator only to avoid 0/0 for parameters whose
//! gradient has always been exactly zero. PyTorch puts it inside the max instead
//! (u_t = max(β₂ u_{t−1}, |g_t| + ε)); with ε = 1e-8 against gradients many orders larger
//! the two steps differ by a relative ~ε/u_t.

use burn::optim::{LearningRate, ModuleOptimizer, Optimizer, RecordState, StateSink, StateSource};
use burn::prelude::*;

#[derive(Clone, Debug)]
pub struct Adamax {
    pub beta_1: f32,
    pub beta_2: f32,
    pub epsilon: f32,
}

impl Default for Adamax {
    /// The paper's (and PyTorch's) defaults.
    fn default() -> Self {
        Self {
            beta_1: 0.9,
            beta_2: 0.999,
            epsilon: 1e-8,
        }
    }
}

impl Adamax {
    pub fn init(self) -> ModuleOptimizer {
        self.into()
    }
}

/// Per-parameter state: step count and the two moments. The step count is stored as a
/// one-element tensor so the state saves through burn's optimizer records unchanged.
#[derive(Clone)]
pub struct AdamaxState<const D: usize> {
    pub time: usize,
    pub m: Tensor<D>,
    pub u: Tensor<D>,
}

impl<const D: usize> RecordState for AdamaxState<D> {
    fn state_flatten(&self, prefix: &str, out: &mut StateSink) {
        out.push_tensor(prefix, "time", TensorData::new(vec![self.time as f32], [1]));
        out.push_tensor(prefix, "m", self.m.clone().into_data());
        out.push_tensor(prefix, "u", self.u.clone().into_data());
    }

    fn state_unflatten(prefix: &str, src: &mut StateSource, device: &Device) -> Option<Self> {
        let time = src
            .take_tensor(prefix, "time")?
            .try_into_vec::<f32>()
            .ok()?
            .first()
            .copied()? as usize;
        let m = Tensor::<D>::from_data(src.take_tensor(prefix, "m")?, device);
        let u = Tensor::<D>::from_data(src.take_tensor(prefix, "u")?, device);
        Some(Self { time, m, u })
    }
}

impl Optimizer for Adamax {
    type State<const D: usize> = AdamaxState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        let (m, u, time) = match state {
            Some(s) => (
                s.m.mul_scalar(self.beta_1)
                    .add(grad.clone().mul_scalar(1.0 - self.beta_1)),
                s.u.mul_scalar(self.beta_2).max_pair(grad.abs()),
                s.time + 1,
            ),
            // m₀ = u₀ = 0.
            None => (grad.clone().mul_scalar(1.0 - self.beta_1), grad.abs(), 1),
        };
        // powf, not powi: `time as i32` wraps past 2^31 steps (configs allow 2^40), and
        // at 2^32 it became powi(0) = 1, a step of lr / 0.
        let step = lr / (1.0 - (self.beta_1 as f64).powf(time as f64));
        let delta = m
            .clone()
            .div(u.clone().add_scalar(self.epsilon))
            .mul_scalar(step);
        (tensor.sub(delta), Some(AdamaxState { time, m, u }))
    }

    fn to_device<const D: usize>(mut s: Self::State<D>, device: &Device) -> Self::State<D> {
        s.m = s.m.to_device(device);
        s.u = s.u.to_device(device);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three steps on a 3-element parameter against the update rule computed by hand in
    /// f64 (Algorithm 2 of Kingma & Ba); f32 arithmetic agrees to ~1e-7 relative.
    #[test]
    fn matches_algorithm_2() {
        let dev = Device::flex();
        let opt = Adamax::default();
        let lr = 0.01;
        let mut theta = vec![0.5f64, -1.0, 2.0];
        let grads = [[0.1f64, -0.2, 0.0], [0.3, 0.1, 0.0], [-0.05, 0.4, 1e-3]];
        let (mut m, mut u) = (vec![0.0f64; 3], vec![0.0f64; 3]);
        let mut t = Tensor::<1>::from_data(
            TensorData::new(theta.iter().map(|&v| v as f32).collect::<Vec<_>>(), [3]),
            &dev,
        );
        let mut state = None;
        for (step, g) in grads.iter().enumerate() {
            let gt = Tensor::<1>::from_data(
                TensorData::new(g.iter().map(|&v| v as f32).collect::<Vec<_>>(), [3]),
                &dev,
            );
            let (nt, ns) = opt.step(lr, t, gt, state);
            t = nt;
            state = ns;
            for i in 0..3 {
                m[i] = 0.9 * m[i] + 0.1 * g[i];
                u[i] = (0.999 * u[i]).max(g[i].abs());
                let bias = 1.0 - 0.9f64.powi(step as i32 + 1);
                theta[i] -= lr / bias * m[i] / (u[i] + 1e-8);
            }
        }
        let got: Vec<f32> = t.try_into_vec_as::<f32>().unwrap();
        for (a, b) in got.iter().zip(&theta) {
            assert!((*a as f64 - b).abs() < 1e-5, "{got:?} vs {theta:?}");
        }
        assert_eq!(state.unwrap().time, 3);
    }

    /// ε and β₂ as written (1e-8, 0.999), where the test above cannot see them: its
    /// gradients are ≥ 1e-3 (ε/u ≤ 1e-5) and it takes three steps (β₂³ against 1 moves its
    /// result by 3.7e-6, inside its 1e-5; β₂ = 0.9999 by 3.3e-6, ε = 1e-6 by 3.6e-6).
    ///
    /// ε: the first step is lr·g/(|g| + ε) (m₁ = (1 − β₁)g, u₁ = |g|, the bias correction
    /// 1/(1 − β₁) cancels), so with lr = 0.01 from θ = 0 the gradients 1e-6, 1e-8 and −0.5
    /// give θ = −0.01/1.01 = −0.00990099, −0.005 and +0.01 (−0.5/(0.5 + 1e-8) = −1 within
    /// 2e-8). ε = 1e-6 gives −0.005 and −9.9e-5, ε = 1e-7 −0.00909 and −9.1e-4.
    ///
    /// β₂: 300 steps whose first gradient (±1) is 100 and 50 times the rest (0.01, −0.02),
    /// so u_t = β₂^(t−1) decays all the while, against the update rule in f64: θ ends at
    /// (−0.0648954, 0.0995642). β₂ = 0.9999 ends 0.0092 away, no decay (β₂ = 1) 0.0101.
    ///
    /// Within 1e-7 for the one step (f32 rounding: ~1e-9 here) and 1e-5 for the 300 (f32
    /// against f64: 1.4e-7, computed in numpy with the same f32 operations).
    #[test]
    fn epsilon_and_beta_2_are_the_papers() {
        let dev = Device::flex();
        let opt = Adamax::default();
        let lr = 0.01;
        let tensor = |v: &[f64]| {
            Tensor::<1>::from_data(
                TensorData::new(v.iter().map(|&x| x as f32).collect::<Vec<_>>(), [v.len()]),
                &dev,
            )
        };
        let (one, _) = opt.step(lr, tensor(&[0.0; 3]), tensor(&[1e-6, 1e-8, -0.5]), None);
        let got: Vec<f32> = one.try_into_vec_as::<f32>().unwrap();
        for (a, b) in got.iter().zip([-0.01 / 1.01, -0.005, 0.01f64]) {
            assert!((*a as f64 - b).abs() < 1e-7, "one step: {got:?}");
        }

        let steps = 300;
        let grad = |t: usize| -> [f64; 2] { if t == 0 { [1.0, -1.0] } else { [0.01, -0.02] } };
        let mut t = tensor(&[0.0, 0.0]);
        let mut state = None;
        let (mut theta, mut m, mut u) = ([0.0f64; 2], [0.0f64; 2], [0.0f64; 2]);
        for step in 0..steps {
            let g = grad(step);
            let (nt, ns) = opt.step(lr, t, tensor(&g), state);
            t = nt;
            state = ns;
            for i in 0..2 {
                m[i] = 0.9 * m[i] + 0.1 * g[i];
                u[i] = (0.999 * u[i]).max(g[i].abs());
                let bias = 1.0 - 0.9f64.powi(step as i32 + 1);
                theta[i] -= lr / bias * m[i] / (u[i] + 1e-8);
            }
        }
        assert!(
            (theta[0] + 0.0648954).abs() < 1e-6 && (theta[1] - 0.0995642).abs() < 1e-6,
            "the reference itself: {theta:?}"
        );
        let got: Vec<f32> = t.try_into_vec_as::<f32>().unwrap();
        for (a, b) in got.iter().zip(&theta) {
            assert!((*a as f64 - b).abs() < 1e-5, "{got:?} vs {theta:?}");
        }
    }
}
