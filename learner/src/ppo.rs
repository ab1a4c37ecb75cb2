//! PPO with the clipped value loss and the adaptive learning rate (rsl_rl's defaults), and the
//! estimator's regression on the same rollout: the Python learner's `PPO.update` and
//! `EstimatorLearning.update`.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;

use crate::mirror::{ActorMirror, mirror_loss};
use crate::nets::{self, ActorCritic, Estimator, matrix};
use crate::rng::Rng;
use crate::schedule::adaptive_learning_rate;
use crate::storage::RolloutStorage;

/// PPO hyper-parameters (Table III of the paper, rsl_rl's defaults otherwise).
#[derive(Debug, Clone, PartialEq)]
pub struct PpoConfig {
    /// Passes over the rollout per update (5).
    pub num_learning_epochs: usize,
    /// Mini-batches per pass (4).
    pub num_mini_batches: usize,
    /// Ratio and value clip (0.2).
    pub clip_param: f32,
    /// Discount (0.99).
    pub gamma: f32,
    /// GAE lambda (0.95).
    pub lam: f32,
    /// Weight of the value loss (1.0).
    pub value_loss_coef: f64,
    /// Weight of the entropy bonus (0.01).
    pub entropy_coef: f64,
    /// Initial Adam learning rate (1e-3).
    pub learning_rate: f64,
    /// Global gradient-norm clip (1.0).
    pub max_grad_norm: f64,
    /// Clip the value update like the ratio (true).
    pub use_clipped_value_loss: bool,
    /// KL-driven learning rate (true) or fixed.
    pub adaptive: bool,
    /// Target KL of the adaptive schedule (0.01).
    pub desired_kl: f64,
    /// Normalise advantages over the batch (true).
    pub normalize_advantage: bool,
    /// Floor of every action dim's std after each Adam step (0: none; decision record 0028).
    pub min_action_std: f64,
    /// |mean action| past which the bound loss pays (0: no bound loss; decision record 0031).
    pub action_mean_bound: f64,
    /// Weight of the bound loss, `mean(sum_i max(|mu_i| - bound, 0)^2)`.
    pub bound_loss_coef: f64,
    /// Weight of the mirror loss, `mean((mu(M x) - M mu(x))^2)` (0: none; decision record
    /// 0033). It needs the mirror maps: [`Ppo::set_mirror`].
    pub mirror_loss_coef: f64,
    /// Threads sharing each mini-batch's forward and backward passes (1): each takes a slice
    /// of the rows, and their gradients are summed before the clip and the Adam step, so the
    /// update is the one-thread update up to float rounding.
    pub update_threads: usize,
}

impl Default for PpoConfig {
    fn default() -> Self {
        Self {
            num_learning_epochs: 5,
            num_mini_batches: 4,
            clip_param: 0.2,
            gamma: 0.99,
            lam: 0.95,
            value_loss_coef: 1.0,
            entropy_coef: 0.01,
            learning_rate: 1e-3,
            max_grad_norm: 1.0,
            use_clipped_value_loss: true,
            adaptive: true,
            desired_kl: 0.01,
            normalize_advantage: true,
            min_action_std: 0.0,
            action_mean_bound: 0.0,
            bound_loss_coef: 0.0,
            mirror_loss_coef: 0.0,
            update_threads: 1,
        }
    }
}

/// Estimator hyper-parameters (Table III).
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorConfig {
    /// Hidden sizes ([256, 128]).
    pub hidden_dims: Vec<usize>,
    /// Adam learning rate (1e-4).
    pub learning_rate: f64,
    /// Samples per step (768).
    pub mini_batch_size: usize,
    /// Passes over the rollout per iteration (5).
    pub num_epochs: usize,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            hidden_dims: vec![256, 128],
            learning_rate: 1e-4,
            mini_batch_size: 768,
            num_epochs: 5,
        }
    }
}

/// Mean losses of one update, and the learning rate it ended with.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UpdateStats {
    /// Mean clipped value loss.
    pub value_loss: f64,
    /// Mean clipped surrogate loss.
    pub surrogate_loss: f64,
    /// Mean entropy.
    pub entropy: f64,
    /// Mean KL(old || new) before each step.
    pub kl: f64,
    /// The learning rate after the update.
    pub learning_rate: f64,
    /// Mean action std after the update.
    pub action_std: f64,
    /// Mean bound loss before each step, when the config has one (decision record 0031).
    pub bound_loss: Option<f64>,
    /// Mean mirror loss before each step, when the config has one (decision record 0033).
    pub mirror_loss: Option<f64>,
}

/// Clipped surrogate: `mean(max(-A r, -A clamp(r, 1 - c, 1 + c)))` with `r = exp(lp - lp_old)`.
pub fn surrogate_loss(
    log_prob: Tensor<1>,
    old_log_prob: Tensor<1>,
    advantages: Tensor<1>,
    clip: f32,
) -> Tensor<1> {
    let ratio = (log_prob - old_log_prob).exp();
    let neg_adv = advantages.neg();
    let s1 = neg_adv.clone() * ratio.clone();
    let s2 = neg_adv * ratio.clamp(1.0 - clip, 1.0 + clip);
    s1.max_pair(s2).mean()
}

/// Whether `cfg` adds the bound loss (both its bound and its weight set).
fn bounded(cfg: &PpoConfig) -> bool {
    cfg.action_mean_bound > 0.0 && cfg.bound_loss_coef > 0.0
}

/// Bound loss: `mean over the batch of sum_i max(|mu_i| - bound, 0)^2`, zero inside the bound.
pub fn bound_loss(mean: Tensor<2>, bound: f32) -> Tensor<1> {
    (mean.abs().sub_scalar(bound))
        .clamp_min(0.0)
        .square()
        .sum_dim(1)
        .mean()
}

/// Value loss: `mean(max((V - R)^2, (V_old + clamp(V - V_old, -c, c) - R)^2))` when clipped,
/// `mean((V - R)^2)` otherwise.
pub fn value_loss(
    values: Tensor<1>,
    old_values: Tensor<1>,
    returns: Tensor<1>,
    clip: f32,
    clipped: bool,
) -> Tensor<1> {
    let plain = (values.clone() - returns.clone()).square();
    if !clipped {
        return plain.mean();
    }
    let v_clipped = old_values.clone() + (values - old_values).clamp(-clip, clip);
    plain.max_pair((v_clipped - returns).square()).mean()
}

/// Mean KL(old || new) over a batch of diagonal Gaussians ([`crate::schedule::gaussian_kl`]
/// on tensors): f32 [B, A] each (`sigma_new` may be [1, A]).
pub fn mean_gaussian_kl(
    mu_old: Tensor<2>,
    sigma_old: Tensor<2>,
    mu_new: Tensor<2>,
    sigma_new: Tensor<2>,
) -> f64 {
    let log_term = (sigma_new.clone() / sigma_old.clone())
        .add_scalar(1e-5)
        .log();
    let quad =
        (sigma_old.square() + (mu_old - mu_new).square()) / sigma_new.square().mul_scalar(2.0);
    let kl: f32 = (log_term + quad)
        .sub_scalar(0.5)
        .sum_dim(1)
        .mean()
        .into_scalar();
    f64::from(kl)
}

struct SquaredNorm<'a> {
    grads: &'a GradientsParams,
    sum: f64,
}

impl ModuleVisitor for SquaredNorm<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            self.sum += f64::from(g.square().sum().into_scalar::<f32>());
        }
    }
}

struct Scale<'a> {
    grads: &'a mut GradientsParams,
    coef: f64,
}

impl ModuleVisitor for Scale<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.remove::<D>(param.id) {
            self.grads.register(param.id, g.mul_scalar(self.coef));
        }
    }
}

/// torch's `clip_grad_norm_`: when the global L2 norm of `module`'s gradients exceeds
/// `max_norm`, scale every gradient by `max_norm / (norm + 1e-6)`. Returns the norm before.
/// (burn's own `GradientClipping::Norm` clips each parameter tensor separately.)
pub fn clip_grad_norm<M: Module>(grads: &mut GradientsParams, module: &M, max_norm: f64) -> f64 {
    let mut sq = SquaredNorm { grads, sum: 0.0 };
    module.visit(&mut sq);
    let norm = sq.sum.sqrt();
    let coef = max_norm / (norm + 1e-6);
    if coef < 1.0 {
        module.visit(&mut Scale { grads, coef });
    }
    norm
}

/// torch's Adam (eps 1e-8, betas 0.9 / 0.999; burn's default eps is 1e-5).
fn adam() -> ModuleOptimizer {
    AdamConfig::new().with_epsilon(1e-8).init()
}

/// Rows `perm` of the column block `[from, to)` of the rollout, as one tensor.
fn shuffled(
    storage: &RolloutStorage,
    from: usize,
    to: usize,
    perm: &[u32],
    device: &Device,
) -> Tensor<2> {
    let w = storage.layout.width();
    let mut out = Vec::with_capacity(perm.len() * (to - from));
    for &i in perm {
        out.extend_from_slice(&storage.data[i as usize * w..][from..to]);
    }
    matrix(out, perm.len(), to - from, device)
}

/// The Adam state of `optimizer` (moments and step count per parameter id) as burn's record.
fn optimizer_bytes(optimizer: &ModuleOptimizer) -> crate::Result<Vec<u8>> {
    let bytes = optimizer
        .into_bytes()
        .map_err(|e| crate::Error::Record(e.to_string()))?;
    Ok(bytes.to_vec())
}

/// `optimizer` with the state of [`optimizer_bytes`]; the networks must carry the parameter ids
/// the state was saved with (checkpoints restore them).
fn load_optimizer(optimizer: ModuleOptimizer, bytes: &[u8]) -> crate::Result<ModuleOptimizer> {
    optimizer
        .from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes.to_vec()))
        .map_err(|e| crate::Error::Record(e.to_string()))
}

/// The PPO update over a [`RolloutStorage`].
pub struct Ppo {
    /// Hyper-parameters.
    pub cfg: PpoConfig,
    /// The current learning rate.
    pub learning_rate: f64,
    optimizer: ModuleOptimizer,
    mirror: Option<ActorMirror>,
}

impl Ppo {
    /// One Adam over every parameter of the actor-critic.
    pub fn new(cfg: PpoConfig) -> Self {
        Self {
            learning_rate: cfg.learning_rate,
            cfg,
            optimizer: adam(),
            mirror: None,
        }
    }

    /// The mirror maps the mirror loss needs (from the session's spec).
    pub fn set_mirror(&mut self, mirror: ActorMirror) {
        self.mirror = Some(mirror);
    }

    /// The mirror the update uses: set and weighted.
    fn active_mirror(&self) -> Option<&ActorMirror> {
        self.mirror
            .as_ref()
            .filter(|_| self.cfg.mirror_loss_coef > 0.0)
    }

    /// The optimiser's state, for a checkpoint.
    pub fn optimizer_bytes(&self) -> crate::Result<Vec<u8>> {
        optimizer_bytes(&self.optimizer)
    }

    /// Restore the optimiser's state from [`Ppo::optimizer_bytes`].
    pub fn load_optimizer(&mut self, bytes: &[u8]) -> crate::Result<()> {
        let fresh = std::mem::replace(&mut self.optimizer, adam());
        self.optimizer = load_optimizer(fresh, bytes)?;
        Ok(())
    }

    /// Run the epochs over `storage` (its returns computed); `rng` draws the permutations.
    /// Returns the updated networks and the mean statistics.
    pub fn update(
        &mut self,
        mut ac: ActorCritic,
        storage: &RolloutStorage,
        rng: &mut Rng,
        device: &Device,
    ) -> (ActorCritic, UpdateStats) {
        let cfg = self.cfg.clone();
        let l = storage.layout;
        let n = storage.num_steps * storage.num_envs;
        let size = n / cfg.num_mini_batches.max(1);
        let first = l.actor_col();
        let mut stats = UpdateStats::default();
        let mut count = 0usize;
        let mut bound_sum = 0.0;
        let mut mirror_sum = 0.0;
        let mirror = self.active_mirror().cloned();
        for _ in 0..cfg.num_learning_epochs {
            let rows = shuffled(storage, first, l.width(), &rng.permutation(n), device);
            for i in 0..cfg.num_mini_batches {
                let batch = rows
                    .clone()
                    .slice([i * size..(i + 1) * size, 0..l.width() - first]);
                let part = mini_batch(&ac, batch, storage, &cfg, mirror.as_ref(), device);
                if cfg.adaptive && cfg.desired_kl > 0.0 {
                    self.learning_rate = adaptive_learning_rate(
                        self.learning_rate,
                        part.kl,
                        cfg.desired_kl,
                        1e-5,
                        1e-2,
                    );
                }
                stats.value_loss += part.value_loss;
                stats.surrogate_loss += part.surrogate_loss;
                stats.entropy += part.entropy;
                stats.kl += part.kl;
                bound_sum += part.bound_loss;
                mirror_sum += part.mirror_loss;
                count += 1;
                let mut grads = part.grads;
                clip_grad_norm(&mut grads, &ac, cfg.max_grad_norm);
                ac = self.optimizer.step(self.learning_rate, ac, grads);
                if cfg.min_action_std > 0.0 {
                    ac = floor_log_std(ac, cfg.min_action_std.ln() as f32);
                }
            }
        }
        let c = count.max(1) as f64;
        stats.value_loss /= c;
        stats.surrogate_loss /= c;
        stats.entropy /= c;
        stats.kl /= c;
        stats.bound_loss = bounded(&cfg).then_some(bound_sum / c);
        stats.mirror_loss = mirror.is_some().then_some(mirror_sum / c);
        stats.learning_rate = self.learning_rate;
        stats.action_std = f64::from(ac.log_std.val().exp().mean().into_scalar::<f32>());
        (ac, stats)
    }
}

/// `ac` with every log-std raised to at least `min_log_std`: a projection after the step, so
/// the parameter (and its Adam state, keyed by its id) stays the one trained.
fn floor_log_std(mut ac: ActorCritic, min_log_std: f32) -> ActorCritic {
    ac.log_std = ac
        .log_std
        .map(|t| t.clamp_min(min_log_std).detach().require_grad());
    ac
}

/// One mini-batch's gradients of the PPO loss and its figures (KL and losses as batch means).
struct MiniBatch {
    grads: GradientsParams,
    value_loss: f64,
    surrogate_loss: f64,
    entropy: f64,
    kl: f64,
    bound_loss: f64,
    mirror_loss: f64,
}

/// The PPO loss of `batch` (its rows: the layout's columns from the actor's) split over
/// `cfg.update_threads` threads: each computes its rows' loss weighted by their share, so the
/// summed gradients are the whole batch's mean loss's.
fn mini_batch(
    ac: &ActorCritic,
    batch: Tensor<2>,
    storage: &RolloutStorage,
    cfg: &PpoConfig,
    mirror: Option<&ActorMirror>,
    device: &Device,
) -> MiniBatch {
    let rows = batch.dims()[0];
    let threads = cfg.update_threads.clamp(1, rows.max(1));
    let bounds: Vec<(usize, usize)> = (0..threads)
        .map(|t| (rows * t / threads, rows * (t + 1) / threads))
        .collect();
    let mut parts: Vec<MiniBatch> = std::thread::scope(|scope| {
        let handles: Vec<_> = bounds
            .iter()
            .skip(1)
            .map(|&(a, b)| {
                // A fork has its own autodiff graph with the same parameter ids: two backward
                // passes through one graph's shared parameter nodes deadlock in burn.
                let ac = ac.clone().fork(device);
                let part = batch.clone().slice([a..b, 0..batch.dims()[1]]);
                let weight = (b - a) as f64 / rows as f64;
                scope.spawn(move || share_loss(&ac, part, storage, cfg, mirror, weight))
            })
            .collect();
        let (a, b) = bounds[0];
        let first = batch.clone().slice([a..b, 0..batch.dims()[1]]);
        let mut parts = vec![share_loss(
            ac,
            first,
            storage,
            cfg,
            mirror,
            (b - a) as f64 / rows as f64,
        )];
        // A panic in a share is a bug in the update: the same code as the first share's.
        parts.extend(
            handles
                .into_iter()
                .map(|h| h.join().expect("update thread")),
        );
        parts
    });
    let mut total = parts.remove(0);
    for part in parts {
        total.value_loss += part.value_loss;
        total.surrogate_loss += part.surrogate_loss;
        total.entropy += part.entropy;
        total.kl += part.kl;
        total.bound_loss += part.bound_loss;
        total.mirror_loss += part.mirror_loss;
        let mut from = part.grads;
        ac.visit(&mut AddGrads {
            into: &mut total.grads,
            from: &mut from,
        });
    }
    total
}

/// `weight` times the PPO loss of `rows` (the entropy bonus too, so that the shares' weights
/// add up to one of it), its gradients, and its figures times `weight`.
fn share_loss(
    ac: &ActorCritic,
    rows: Tensor<2>,
    storage: &RolloutStorage,
    cfg: &PpoConfig,
    mirror: Option<&ActorMirror>,
    weight: f64,
) -> MiniBatch {
    let l = storage.layout;
    let first = l.actor_col();
    let col = |c: usize, w: usize| {
        rows.clone()
            .slice([0..rows.dims()[0], c - first..c - first + w])
    };
    let vec = |c: usize| col(c, 1).squeeze_dim::<1>(1);
    let actor_obs = col(l.actor_col(), l.actor_obs);
    let mean = ac.actor.forward(actor_obs.clone());
    let log_std = ac.log_std.val();
    let lp = nets::log_prob(
        col(l.actions_col(), l.actions),
        mean.clone(),
        log_std.clone(),
    );
    let entropy = nets::entropy(log_std.clone());
    let values = ac.value(col(l.critic_col(), l.critic_obs));
    let kl = mean_gaussian_kl(
        col(l.mu_col(), l.actions),
        col(l.sigma_col(), l.actions),
        mean.clone().detach(),
        log_std.detach().exp().unsqueeze::<2>(),
    );
    let surrogate = surrogate_loss(
        lp,
        vec(l.log_prob_col()),
        vec(l.advantage_col()),
        cfg.clip_param,
    );
    let v_loss = value_loss(
        values,
        vec(l.value_col()),
        vec(l.return_col()),
        cfg.clip_param,
        cfg.use_clipped_value_loss,
    );
    let figures = (
        f64::from(v_loss.clone().into_scalar::<f32>()),
        f64::from(surrogate.clone().into_scalar::<f32>()),
        f64::from(entropy.clone().into_scalar::<f32>()),
    );
    let mut loss =
        surrogate + v_loss.mul_scalar(cfg.value_loss_coef) - entropy.mul_scalar(cfg.entropy_coef);
    let mut bound_figure = 0.0;
    if bounded(cfg) {
        let b_loss = bound_loss(mean.clone(), cfg.action_mean_bound as f32);
        bound_figure = f64::from(b_loss.clone().into_scalar::<f32>());
        loss = loss + b_loss.mul_scalar(cfg.bound_loss_coef);
    }
    let mut mirror_figure = 0.0;
    if let Some(m) = mirror {
        let device = actor_obs.device();
        let mirrored = ac
            .actor
            .forward(actor_obs.matmul(m.actor_obs.matrix(&device)));
        let m_loss = mirror_loss(mean, mirrored, m.actions.matrix(&device));
        mirror_figure = f64::from(m_loss.clone().into_scalar::<f32>());
        loss = loss + m_loss.mul_scalar(cfg.mirror_loss_coef);
    }
    let loss = loss.mul_scalar(weight);
    MiniBatch {
        grads: GradientsParams::from_grads(loss.backward(), ac),
        value_loss: weight * figures.0,
        surrogate_loss: weight * figures.1,
        entropy: weight * figures.2,
        kl: weight * kl,
        bound_loss: weight * bound_figure,
        mirror_loss: weight * mirror_figure,
    }
}

/// Adds `from`'s gradient of each parameter into `into`'s.
struct AddGrads<'a> {
    into: &'a mut GradientsParams,
    from: &'a mut GradientsParams,
}

impl ModuleVisitor for AddGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let sum = match (
            self.into.remove::<D>(param.id),
            self.from.remove::<D>(param.id),
        ) {
            (Some(a), Some(b)) => a + b,
            (Some(g), None) | (None, Some(g)) => g,
            (None, None) => return,
        };
        self.into.register(param.id, sum);
    }
}

/// MSE regression of the estimate on the labels from the stored histories.
pub struct EstimatorLearning {
    /// Hyper-parameters.
    pub cfg: EstimatorConfig,
    optimizer: ModuleOptimizer,
}

impl EstimatorLearning {
    /// Adam over the estimator's parameters.
    pub fn new(cfg: EstimatorConfig) -> Self {
        Self {
            cfg,
            optimizer: adam(),
        }
    }

    /// The optimiser's state, for a checkpoint.
    pub fn optimizer_bytes(&self) -> crate::Result<Vec<u8>> {
        optimizer_bytes(&self.optimizer)
    }

    /// Restore the optimiser's state from [`EstimatorLearning::optimizer_bytes`].
    pub fn load_optimizer(&mut self, bytes: &[u8]) -> crate::Result<()> {
        let fresh = std::mem::replace(&mut self.optimizer, adam());
        self.optimizer = load_optimizer(fresh, bytes)?;
        Ok(())
    }

    /// Run the epochs; return the updated estimator and the mean MSE. Batch k of an epoch is
    /// `perm[k * B .. (k + 1) * B]`, as many whole batches as fit (one batch of every sample
    /// when fewer than B).
    pub fn update(
        &mut self,
        mut estimator: Estimator,
        storage: &RolloutStorage,
        rng: &mut Rng,
        device: &Device,
    ) -> (Estimator, f64) {
        let l = storage.layout;
        let n = storage.num_steps * storage.num_envs;
        let b = self.cfg.mini_batch_size.min(n).max(1);
        let (mut total, mut count) = (0.0, 0usize);
        for _ in 0..self.cfg.num_epochs {
            let rows = shuffled(
                storage,
                0,
                l.actor_col() + l.history,
                &rng.permutation(n),
                device,
            );
            for k in 0..n / b {
                let r = k * b..(k + 1) * b;
                let labels = rows.clone().slice([r.clone(), 0..l.labels]);
                let history = rows.clone().slice([r, l.labels..l.labels + l.history]);
                let loss = (estimator.forward(history) - labels).square().mean();
                total += f64::from(loss.clone().into_scalar::<f32>());
                count += 1;
                let grads = GradientsParams::from_grads(loss.backward(), &estimator);
                estimator = self
                    .optimizer
                    .step(self.cfg.learning_rate, estimator, grads);
            }
        }
        (estimator, total / count.max(1) as f64)
    }
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::nets::{device, values, vector};
    use crate::storage::{Layout, Step};

    fn scalar(x: Tensor<1>) -> f32 {
        x.into_scalar()
    }

    /// ratios 1.5 and 0.5 (clip 0.2), advantages 1 and -1:
    /// unclipped -A r = [-1.5, 0.5], clipped -A clamp(r) = [-1.2, 0.8]; max = [-1.2, 0.8],
    /// mean -0.2. (Clipping is pessimistic: both samples take the clipped term.)
    #[test]
    fn surrogate_loss_on_known_numbers() {
        let dev = device();
        let v = |x: &[f32]| vector(x.to_vec(), &dev);
        let loss = surrogate_loss(
            v(&[1.5f32.ln(), 0.5f32.ln()]),
            v(&[0.0, 0.0]),
            v(&[1.0, -1.0]),
            0.2,
        );
        assert!(
            (scalar(loss.clone()) + 0.2).abs() < 1e-6,
            "{}",
            scalar(loss)
        );
        // Inside the clip range nothing is clipped: ratio 1.1, A = 2: -2.2.
        let loss = surrogate_loss(v(&[1.1f32.ln()]), v(&[0.0]), v(&[2.0]), 0.2);
        assert!((scalar(loss) + 2.2).abs() < 1e-6);
    }

    /// values [1, 0], old [0.5, 0.5], returns [2, 0], clip 0.2:
    /// plain (V - R)^2 = [1, 0]; V_clipped = [0.7, 0.3], (V_c - R)^2 = [1.69, 0.09];
    /// max = [1.69, 0.09], mean 0.89; unclipped mean 0.5.
    #[test]
    fn value_loss_on_known_numbers() {
        let dev = device();
        let v = |x: &[f32]| vector(x.to_vec(), &dev);
        let clipped = value_loss(v(&[1.0, 0.0]), v(&[0.5, 0.5]), v(&[2.0, 0.0]), 0.2, true);
        assert!((scalar(clipped) - 0.89).abs() < 1e-6);
        let plain = value_loss(v(&[1.0, 0.0]), v(&[0.5, 0.5]), v(&[2.0, 0.0]), 0.2, false);
        assert!((scalar(plain) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn batch_kl_matches_the_scalar_formula() {
        let dev = device();
        let m = |x: &[f32]| matrix(x.to_vec(), 2, 2, &dev);
        let kl = mean_gaussian_kl(
            m(&[0.0; 4]),
            m(&[1.0; 4]),
            m(&[1.0, 0.0, 0.0, 0.0]),
            m(&[1.0, 2.0, 1.0, 1.0]),
        );
        // Row 0: 0.818162 (see schedule's test); row 1: 2 ln(1 + 1e-5) = 2e-5.
        assert!((kl - (0.818162 + 2e-5) / 2.0).abs() < 1e-5, "{kl}");
    }

    #[derive(Module, Debug)]
    struct Two {
        a: Param<Tensor<1>>,
        b: Param<Tensor<1>>,
    }

    /// Gradients [3, 4] (norm 5) clipped to 1 become [0.6, 0.8]; [0.3, 0.4] stay.
    #[test]
    fn grad_norm_clip_scales_globally() {
        let dev = device();
        let m = Two {
            a: Param::from_tensor(vector(vec![1.0], &dev)),
            b: Param::from_tensor(vector(vec![1.0], &dev)),
        };
        for (ka, kb, expected) in [(3.0f64, 4.0f64, [0.6, 0.8]), (0.3, 0.4, [0.3, 0.4])] {
            let loss = m.a.val().mul_scalar(ka) + m.b.val().mul_scalar(kb);
            let mut grads = GradientsParams::from_grads(loss.backward(), &m);
            let norm = clip_grad_norm(&mut grads, &m, 1.0);
            assert!((norm - (ka * ka + kb * kb).sqrt()).abs() < 1e-5);
            let ga = values(grads.get::<1>(m.a.id).unwrap()).unwrap();
            let gb = values(grads.get::<1>(m.b.id).unwrap()).unwrap();
            assert!(
                (ga[0] - expected[0]).abs() < 1e-5 && (gb[0] - expected[1]).abs() < 1e-5,
                "{ga:?} {gb:?}"
            );
        }
    }

    /// A 4-step x 8-env rollout of one-dim actions drawn from N(0, 1) (the log-probabilities
    /// say so), every step ending its episode: env e takes `actions[e % len]` and earns
    /// `reward(action)`. Returns computed.
    fn one_action_rollout(actions: &[f32], reward: impl Fn(f32) -> f32) -> RolloutStorage {
        let layout = Layout {
            labels: 1,
            actor_obs: 2,
            history: 1,
            critic_obs: 1,
            actions: 1,
        };
        let (steps, envs) = (4, 8);
        let mut storage = RolloutStorage::new(steps, envs, layout);
        let taken: Vec<f32> = (0..envs).map(|e| actions[e % actions.len()]).collect();
        let rewards: Vec<f32> = taken.iter().map(|&a| reward(a)).collect();
        // log N(a; 0, 1) = -a^2 / 2 - 0.918939.
        let log_prob: Vec<f32> = taken.iter().map(|a| -0.5 * a * a - 0.918_938_5).collect();
        for _ in 0..steps {
            storage
                .add(&Step {
                    actor_obs: &vec![0.5; envs * 2],
                    critic_obs: &vec![0.5; envs],
                    labels: &vec![0.0; envs],
                    actions: &taken,
                    log_prob: &log_prob,
                    mu: &vec![0.0; envs],
                    sigma: &vec![1.0; envs],
                    values: &vec![0.0; envs],
                    rewards: &rewards,
                    dones: &vec![true; envs],
                })
                .unwrap();
        }
        storage.compute_returns(&vec![0.0; envs], 0.99, 0.95, true);
        storage
    }

    /// A rollout where action +1 always earned advantage +1 and action -1 advantage -1: one
    /// update must raise the actor's mean (towards +1).
    #[test]
    fn update_prefers_the_advantaged_action() {
        let dev = device();
        let mut rng = Rng::new(0);
        let ac = ActorCritic::new(2, 1, 1, &[8], &[8], 1.0, &mut rng, &dev);
        let storage = one_action_rollout(&[1.0, -1.0], |a| a);
        let x = || matrix(vec![0.5, 0.5], 1, 2, &dev);
        let before = values(ac.actor.forward(x())).unwrap()[0];
        let mut ppo = Ppo::new(PpoConfig {
            adaptive: false,
            ..PpoConfig::default()
        });
        let (ac, stats) = ppo.update(ac, &storage, &mut rng, &dev);
        let after = values(ac.actor.forward(x())).unwrap()[0];
        assert!(after > before + 1e-3, "mean {before} -> {after}");
        assert!(stats.value_loss > 0.0 && stats.kl >= 0.0);
        assert_eq!(stats.learning_rate, 1e-3);
        // Entropy of one dim with log-std near 0: 1.4189 (the bonus moved it slightly).
        assert!((stats.entropy - 1.4189).abs() < 0.05, "{}", stats.entropy);
    }

    /// Actions near the mean earned +1 and far ones -1, so the update narrows the std: from 1.0
    /// it falls below 0.95 with no floor, and with a 0.95 floor it ends exactly there.
    #[test]
    fn the_std_floor_holds_where_the_update_would_narrow() {
        let dev = device();
        let storage = one_action_rollout(&[0.1, -0.1, 2.0, -2.0], |a| {
            if a.abs() < 1.0 { 1.0 } else { -1.0 }
        });
        let std_after = |min_action_std: f64| {
            let mut rng = Rng::new(0);
            let ac = ActorCritic::new(2, 1, 1, &[8], &[8], 1.0, &mut rng, &dev);
            let mut ppo = Ppo::new(PpoConfig {
                adaptive: false,
                learning_rate: 1e-2,
                entropy_coef: 0.0,
                min_action_std,
                ..PpoConfig::default()
            });
            let (_, stats) = ppo.update(ac, &storage, &mut rng, &dev);
            stats.action_std
        };
        let free = std_after(0.0);
        assert!(free < 0.95, "std with no floor {free}");
        let floored = std_after(0.95);
        assert!(
            (floored - 0.95).abs() < 1e-5,
            "std with a 0.95 floor {floored}"
        );
    }

    /// Bound 10: row 1 pays (12 - 10)^2 = 4, row 2 pays (11.5 - 10)^2 = 2.25; mean 3.125.
    #[test]
    fn bound_loss_on_known_numbers() {
        let dev = device();
        let mu = matrix(vec![12.0, -3.0, 0.0, -11.5], 2, 2, &dev);
        let at = |b: f32| values(bound_loss(mu.clone(), b)).unwrap()[0];
        assert!((at(10.0) - 3.125).abs() < 1e-6, "{}", at(10.0));
        assert_eq!(at(20.0), 0.0);
    }

    /// Every reward equal, so the advantages are 0, and no entropy bonus: only the mirror loss
    /// moves the actor. Its map swaps the two inputs and the two actions; after a few updates
    /// the actor answers a swapped input with the swapped action, where before it did not.
    #[test]
    fn the_mirror_loss_alone_makes_the_actor_symmetric() {
        use crate::mirror::{ActorMirror, SignedPermutation};
        let dev = device();
        let layout = Layout {
            labels: 1,
            actor_obs: 2,
            history: 1,
            critic_obs: 1,
            actions: 2,
        };
        let (steps, envs) = (4, 64);
        let mut storage = RolloutStorage::new(steps, envs, layout);
        let mut rng = Rng::new(3);
        for _ in 0..steps {
            let obs: Vec<f32> = (0..envs * 2).map(|_| rng.normal()).collect();
            storage
                .add(&Step {
                    actor_obs: &obs,
                    critic_obs: &vec![0.5; envs],
                    labels: &vec![0.0; envs],
                    actions: &vec![0.0; envs * 2],
                    log_prob: &vec![-1.837_877; envs],
                    mu: &vec![0.0; envs * 2],
                    sigma: &vec![1.0; envs * 2],
                    values: &vec![0.0; envs],
                    rewards: &vec![1.0; envs],
                    dones: &vec![true; envs],
                })
                .unwrap();
        }
        storage.compute_returns(&vec![0.0; envs], 0.99, 0.95, true);
        let swap = SignedPermutation {
            index: vec![1, 0],
            sign: vec![1.0, 1.0],
        };
        let mirror = ActorMirror {
            actor_obs: swap.clone(),
            actions: swap,
        };
        let probe: Vec<f32> = (0..64).map(|_| rng.normal()).collect();
        let asymmetry = |ac: &ActorCritic| {
            let x = matrix(probe.clone(), 32, 2, &dev);
            let m = mirror.actions.matrix(&dev);
            let mirrored = ac.actor.forward(x.clone().matmul(m.clone()));
            values(mirror_loss(ac.actor.forward(x), mirrored, m)).unwrap()[0]
        };
        let mut ac = ActorCritic::new(2, 1, 2, &[16], &[8], 1.0, &mut Rng::new(0), &dev);
        let before = asymmetry(&ac);
        let mut ppo = Ppo::new(PpoConfig {
            adaptive: false,
            learning_rate: 1e-2,
            entropy_coef: 0.0,
            mirror_loss_coef: 1.0,
            ..PpoConfig::default()
        });
        let (free, stats) = ppo.update(ac.clone(), &storage, &mut rng, &dev);
        assert!(stats.mirror_loss.is_none(), "no maps, no mirror term");
        assert_eq!(
            asymmetry(&free),
            before,
            "no mirror term, no change to the actor"
        );
        ppo.set_mirror(mirror.clone());
        let mut figure = None;
        for _ in 0..10 {
            let (next, stats) = ppo.update(ac, &storage, &mut rng, &dev);
            ac = next;
            figure = stats.mirror_loss;
        }
        assert!(figure.is_some_and(|f| f > 0.0), "{figure:?}");
        let after = asymmetry(&ac);
        assert!(before > 1e-3 && after < 0.1 * before, "{before} -> {after}");
    }

    /// Every reward equal: the advantages are 0 and the entropy bonus is off, so only the bound
    /// loss moves the actor's mean. With no bound it stays put; with a bound below the mean it
    /// falls towards the bound.
    #[test]
    fn the_bound_loss_alone_pulls_an_outlying_mean_in() {
        let dev = device();
        let storage = one_action_rollout(&[0.1, -0.1, 2.0, -2.0], |_| 1.0);
        let x = || matrix(vec![0.5, 0.5], 1, 2, &dev);
        let mean_after = |coef: f64| {
            let mut rng = Rng::new(0);
            let ac = ActorCritic::new(2, 1, 1, &[8], &[8], 1.0, &mut rng, &dev);
            let before = values(ac.actor.forward(x())).unwrap()[0];
            let mut ppo = Ppo::new(PpoConfig {
                adaptive: false,
                learning_rate: 1e-2,
                entropy_coef: 0.0,
                action_mean_bound: 1e-3,
                bound_loss_coef: coef,
                ..PpoConfig::default()
            });
            let (ac, stats) = ppo.update(ac, &storage, &mut rng, &dev);
            let after = values(ac.actor.forward(x())).unwrap()[0];
            (before, after, stats.bound_loss)
        };
        let (before, free, no_figure) = mean_after(0.0);
        assert!(
            before.abs() > 0.05,
            "the fresh mean {before} sits inside the bound"
        );
        assert_eq!(free, before);
        assert_eq!(no_figure, None);
        let (_, bounded, figure) = mean_after(1.0);
        assert!(
            bounded.abs() < before.abs() - 1e-3,
            "mean {before} -> {bounded}"
        );
        // (|mu| - 0.001)^2 averaged over the updates: positive, at most the first one's.
        let figure = figure.expect("a bound loss figure");
        let first = (f64::from(before.abs()) - 1e-3).powi(2);
        assert!(
            figure > 0.0 && figure <= first + 1e-6,
            "{figure} vs {first}"
        );
    }

    /// Splitting each mini-batch over threads changes float rounding only: on a random rollout
    /// (varied observations, actions, rewards, old means), one and three threads (shares of
    /// unequal size: 32 rows in 11, 11, 10) give the same weights, losses, KL and rate.
    #[test]
    fn an_update_split_over_threads_is_the_one_thread_update() {
        let dev = device();
        let layout = Layout {
            labels: 1,
            actor_obs: 3,
            history: 1,
            critic_obs: 2,
            actions: 2,
        };
        let mut draw = Rng::new(7);
        let (steps, envs) = (4, 32);
        let mut storage = RolloutStorage::new(steps, envs, layout);
        let mut noise =
            |n: usize, scale: f32| -> Vec<f32> { (0..n).map(|_| scale * draw.normal()).collect() };
        for _ in 0..steps {
            storage
                .add(&Step {
                    actor_obs: &noise(envs * 3, 1.0),
                    critic_obs: &noise(envs * 2, 1.0),
                    labels: &noise(envs, 1.0),
                    actions: &noise(envs * 2, 1.0),
                    log_prob: &noise(envs, 0.3).iter().map(|x| x - 2.8).collect::<Vec<_>>(),
                    mu: &noise(envs * 2, 0.1),
                    sigma: &vec![1.0; envs * 2],
                    values: &noise(envs, 0.5),
                    rewards: &noise(envs, 1.0),
                    dones: &vec![false; envs],
                })
                .unwrap();
        }
        storage.compute_returns(&vec![0.0; envs], 0.99, 0.95, true);
        let run = |threads: usize| {
            let mut rng = Rng::new(3);
            let ac = ActorCritic::new(3, 2, 2, &[16], &[16], 1.0, &mut rng, &dev);
            let mut ppo = Ppo::new(PpoConfig {
                num_mini_batches: 4,
                update_threads: threads,
                ..PpoConfig::default()
            });
            let (ac, stats) = ppo.update(ac, &storage, &mut rng, &dev);
            let probe = matrix(vec![0.3, -0.7, 1.1], 1, 3, &dev);
            (values(ac.actor.forward(probe)).unwrap(), stats)
        };
        let (one, a) = run(1);
        let (three, b) = run(3);
        for (x, y) in one.iter().zip(&three) {
            assert!((x - y).abs() < 1e-4, "{one:?} vs {three:?}");
        }
        for (x, y) in [
            (a.value_loss, b.value_loss),
            (a.surrogate_loss, b.surrogate_loss),
            (a.entropy, b.entropy),
            (a.kl, b.kl),
            (a.learning_rate, b.learning_rate),
        ] {
            assert!((x - y).abs() <= 1e-5 * x.abs().max(1.0), "{a:?} vs {b:?}");
        }
        // The update did something: the weights moved from their initial values.
        let mut rng = Rng::new(3);
        let fresh = ActorCritic::new(3, 2, 2, &[16], &[16], 1.0, &mut rng, &dev);
        let before = values(
            fresh
                .actor
                .forward(matrix(vec![0.3, -0.7, 1.1], 1, 3, &dev)),
        );
        assert!((before.unwrap()[0] - one[0]).abs() > 1e-3);
    }

    /// The adaptive rule runs inside the update: a rollout whose old means sit far from the
    /// policy's gives a KL above 2 kl*, so every mini-batch divides the rate by 1.5.
    #[test]
    fn update_shrinks_the_rate_on_a_large_kl() {
        let dev = device();
        let layout = Layout {
            labels: 1,
            actor_obs: 2,
            history: 1,
            critic_obs: 1,
            actions: 1,
        };
        let mut rng = Rng::new(2);
        let ac = ActorCritic::new(2, 1, 1, &[4], &[4], 1.0, &mut rng, &dev);
        let mut storage = RolloutStorage::new(1, 8, layout);
        storage
            .add(&Step {
                actor_obs: &[0.0; 16],
                critic_obs: &[0.0; 8],
                labels: &[0.0; 8],
                actions: &[0.0; 8],
                log_prob: &[0.0; 8],
                mu: &[5.0; 8],
                sigma: &[1.0; 8],
                values: &[0.0; 8],
                rewards: &[0.0; 8],
                dones: &[false; 8],
            })
            .unwrap();
        storage.compute_returns(&[0.0; 8], 0.99, 0.95, false);
        let cfg = PpoConfig {
            num_learning_epochs: 1,
            num_mini_batches: 2,
            ..PpoConfig::default()
        };
        let mut ppo = Ppo::new(cfg);
        let (_, stats) = ppo.update(ac, &storage, &mut rng, &dev);
        // KL ~ 25 / 2 per sample >> 0.02: two mini-batches, 1e-3 / 1.5^2.
        assert!(
            (stats.learning_rate - 1e-3 / 2.25).abs() < 1e-12,
            "{}",
            stats.learning_rate
        );
        assert!(stats.kl > 10.0);
    }

    /// The estimator's MSE falls when the labels are a fixed function of the history.
    #[test]
    fn estimator_learns_a_linear_label() {
        let dev = device();
        let layout = Layout {
            labels: 1,
            actor_obs: 2,
            history: 1,
            critic_obs: 1,
            actions: 1,
        };
        let mut rng = Rng::new(1);
        let est = Estimator::new(1, &[16], 1, &mut rng, &dev);
        let envs = 64;
        let mut storage = RolloutStorage::new(1, envs, layout);
        let h: Vec<f32> = (0..envs).map(|i| i as f32 / envs as f32).collect();
        let actor_obs: Vec<f32> = h.iter().flat_map(|&x| [x, 0.0]).collect();
        let labels: Vec<f32> = h.iter().map(|x| 2.0 * x - 0.5).collect();
        storage
            .add(&Step {
                actor_obs: &actor_obs,
                critic_obs: &vec![0.0; envs],
                labels: &labels,
                actions: &vec![0.0; envs],
                log_prob: &vec![0.0; envs],
                mu: &vec![0.0; envs],
                sigma: &vec![1.0; envs],
                values: &vec![0.0; envs],
                rewards: &vec![0.0; envs],
                dones: &vec![false; envs],
            })
            .unwrap();
        let cfg = EstimatorConfig {
            learning_rate: 1e-2,
            mini_batch_size: 16,
            ..Default::default()
        };
        let mut learning = EstimatorLearning::new(cfg);
        let (mut est, first) = learning.update(est, &storage, &mut rng, &dev);
        let mut last = first;
        for _ in 0..10 {
            (est, last) = learning.update(est, &storage, &mut rng, &dev);
        }
        assert!(last < 0.2 * first, "MSE {first} -> {last}");
    }
}
