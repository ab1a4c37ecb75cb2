//! The networks (Table III): actor and critic MLPs with ELU, a learned log-std, the estimator.

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::rng::Rng;

/// The learner's device: burn's Flex CPU backend with autodiff.
pub fn device() -> Device {
    Device::flex().autodiff()
}

/// f32 [rows, cols] from row-major values.
pub fn matrix(values: Vec<f32>, rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(values, [rows, cols]), device)
}

/// f32 [n] from values.
pub fn vector(values: Vec<f32>, device: &Device) -> Tensor<1> {
    let n = values.len();
    Tensor::from_data(TensorData::new(values, [n]), device)
}

/// The values of a tensor, row-major.
pub fn values<const D: usize>(t: Tensor<D>) -> crate::Result<Vec<f32>> {
    Ok(t.into_data().convert::<f32>().try_into_vec::<f32>()?)
}

/// A plain MLP `in -> hidden... -> out`, ELU between layers, none after the last.
#[derive(Module, Debug)]
pub struct Mlp {
    /// The layers (burn's weight is [in, out]).
    pub layers: Vec<Linear>,
}

impl Mlp {
    /// Weights and biases uniform in ±1/sqrt(fan_in), torch's `nn.Linear` default, from `rng`.
    pub fn new(
        in_dim: usize,
        hidden: &[usize],
        out_dim: usize,
        rng: &mut Rng,
        device: &Device,
    ) -> Self {
        let dims: Vec<usize> = std::iter::once(in_dim)
            .chain(hidden.iter().copied())
            .chain([out_dim])
            .collect();
        let layers = dims
            .windows(2)
            .map(|w| {
                let bound = 1.0 / (w[0] as f32).sqrt();
                let mut uniform = |n: usize| {
                    (0..n)
                        .map(|_| (2.0 * rng.uniform() - 1.0) * bound)
                        .collect::<Vec<_>>()
                };
                let weight = uniform(w[0] * w[1]);
                let bias = uniform(w[1]);
                layer(weight, bias, w[0], w[1], device)
            })
            .collect();
        Self { layers }
    }

    /// The output f32 [B, out] of `x` f32 [B, in].
    pub fn forward(&self, mut x: Tensor<2>) -> Tensor<2> {
        let last = self.layers.len().saturating_sub(1);
        for (i, l) in self.layers.iter().enumerate() {
            x = l.forward(x);
            if i < last {
                x = elu(x);
            }
        }
        x
    }
}

/// ELU (alpha 1) as `relu(x) + exp(min(x, 0)) - 1`: burn's own `elu` selects with `mask_where`,
/// which took a third of the update's time (perf, 512 envs); relu and clamp have fused backward
/// kernels. Equal for every x: x > 0 gives x + 1 - 1, x <= 0 gives e^x - 1.
pub fn elu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    relu(x.clone()) + x.clamp_max(0.0).exp().sub_scalar(1.0)
}

/// A linear layer from its weight (row-major [in, out]) and bias.
pub fn layer(weight: Vec<f32>, bias: Vec<f32>, inp: usize, out: usize, device: &Device) -> Linear {
    Linear {
        weight: Param::from_tensor(matrix(weight, inp, out, device)),
        bias: Some(Param::from_tensor(vector(bias, device))),
    }
}

/// Gaussian actor with a state-independent learned log-std, and a value critic.
#[derive(Module, Debug)]
pub struct ActorCritic {
    /// Actor: mean action of the flat history and the estimate.
    pub actor: Mlp,
    /// Critic: state value of (o, e, s).
    pub critic: Mlp,
    /// f32 [A] log of the action std (rsl_rl's "log" std type: positive with no clamp).
    pub log_std: Param<Tensor<1>>,
}

impl ActorCritic {
    /// Actor `actor_in -> actor_hidden -> num_actions`, critic `critic_in -> critic_hidden -> 1`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        actor_in: usize,
        critic_in: usize,
        num_actions: usize,
        actor_hidden: &[usize],
        critic_hidden: &[usize],
        init_noise_std: f32,
        rng: &mut Rng,
        device: &Device,
    ) -> Self {
        let actor = Mlp::new(actor_in, actor_hidden, num_actions, rng, device);
        let critic = Mlp::new(critic_in, critic_hidden, 1, rng, device);
        let log_std = Param::from_tensor(vector(vec![init_noise_std.ln(); num_actions], device));
        Self {
            actor,
            critic,
            log_std,
        }
    }

    /// State value f32 [B] of `critic_obs` f32 [B, critic_in].
    pub fn value(&self, critic_obs: Tensor<2>) -> Tensor<1> {
        self.critic.forward(critic_obs).squeeze_dim::<1>(1)
    }
}

/// The explicit state estimator: history f32 [B, 159] -> estimate f32 [B, 14].
pub type Estimator = Mlp;

/// log N(actions; mean, exp(log_std)) summed over the action dims: f32 [B].
pub fn log_prob(actions: Tensor<2>, mean: Tensor<2>, log_std: Tensor<1>) -> Tensor<1> {
    let half_ln_2pi = 0.5 * std::f64::consts::TAU.ln();
    let log_std = log_std.unsqueeze::<2>();
    let z = (actions - mean) / log_std.clone().exp();
    (z.square().mul_scalar(-0.5) - log_std)
        .sub_scalar(half_ln_2pi)
        .sum_dim(1)
        .squeeze_dim::<1>(1)
}

/// Entropy of the diagonal Gaussian summed over the action dims (the same for every sample): [1].
pub fn entropy(log_std: Tensor<1>) -> Tensor<1> {
    let per_dim = 0.5 + 0.5 * std::f64::consts::TAU.ln();
    let n = log_std.dims()[0] as f64;
    log_std.sum().add_scalar(per_dim * n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 1 -> [1] -> 1 with w0 = 2, b0 = -1, w1 = 3, b1 = 0.5:
    /// x = 0: h = elu(-1) = e^-1 - 1 = -0.632121, y = 3 h + 0.5 = -1.396362;
    /// x = 1: h = elu(1) = 1, y = 3.5.
    #[test]
    fn mlp_applies_elu_between_layers_only() {
        let dev = device();
        let mlp = Mlp {
            layers: vec![
                layer(vec![2.0], vec![-1.0], 1, 1, &dev),
                layer(vec![3.0], vec![0.5], 1, 1, &dev),
            ],
        };
        let y = values(mlp.forward(matrix(vec![0.0, 1.0], 2, 1, &dev))).unwrap();
        assert!((y[0] + 1.396362).abs() < 1e-5, "{y:?}");
        assert!((y[1] - 3.5).abs() < 1e-6);
    }

    /// elu(-2) = e^-2 - 1 = -0.864665, elu(0) = 0, elu(3) = 3; gradients 1 above 0, e^x below.
    #[test]
    fn elu_values_and_gradients() {
        let dev = device();
        let x = vector(vec![-2.0, 0.0, 3.0], &dev).require_grad();
        let y = elu(x.clone());
        let v = values(y.clone()).unwrap();
        assert!(
            (v[0] + 0.864_665).abs() < 1e-6 && v[1] == 0.0 && v[2] == 3.0,
            "{v:?}"
        );
        let grads = y.sum().backward();
        let g = values(x.grad(&grads).unwrap()).unwrap();
        assert!(
            (g[0] - (-2.0f32).exp()).abs() < 1e-6 && (g[2] - 1.0).abs() < 1e-6,
            "{g:?}"
        );
    }

    #[test]
    fn init_is_torch_uniform_and_seeded() {
        let dev = device();
        let a = Mlp::new(173, &[512, 256, 128], 12, &mut Rng::new(3), &dev);
        let b = Mlp::new(173, &[512, 256, 128], 12, &mut Rng::new(3), &dev);
        let w = values(a.layers[0].weight.val()).unwrap();
        let bound = 1.0 / 173f32.sqrt();
        assert_eq!(w.len(), 512 * 173);
        assert!(w.iter().all(|x| x.abs() <= bound));
        let max = w.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        assert!(
            max > 0.99 * bound,
            "uniform over the whole range: {max} vs {bound}"
        );
        assert_eq!(w, values(b.layers[0].weight.val()).unwrap());
        assert_eq!(a.layers.len(), 4);
    }

    /// N(0, 1) at 0: -0.5 ln(2 pi) = -0.918939 per dim; two dims: -1.837877.
    /// std e^0.5 at 1 from mean 0: -0.5 e^-1 - 0.5 - 0.918939 = -1.602880 per dim.
    /// Entropy per dim: 0.5 + 0.5 ln(2 pi) + log_std = 1.418939 (+ 0.5 for log_std 0.5).
    #[test]
    fn gaussian_log_prob_and_entropy() {
        let dev = device();
        let zeros = || matrix(vec![0.0; 2], 1, 2, &dev);
        let lp = values(log_prob(zeros(), zeros(), vector(vec![0.0; 2], &dev))).unwrap();
        assert!((lp[0] + 1.837877).abs() < 1e-5, "{lp:?}");
        let ones = matrix(vec![1.0; 2], 1, 2, &dev);
        let lp = values(log_prob(ones, zeros(), vector(vec![0.5; 2], &dev))).unwrap();
        assert!((lp[0] - 2.0 * -1.60288).abs() < 1e-5, "{lp:?}");
        let h = values(entropy(vector(vec![0.0; 2], &dev))).unwrap();
        assert!((h[0] - 2.0 * 1.418939).abs() < 1e-5);
        let h = values(entropy(vector(vec![0.5; 2], &dev))).unwrap();
        assert!((h[0] - 2.0 * 1.918939).abs() < 1e-5);
    }
}
