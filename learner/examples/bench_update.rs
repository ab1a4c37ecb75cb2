//! Time one learner update (PPO + estimator epochs) on random data, as the Python learner runs it.
//!
//! 512 envs x 24 steps by default; actor 173 -> [512, 256, 128] -> 12 and critic 77 ->
//! [512, 256, 128] -> 1 (ELU), a learned log-std, one Adam over them, clipped surrogate, clipped
//! value loss, entropy bonus, global grad-norm clip 1.0, adaptive learning rate; 5 epochs x 4
//! mini-batches. Then the estimator 159 -> [256, 128] -> 14, 5 epochs of 768 samples (MSE, Adam
//! 1e-4). Threads come from `RAYON_NUM_THREADS` (both libraries size their matmul pools by it).
//!
//! ```text
//! RAYON_NUM_THREADS=1 target/release/examples/bench_update --lib burn
//! RAYON_NUM_THREADS=2 target/release/examples/bench_update --lib candle   # --features bench-candle
//! ```
//!
//! Prints one line: the median over `--repeats` updates (after one warm-up) of the PPO, estimator
//! and total milliseconds, in the format of tests/data/bench_update.py.

// The update's constants and helpers serve the candle path, built with bench-candle only.
#![cfg_attr(not(feature = "bench-candle"), allow(dead_code))]

use std::time::Instant;

const STEPS: usize = 24;
const ACTOR_IN: usize = 173;
const HISTORY: usize = 159;
const CRITIC_IN: usize = 77;
const LABELS: usize = 14;
const ACTIONS: usize = 12;
const HIDDEN: [usize; 3] = [512, 256, 128];
const EST_HIDDEN: [usize; 2] = [256, 128];
const EPOCHS: usize = 5;
const MINI_BATCHES: usize = 4;
const EST_BATCH: usize = 768;
const CLIP: f32 = 0.2;
const ENTROPY_COEF: f64 = 0.01;
const MAX_GRAD_NORM: f64 = 1.0;
const DESIRED_KL: f64 = 0.01;

// Column layout of one sample row (labels first, as in the Python storage).
const C_LABELS: usize = 0;
const C_ACTOR: usize = C_LABELS + LABELS;
const C_CRITIC: usize = C_ACTOR + ACTOR_IN;
const C_ACTIONS: usize = C_CRITIC + CRITIC_IN;
const C_LOGP: usize = C_ACTIONS + ACTIONS;
const C_MU: usize = C_LOGP + 1;
const C_SIGMA: usize = C_MU + ACTIONS;
const C_VALUES: usize = C_SIGMA + ACTIONS;
const C_ADV: usize = C_VALUES + 1;
const C_RET: usize = C_ADV + 1;
const WIDTH: usize = C_RET + 1;

/// SplitMix64: reproducible data and permutations without a dependency.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f32 {
        ((self.next_u64() >> 40) as f32 + 0.5) / (1u64 << 24) as f32
    }
    fn normal(&mut self) -> f32 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    }
    fn permutation(&mut self, n: usize) -> Vec<u32> {
        let mut p: Vec<u32> = (0..n as u32).collect();
        for i in (1..n).rev() {
            let j = (self.next_u64() % (i as u64 + 1)) as usize;
            p.swap(i, j);
        }
        p
    }
}

/// A rollout of random values like the Python bench's: [N, WIDTH] rows, advantages normalised.
fn rollout(n: usize) -> Vec<f32> {
    let mut rng = Rng(0);
    let mut data = vec![0.0f32; n * WIDTH];
    for row in data.chunks_mut(WIDTH) {
        for x in &mut row[..C_LOGP] {
            *x = rng.normal();
        }
        row[C_LOGP] = -rng.uniform() * 10.0;
        for x in &mut row[C_MU..C_SIGMA] {
            *x = rng.normal() * 0.1;
        }
        for x in &mut row[C_SIGMA..C_VALUES] {
            *x = 1.0;
        }
        row[C_VALUES] = rng.normal();
        row[C_ADV] = rng.normal();
        row[C_RET] = row[C_VALUES] + row[C_ADV];
    }
    data
}

fn adaptive(lr: f64, kl: f64) -> f64 {
    if kl > 2.0 * DESIRED_KL {
        (lr / 1.5).max(1e-5)
    } else if kl > 0.0 && kl < DESIRED_KL / 2.0 {
        (lr * 1.5).min(1e-2)
    } else {
        lr
    }
}

#[cfg(feature = "bench-candle")]
mod candle_impl {
    use super::*;
    use candle_core::{D, DType, Device, Result, Tensor, Var};
    use candle_nn::{AdamW, Linear, Module, Optimizer, ParamsAdamW, VarBuilder, VarMap};

    struct Mlp(Vec<Linear>);

    impl Mlp {
        fn new(vb: VarBuilder, dims: &[usize]) -> Result<Self> {
            let layers = dims
                .windows(2)
                .enumerate()
                .map(|(i, w)| candle_nn::linear(w[0], w[1], vb.pp(i.to_string())))
                .collect::<Result<Vec<_>>>()?;
            Ok(Self(layers))
        }
        fn forward(&self, x: &Tensor) -> Result<Tensor> {
            let mut x = x.clone();
            for (i, l) in self.0.iter().enumerate() {
                x = l.forward(&x)?;
                if i + 1 < self.0.len() {
                    x = x.elu(1.0)?;
                }
            }
            Ok(x)
        }
    }

    pub struct Bench {
        data: Tensor,
        n: usize,
        rng: Rng,
        actor: Mlp,
        critic: Mlp,
        log_std: Var,
        estimator: Mlp,
        vars: Vec<Var>,
        opt: AdamW,
        est_opt: AdamW,
        lr: f64,
    }

    fn dims(i: usize, hidden: &[usize], o: usize) -> Vec<usize> {
        std::iter::once(i)
            .chain(hidden.iter().copied())
            .chain([o])
            .collect()
    }

    impl Bench {
        pub fn new(envs: usize) -> Result<Self> {
            let dev = Device::Cpu;
            let n = envs * STEPS;
            let data = Tensor::from_vec(rollout(n), (n, WIDTH), &dev)?;
            let ac = VarMap::new();
            let vb = VarBuilder::from_varmap(&ac, DType::F32, &dev);
            let actor = Mlp::new(vb.pp("actor"), &dims(ACTOR_IN, &HIDDEN, ACTIONS))?;
            let critic = Mlp::new(vb.pp("critic"), &dims(CRITIC_IN, &HIDDEN, 1))?;
            let log_std = Var::zeros(ACTIONS, DType::F32, &dev)?;
            let mut vars = ac.all_vars();
            vars.push(log_std.clone());
            let em = VarMap::new();
            let evb = VarBuilder::from_varmap(&em, DType::F32, &dev);
            let estimator = Mlp::new(evb, &dims(HISTORY, &EST_HIDDEN, LABELS))?;
            let adam = |lr| ParamsAdamW {
                lr,
                weight_decay: 0.0,
                ..ParamsAdamW::default()
            };
            let opt = AdamW::new(vars.clone(), adam(1e-3))?;
            let est_opt = AdamW::new(em.all_vars(), adam(1e-4))?;
            Ok(Self {
                data,
                n,
                rng: Rng(123),
                actor,
                critic,
                log_std,
                estimator,
                vars,
                opt,
                est_opt,
                lr: 1e-3,
            })
        }

        fn shuffled(&mut self, from: usize, to: usize) -> Result<Tensor> {
            let perm = Tensor::from_vec(self.rng.permutation(self.n), self.n, &Device::Cpu)?;
            // candle gathers from contiguous tensors only: the column block is copied first.
            self.data
                .narrow(1, from, to - from)?
                .contiguous()?
                .index_select(&perm, 0)
        }

        pub fn ppo(&mut self) -> Result<f64> {
            let size = self.n / MINI_BATCHES;
            let half_ln_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
            let mut kl_sum = 0.0;
            for _ in 0..EPOCHS {
                let shuffled = self.shuffled(C_ACTOR, WIDTH)?;
                let col = |rows: &Tensor, c: usize, w: usize| -> Result<Tensor> {
                    rows.narrow(1, c - C_ACTOR, w)?.contiguous()
                };
                for i in 0..MINI_BATCHES {
                    let rows = shuffled.narrow(0, i * size, size)?;
                    let actor_obs = col(&rows, C_ACTOR, ACTOR_IN)?;
                    let critic_obs = col(&rows, C_CRITIC, CRITIC_IN)?;
                    let actions = col(&rows, C_ACTIONS, ACTIONS)?;
                    let old_logp = col(&rows, C_LOGP, 1)?.squeeze(1)?;
                    let old_mu = col(&rows, C_MU, ACTIONS)?;
                    let old_sigma = col(&rows, C_SIGMA, ACTIONS)?;
                    let old_v = col(&rows, C_VALUES, 1)?.squeeze(1)?;
                    let adv = col(&rows, C_ADV, 1)?.squeeze(1)?;
                    let ret = col(&rows, C_RET, 1)?.squeeze(1)?;

                    let mean = self.actor.forward(&actor_obs)?;
                    let log_std = self.log_std.as_tensor();
                    let std = log_std.exp()?;
                    let z = actions.broadcast_sub(&mean)?.broadcast_div(&std)?;
                    let logp = ((z.sqr()? * -0.5)?.broadcast_sub(log_std)? - half_ln_2pi)?
                        .sum(D::Minus1)?;
                    let entropy = (log_std.sum_all()? + ACTIONS as f64 * (0.5 + half_ln_2pi))?;
                    let values = self.critic.forward(&critic_obs)?.squeeze(1)?;

                    let (mu_d, sd_d) = (mean.detach(), std.detach().broadcast_as(mean.shape())?);
                    let kl = (((sd_d.broadcast_div(&old_sigma)? + 1e-5)?.log()?
                        + ((old_sigma.sqr()? + (&old_mu - &mu_d)?.sqr()?)?
                            / (sd_d.sqr()? * 2.0)?)?)?
                        - 0.5)?
                        .sum(D::Minus1)?
                        .mean_all()?
                        .to_scalar::<f32>()? as f64;
                    kl_sum += kl;
                    self.lr = adaptive(self.lr, kl);
                    self.opt.set_learning_rate(self.lr);

                    let ratio = (logp - &old_logp)?.exp()?;
                    let neg_adv = adv.neg()?;
                    let s1 = (&neg_adv * &ratio)?;
                    let s2 = (&neg_adv * ratio.clamp(1.0 - CLIP, 1.0 + CLIP)?)?;
                    let surrogate = s1.maximum(&s2)?.mean_all()?;
                    let dv = (&values - &old_v)?;
                    let v_clipped = (&old_v + dv.clamp(-CLIP, CLIP)?)?;
                    let value_loss = (&values - &ret)?
                        .sqr()?
                        .maximum(&(v_clipped - &ret)?.sqr()?)?
                        .mean_all()?;
                    let loss = ((surrogate + value_loss)? - (entropy * ENTROPY_COEF)?)?;
                    let mut grads = loss.backward()?;
                    clip_grad_norm(&mut grads, &self.vars, MAX_GRAD_NORM)?;
                    self.opt.step(&grads)?;
                }
            }
            Ok(kl_sum)
        }

        pub fn estimator(&mut self) -> Result<f64> {
            let mut total = 0.0;
            for _ in 0..EPOCHS {
                let shuffled = self.shuffled(C_LABELS, C_ACTOR + HISTORY)?;
                for k in 0..self.n / EST_BATCH {
                    let rows = shuffled.narrow(0, k * EST_BATCH, EST_BATCH)?;
                    let labels = rows.narrow(1, 0, LABELS)?.contiguous()?;
                    let history = rows.narrow(1, LABELS, HISTORY)?.contiguous()?;
                    let loss = (self.estimator.forward(&history)? - labels)?
                        .sqr()?
                        .mean_all()?;
                    self.est_opt.backward_step(&loss)?;
                    total += loss.to_scalar::<f32>()? as f64;
                }
            }
            Ok(total)
        }
    }

    /// torch's `clip_grad_norm_`: scale every gradient by max_norm / (total norm + 1e-6) when over.
    fn clip_grad_norm(
        grads: &mut candle_core::backprop::GradStore,
        vars: &[Var],
        max_norm: f64,
    ) -> Result<()> {
        let mut sq = 0.0f64;
        for v in vars {
            if let Some(g) = grads.get(v.as_tensor()) {
                sq += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
            }
        }
        let coef = max_norm / (sq.sqrt() + 1e-6);
        if coef < 1.0 {
            for v in vars {
                if let Some(g) = grads.remove(v.as_tensor()) {
                    grads.insert(v.as_tensor(), (g * coef)?);
                }
            }
        }
        Ok(())
    }
}

/// burn: the learner's own update (`unigait_learner::ppo`), on the same rollout.
mod burn_impl {
    use super::*;
    use burn::prelude::Device;
    use unigait_learner::nets::{self, ActorCritic, Estimator};
    use unigait_learner::ppo::{EstimatorConfig, EstimatorLearning, Ppo, PpoConfig};
    use unigait_learner::storage::{Layout, RolloutStorage};

    pub struct Bench {
        device: Device,
        storage: RolloutStorage,
        rng: unigait_learner::rng::Rng,
        ac: Option<ActorCritic>,
        estimator: Option<Estimator>,
        ppo: Ppo,
        learning: EstimatorLearning,
    }

    impl Bench {
        pub fn new(envs: usize) -> Self {
            let device = nets::device();
            let layout = Layout {
                labels: LABELS,
                actor_obs: ACTOR_IN,
                history: HISTORY,
                critic_obs: CRITIC_IN,
                actions: ACTIONS,
            };
            assert_eq!(
                layout.width(),
                WIDTH,
                "the bench's columns are the storage's"
            );
            let mut storage = RolloutStorage::new(STEPS, envs, layout);
            storage.data = rollout(envs * STEPS);
            let mut rng = unigait_learner::rng::Rng::new(0);
            let ac = ActorCritic::new(
                ACTOR_IN, CRITIC_IN, ACTIONS, &HIDDEN, &HIDDEN, 1.0, &mut rng, &device,
            );
            let estimator = Estimator::new(HISTORY, &EST_HIDDEN, LABELS, &mut rng, &device);
            Self {
                device,
                storage,
                rng,
                ac: Some(ac),
                estimator: Some(estimator),
                ppo: Ppo::new(PpoConfig::default()),
                learning: EstimatorLearning::new(EstimatorConfig::default()),
            }
        }

        pub fn ppo(&mut self) -> f64 {
            let ac = self.ac.take().expect("networks");
            let (ac, stats) = self
                .ppo
                .update(ac, &self.storage, &mut self.rng, &self.device);
            self.ac = Some(ac);
            stats.kl
        }

        pub fn estimator(&mut self) -> f64 {
            let est = self.estimator.take().expect("estimator");
            let (est, loss) = self
                .learning
                .update(est, &self.storage, &mut self.rng, &self.device);
            self.estimator = Some(est);
            loss
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut lib = String::from("burn");
    let mut envs = 512usize;
    let mut repeats = 5usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--lib" => lib = value()?,
            "--envs" => envs = value()?.parse()?,
            "--repeats" => repeats = value()?.parse()?,
            _ => return Err(format!("unknown argument {a}").into()),
        }
    }
    let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "all".into());
    let mut times = Vec::new();
    match lib.as_str() {
        #[cfg(feature = "bench-candle")]
        "candle" => {
            let mut b = candle_impl::Bench::new(envs)?;
            for _ in 0..=repeats {
                let t0 = Instant::now();
                b.ppo()?;
                let t1 = Instant::now();
                b.estimator()?;
                times.push(((t1 - t0).as_secs_f64(), t1.elapsed().as_secs_f64()));
            }
        }
        "burn" => {
            let mut b = burn_impl::Bench::new(envs);
            for _ in 0..=repeats {
                let t0 = Instant::now();
                b.ppo();
                let t1 = Instant::now();
                b.estimator();
                times.push(((t1 - t0).as_secs_f64(), t1.elapsed().as_secs_f64()));
            }
        }
        other => return Err(format!("unknown or not built library {other}").into()),
    }
    times.remove(0); // warm-up
    let ppo = median(times.iter().map(|t| t.0).collect());
    let est = median(times.iter().map(|t| t.1).collect());
    let total = median(times.iter().map(|t| t.0 + t.1).collect());
    println!(
        "{lib:6} threads {threads}: update {:7.0} ms (PPO {:6.0} ms, estimator {:6.0} ms), \
         envs {envs} x {STEPS}, median of {repeats}",
        total * 1e3,
        ppo * 1e3,
        est * 1e3
    );
    Ok(())
}
