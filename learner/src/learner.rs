//! The training loop over a session of the service: the Python learner's `OnPolicyRunner`.
//!
//! Per iteration: roll out T steps of N envs (the actor sees o_{t-H+1:t} and the estimate of
//! the current networks, detached), bootstrap time-outs from the critic's value of the final
//! state, GAE, the PPO epochs, then the estimator's MSE epochs on the same rollout.

use std::time::{Duration, Instant};

use burn::module::Module;
use burn::prelude::*;
use unigait_client::{Client, Session, Spec, StepStream, v1};

use crate::checkpoint::{self, Blob, Checkpoint, Header};
use crate::config::TrainConfig;
use crate::env::{Dims, Ended, EpisodeStats, ObservationHistory, StepData};
use crate::gae::bootstrap_time_outs;
use crate::mirror::ActorMirror;
use crate::nets::{self, ActorCritic, Estimator, Mlp, matrix};
use crate::ppo::{EstimatorLearning, Ppo};
use crate::rng::Rng;
use crate::stats::{BipedPoseStats, TerrainLevelStats, env_terrain_types};
use crate::storage::{Layout, RolloutStorage, Step};
use crate::{Error, Result};

/// 0.5 ln(2 pi): the Gaussian's normalising term per dimension.
const HALF_LN_2PI: f32 = 0.918_938_5;

/// One iteration's scalars, in the Python learner's CSV order.
pub type Scalars = Vec<(String, f64)>;

/// Where a session's curriculum envs start: each env's level, and its (quad, biped) levels
/// when the run keeps a level per mode (decision record 0036). Empty: drawn afresh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StartLevels {
    /// One level per env.
    pub levels: Vec<u32>,
    /// Two per env, (quad, biped).
    pub mode_levels: Vec<u32>,
}

/// The session a training run opens (reward terms on: the log needs them).
pub fn session_config(cfg: &TrainConfig, start: &StartLevels) -> v1::SessionConfig {
    v1::SessionConfig {
        num_envs: cfg.env.num_envs,
        seed: cfg.env.seed,
        task_overrides_toml: cfg.task_toml(),
        terrain: Some(v1::TerrainConfig {
            kind: cfg.env.terrain.clone(),
            level: cfg.env.terrain_level,
            initial_levels: start.levels.clone(),
            initial_mode_levels: start.mode_levels.clone(),
            columns: cfg.env.terrain_columns.clone(),
        }),
        autoreset: v1::AutoresetMode::SameStep as i32,
        reward_terms: true,
        robot_drawing: false,
    }
}

/// The grid a session built is the one its config named (or it named none): a server older than
/// `terrain.columns` builds its default grid without a word (decision record 0037).
pub fn grid_as_asked(asked: &[String], built: &[String]) -> Result<()> {
    if asked.is_empty() || asked == built {
        return Ok(());
    }
    Err(Error::Spec(format!(
        "asked for the grid columns {asked:?} and the server built {built:?}: it predates \
         TerrainConfig.columns"
    )))
}

/// A session seen as batched envs: its step stream, the last step, the observation history
/// and the episode bookkeeping.
pub struct Envs {
    session: Option<Session>,
    stream: StepStream,
    /// The sizes.
    pub dims: Dims,
    /// N.
    pub num_envs: usize,
    /// The reward terms' names.
    pub reward_terms: Vec<String>,
    /// The longest episode in seconds (per-term episode rewards are per second of it).
    pub episode_length_s: f64,
    /// The physics engine the session steps in ("" from a server that does not say).
    pub physics_engine: String,
    /// The session's spec.
    pub spec: Spec,
    terrain_stats: TerrainLevelStats,
    biped_pose: BipedPoseStats,
    last: StepData,
    history: ObservationHistory,
    stats: EpisodeStats,
}

impl Envs {
    /// Open a session on `client` and its step stream.
    pub async fn open(
        client: &mut Client,
        config: v1::SessionConfig,
        history_length: usize,
    ) -> Result<Self> {
        let asked = config
            .terrain
            .as_ref()
            .map(|t| t.columns.clone())
            .unwrap_or_default();
        let mut session = client.create_session(config).await?;
        let spec = session.spec.clone();
        if let Err(e) = grid_as_asked(&asked, &spec.0.terrain_columns) {
            session.close().await?;
            return Err(e);
        }
        let dims = Dims::from_spec(&spec, history_length)?;
        let n = spec.num_envs();
        let last = StepData::from_step(&session.initial, &dims, n)?;
        let stream = session.stream().await?;
        let reward_terms = spec.0.reward_terms.clone();
        let physics_engine = spec.0.physics_engine.clone();
        Ok(Self {
            physics_engine,
            spec: spec.clone(),
            terrain_stats: TerrainLevelStats::new(&env_terrain_types(
                &spec.0.terrain,
                &spec.0.terrain_columns,
                n,
            )),
            biped_pose: BipedPoseStats::from_spec(&spec)?,
            history: ObservationHistory::new(&last.obs, history_length, dims.obs),
            stats: EpisodeStats::new(n, reward_terms.len()),
            episode_length_s: f64::from(spec.0.max_episode_steps) * f64::from(spec.0.policy_dt),
            session: Some(session),
            stream,
            dims,
            num_envs: n,
            reward_terms,
            last,
        })
    }

    async fn step(&mut self, actions: &[f32]) -> Result<StepData> {
        let step = self.stream.step(actions).await?;
        StepData::from_step(&step, &self.dims, self.num_envs)
    }

    /// Close the session.
    pub async fn close(mut self) -> Result<()> {
        drop(self.stream);
        if let Some(s) = self.session.take() {
            s.close().await?;
        }
        Ok(())
    }
}

/// Wall time per part of an iteration.
#[derive(Debug, Default, Clone, Copy)]
struct Timers {
    simulation: Duration,
    inference: Duration,
    update: Duration,
}

/// The networks, their optimisers, the rollout storage and the counters.
pub struct Learner {
    /// The config.
    pub cfg: TrainConfig,
    /// The sizes.
    pub dims: Dims,
    /// N.
    pub num_envs: usize,
    device: Device,
    infer_device: Device,
    // Taken by value through each update (burn's optimiser consumes and returns the module).
    ac: Option<ActorCritic>,
    estimator: Option<Estimator>,
    ac_infer: ActorCritic,
    estimator_infer: Estimator,
    ppo: Ppo,
    estimator_learning: EstimatorLearning,
    storage: RolloutStorage,
    action_rng: Rng,
    update_rng: Rng,
    /// Iterations trained.
    pub iteration: u64,
    /// Env steps trained.
    pub total_env_steps: u64,
    /// The upright indicator's threshold at the end of the last rollout.
    pub upright_pitch: Option<f32>,
    /// Each env's terrain level at the end of the last rollout.
    pub terrain_levels: Vec<u32>,
    /// Each env's (quad, biped) levels at the end of the last rollout (empty from servers that
    /// do not report them).
    pub terrain_mode_levels: Vec<u32>,
    /// Where these networks come from, saved with every checkpoint.
    pub provenance: serde_json::Value,
    /// The physics engine the envs step in (the session's spec says), saved with every
    /// checkpoint and stamped into exported policies (decision record 0026).
    pub physics_engine: String,
}

fn infer(mlp: &Mlp, x: Vec<f32>, rows: usize, cols: usize, device: &Device) -> Result<Vec<f32>> {
    nets::values(mlp.forward(matrix(x, rows, cols, device)))
}

impl Learner {
    /// Give the PPO update the mirror maps its mirror loss needs (decision record 0033).
    pub fn set_mirror(&mut self, mirror: ActorMirror) {
        self.ppo.set_mirror(mirror);
    }

    /// Fresh networks for `dims` and `num_envs`, seeded by `cfg.runner.seed`.
    pub fn new(cfg: TrainConfig, dims: Dims, num_envs: usize) -> Self {
        let device = nets::device();
        let infer_device = device.clone().inner();
        let mut rng = Rng::new(cfg.runner.seed);
        let ac = ActorCritic::new(
            dims.actor_in(),
            dims.critic_in(),
            dims.actions,
            &cfg.policy.actor_hidden_dims,
            &cfg.policy.critic_hidden_dims,
            cfg.policy.init_noise_std as f32,
            &mut rng,
            &device,
        );
        let estimator = Estimator::new(
            dims.history(),
            &cfg.estimator.hidden_dims,
            dims.labels,
            &mut rng,
            &device,
        );
        let layout = Layout {
            labels: dims.labels,
            actor_obs: dims.actor_in(),
            history: dims.history(),
            critic_obs: dims.critic_in(),
            actions: dims.actions,
        };
        let action_rng = Rng::new(rng.next_u64());
        let update_rng = Rng::new(rng.next_u64());
        Self {
            storage: RolloutStorage::new(cfg.runner.num_steps_per_env, num_envs, layout),
            ppo: Ppo::new(cfg.ppo_config()),
            estimator_learning: EstimatorLearning::new(cfg.estimator_config()),
            ac_infer: ac.valid(),
            estimator_infer: estimator.valid(),
            ac: Some(ac),
            estimator: Some(estimator),
            device,
            infer_device,
            action_rng,
            update_rng,
            iteration: 0,
            total_env_steps: 0,
            upright_pitch: None,
            terrain_levels: Vec::new(),
            terrain_mode_levels: Vec::new(),
            provenance: serde_json::Value::Null,
            physics_engine: cfg
                .task_engine()
                .unwrap_or(crate::config::ENGINE_BEFORE_RECORDING)
                .to_string(),
            cfg,
            dims,
            num_envs,
        }
    }

    /// The current learning rate.
    pub fn learning_rate(&self) -> f64 {
        self.ppo.learning_rate
    }

    /// The actor-critic (for export and tests).
    pub fn actor_critic(&self) -> &ActorCritic {
        self.ac
            .as_ref()
            .expect("the networks are in place between updates")
    }

    /// The estimator (for export and tests).
    pub fn estimator(&self) -> &Estimator {
        self.estimator
            .as_ref()
            .expect("the networks are in place between updates")
    }

    /// Mean actions f32 [B, A] of the fused estimator and actor for histories f32 [B, H * obs],
    /// as the exported policy computes them.
    pub fn policy_actions(&self, history: &[f32]) -> Result<Vec<f32>> {
        let d = self.dims;
        let rows = history.len() / d.history();
        let actor_obs = self.actor_obs(history, rows)?;
        infer(
            &self.ac_infer.actor,
            actor_obs,
            rows,
            d.actor_in(),
            &self.infer_device,
        )
    }

    /// f32 [B, history + labels]: each history row and its estimate.
    fn actor_obs(&self, history: &[f32], rows: usize) -> Result<Vec<f32>> {
        let d = self.dims;
        let estimate = infer(
            &self.estimator_infer,
            history.to_vec(),
            rows,
            d.history(),
            &self.infer_device,
        )?;
        let mut out = Vec::with_capacity(rows * d.actor_in());
        for e in 0..rows {
            out.extend_from_slice(&history[e * d.history()..(e + 1) * d.history()]);
            out.extend_from_slice(&estimate[e * d.labels..(e + 1) * d.labels]);
        }
        Ok(out)
    }

    fn values(&self, critic_obs: Vec<f32>, rows: usize) -> Result<Vec<f32>> {
        if rows == 0 {
            return Ok(Vec::new());
        }
        infer(
            &self.ac_infer.critic,
            critic_obs,
            rows,
            self.dims.critic_in(),
            &self.infer_device,
        )
    }

    /// Collect one rollout into the storage and compute its returns; its statistics.
    async fn rollout(&mut self, envs: &mut Envs, timers: &mut Timers) -> Result<Scalars> {
        let (d, n) = (self.dims, self.num_envs);
        if envs.num_envs != n || envs.dims != d {
            return Err(Error::Spec(format!(
                "the session has {} envs of {:?}, the learner {n} of {d:?}",
                envs.num_envs, envs.dims
            )));
        }
        let gamma = self.cfg.ppo.gamma as f32;
        let log_std = nets::values(self.ac_infer.log_std.val())?;
        let std: Vec<f32> = log_std.iter().map(|x| x.exp()).collect();
        let sigma: Vec<f32> = (0..n).flat_map(|_| std.iter().copied()).collect();
        let terms = envs.reward_terms.len();
        let mut term_sum = vec![0.0f64; terms];
        let (mut reward_sum, mut biped, mut level, mut blowups) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let mut ended = Ended::default();
        self.storage.clear();
        let steps = self.cfg.runner.num_steps_per_env;
        for _ in 0..steps {
            let t0 = Instant::now();
            let actor_obs = self.actor_obs(&envs.history.buffer, n)?;
            let mean = infer(
                &self.ac_infer.actor,
                actor_obs.clone(),
                n,
                d.actor_in(),
                &self.infer_device,
            )?;
            let critic_obs = envs.last.critic_obs(&d);
            let values = self.values(critic_obs.clone(), n)?;
            let mut actions = vec![0.0f32; n * d.actions];
            let mut log_prob = vec![0.0f32; n];
            for e in 0..n {
                let mut lp = 0.0f32;
                for j in 0..d.actions {
                    let z = self.action_rng.normal();
                    actions[e * d.actions + j] = mean[e * d.actions + j] + std[j] * z;
                    lp += -0.5 * z * z - log_std[j] - HALF_LN_2PI;
                }
                log_prob[e] = lp;
            }
            timers.inference += t0.elapsed();

            let t1 = Instant::now();
            let next = envs.step(&actions).await?;
            timers.simulation += t1.elapsed();

            let t2 = Instant::now();
            let mut rewards = next.reward.clone();
            let final_values = self.values(next.final_critic_obs(&d), next.final_env_ids.len())?;
            bootstrap_time_outs(
                &mut rewards,
                &next.terminated,
                &next.truncated,
                &next.final_env_ids,
                &final_values,
                gamma,
            );
            let dones = next.dones();
            self.storage.add(&Step {
                actor_obs: &actor_obs,
                critic_obs: &critic_obs,
                labels: &envs.last.labels,
                actions: &actions,
                log_prob: &log_prob,
                mu: &mean,
                sigma: &sigma,
                values: &values,
                rewards: &rewards,
                dones: &dones,
            })?;
            envs.history.push(&next.obs, &dones);
            envs.stats.update(&next, &mut ended);
            if let Some(rt) = &next.reward_terms {
                for (e, v) in rt.iter().enumerate() {
                    term_sum[e % terms.max(1)] += f64::from(*v);
                }
            }
            reward_sum += next.reward.iter().map(|&r| f64::from(r)).sum::<f64>();
            blowups += f64::from(next.nonfinite_resets);
            biped += next.mode.iter().filter(|&&m| m == 1).count() as f64 / n as f64;
            // The mode each env acted in, and the state the step left it in.
            envs.biped_pose.add(&envs.last.mode, &next, d.obs, d.labels);
            envs.terrain_stats.add(&next.terrain_level, &next.mode);
            envs.terrain_stats.add_episode_ends(
                &envs.last.terrain_level,
                &next.terrain_level,
                &dones,
            );
            level += next
                .terrain_level
                .iter()
                .map(|&l| f64::from(l))
                .sum::<f64>()
                / n as f64;
            envs.last = next;
            timers.inference += t2.elapsed();
        }
        self.terrain_levels = envs.last.terrain_level.clone();
        self.terrain_mode_levels = envs.last.mode_levels.clone();
        let t3 = Instant::now();
        let last_values = self.values(envs.last.critic_obs(&d), n)?;
        let p = &self.cfg.ppo;
        self.storage.compute_returns(
            &last_values,
            p.gamma as f32,
            p.lam as f32,
            p.normalize_advantage,
        );
        timers.inference += t3.elapsed();

        let samples = (steps * n) as f64;
        let mut out: Scalars = vec![
            ("mean_step_reward".into(), reward_sum / samples),
            ("terrain_level".into(), level / steps as f64),
            ("biped_share".into(), biped / steps as f64),
            // Envs the server reset for a physics blow-up (decision 0035): should stay 0.
            ("physics_blowups".into(), blowups),
        ];
        out.extend(envs.biped_pose.summary());
        out.extend(envs.terrain_stats.summary());
        if let Some(pitch) = envs.last.upright_pitch {
            out.push(("curriculum/upright_pitch".into(), f64::from(pitch)));
            self.upright_pitch = Some(pitch);
        }
        let episodes = ended.reward.len();
        let mean_or_nan = |sum: f64| {
            if episodes > 0 {
                sum / episodes as f64
            } else {
                f64::NAN
            }
        };
        out.push(("episodes".into(), episodes as f64));
        out.push(("time_outs".into(), ended.time_outs as f64));
        out.push((
            "mean_episode_reward".into(),
            mean_or_nan(ended.reward.iter().sum()),
        ));
        out.push((
            "mean_episode_length".into(),
            mean_or_nan(ended.length.iter().map(|&l| l as f64).sum()),
        ));
        for (i, name) in envs.reward_terms.iter().enumerate() {
            let ep = ended.terms.get(i).copied().unwrap_or(0.0);
            out.push((
                format!("episode_reward/{name}"),
                mean_or_nan(ep) / envs.episode_length_s,
            ));
            out.push((format!("step_reward/{name}"), term_sum[i] / samples));
        }
        Ok(out)
    }

    /// The PPO epochs, then the estimator's, on the stored rollout.
    fn update(&mut self) -> Result<Scalars> {
        let largest = self.storage.largest();
        let where_ = || {
            largest
                .iter()
                .map(|(k, b)| {
                    format!(
                        "{k} {:.3e} at step {} env {} column {}",
                        b.magnitude, b.step, b.env, b.column
                    )
                })
                .collect::<Vec<_>>()
                .join("; ")
        };
        if largest.iter().any(|(_, b)| !b.magnitude.is_finite()) {
            return Err(Error::NonFinite(format!(
                "non-finite rollout at iteration {}: {}",
                self.iteration + 1,
                where_()
            )));
        }
        let ac = self
            .ac
            .take()
            .expect("the networks are in place between updates");
        let (ac, stats) = self
            .ppo
            .update(ac, &self.storage, &mut self.update_rng, &self.device);
        let estimator = self
            .estimator
            .take()
            .expect("the networks are in place between updates");
        let (estimator, estimator_loss) = self.estimator_learning.update(
            estimator,
            &self.storage,
            &mut self.update_rng,
            &self.device,
        );
        let mut out: Scalars = vec![
            ("value_loss".into(), stats.value_loss),
            ("surrogate_loss".into(), stats.surrogate_loss),
            ("entropy".into(), stats.entropy),
            ("kl".into(), stats.kl),
        ];
        out.extend(stats.bound_loss.map(|b| ("bound_loss".to_string(), b)));
        out.extend(stats.mirror_loss.map(|m| ("mirror_loss".to_string(), m)));
        out.extend([
            ("learning_rate".into(), stats.learning_rate),
            ("action_std".into(), stats.action_std),
            ("estimator_loss".into(), estimator_loss),
        ]);
        if out.iter().any(|(_, v)| !v.is_finite()) {
            // The networks that came out are not kept: the last checkpoint is the clean state.
            return Err(Error::NonFinite(format!(
                "non-finite update at iteration {} ({out:?}): {}",
                self.iteration + 1,
                where_()
            )));
        }
        self.set_networks(ac, estimator);
        for (name, b) in &largest {
            out.push((format!("rollout/max_abs/{name}"), f64::from(b.magnitude)));
        }
        for (name, b) in &largest {
            out.push((format!("rollout/max_abs_column/{name}"), b.column as f64));
        }
        Ok(out)
    }

    fn set_networks(&mut self, ac: ActorCritic, estimator: Estimator) {
        self.ac_infer = ac.valid();
        self.estimator_infer = estimator.valid();
        self.ac = Some(ac);
        self.estimator = Some(estimator);
    }

    /// One iteration: rollout and update; its scalars, in the Python learner's CSV order.
    pub async fn iterate(&mut self, envs: &mut Envs) -> Result<Scalars> {
        let start = Instant::now();
        let mut timers = Timers::default();
        let rollout = self.rollout(envs, &mut timers).await?;
        let t = Instant::now();
        let update = self.update()?;
        timers.update += t.elapsed();
        let elapsed = start.elapsed().as_secs_f64();
        self.iteration += 1;
        let samples = (self.cfg.runner.num_steps_per_env * self.num_envs) as u64;
        self.total_env_steps += samples;
        let share = |d: Duration| d.as_secs_f64() / elapsed;
        let mut out: Scalars = vec![
            ("iteration".into(), self.iteration as f64),
            ("total_env_steps".into(), self.total_env_steps as f64),
            ("env_steps_per_s".into(), samples as f64 / elapsed),
            ("iteration_time_s".into(), elapsed),
            ("time_share/simulation".into(), share(timers.simulation)),
            ("time_share/inference".into(), share(timers.inference)),
            ("time_share/update".into(), share(timers.update)),
        ];
        out.extend(rollout);
        out.extend(update);
        Ok(out)
    }

    /// Everything a checkpoint holds.
    pub fn to_checkpoint(&self) -> Result<Checkpoint> {
        let mut blobs = Vec::new();
        let actor_critic = checkpoint::collect(self.actor_critic(), &mut blobs)?;
        let estimator = checkpoint::collect(self.estimator(), &mut blobs)?;
        let mut push = |bytes: Vec<u8>| {
            let b = Blob {
                offset: blobs.len(),
                len: bytes.len(),
            };
            blobs.extend_from_slice(&bytes);
            b
        };
        let ppo_optimizer = push(self.ppo.optimizer_bytes()?);
        let estimator_optimizer = push(self.estimator_learning.optimizer_bytes()?);
        Ok(Checkpoint {
            header: Header {
                iteration: self.iteration,
                total_env_steps: self.total_env_steps,
                learning_rate: self.ppo.learning_rate,
                action_rng: self.action_rng.state(),
                update_rng: self.update_rng.state(),
                config_toml: self.cfg.to_toml(),
                dims: self.dims,
                provenance: self.provenance.clone(),
                upright_pitch: self.upright_pitch,
                terrain_levels: self.terrain_levels.clone(),
                terrain_mode_levels: self.terrain_mode_levels.clone(),
                physics_engine: self.physics_engine.clone(),
                actor_critic,
                estimator,
                ppo_optimizer,
                estimator_optimizer,
            },
            blobs,
        })
    }

    /// Take a checkpoint's networks; with `all`, also its optimisers, counters, generators and
    /// (adaptive schedule) learning rate, as the Python learner's `load` (else `load_weights`,
    /// which keeps an adaptive schedule's rate too).
    pub fn load(&mut self, ck: &Checkpoint, all: bool) -> Result<()> {
        let h = &ck.header;
        let theirs = TrainConfig::from_table(
            toml::from_str(&h.config_toml)
                .map_err(|e| Error::Checkpoint(format!("its config: {e}")))?,
        )?;
        let mut differences = Vec::new();
        for (name, a, b) in [
            (
                "policy.actor_hidden_dims",
                &theirs.policy.actor_hidden_dims,
                &self.cfg.policy.actor_hidden_dims,
            ),
            (
                "policy.critic_hidden_dims",
                &theirs.policy.critic_hidden_dims,
                &self.cfg.policy.critic_hidden_dims,
            ),
            (
                "estimator.hidden_dims",
                &theirs.estimator.hidden_dims,
                &self.cfg.estimator.hidden_dims,
            ),
        ] {
            if a != b {
                differences.push(format!("{name} = {a:?} (this run {b:?})"));
            }
        }
        if h.dims != self.dims {
            differences.push(format!("dims {:?} (this run {:?})", h.dims, self.dims));
        }
        if !differences.is_empty() {
            return Err(Error::Checkpoint(format!(
                "other networks than this run's: {}",
                differences.join("; ")
            )));
        }
        let ac = self.ac.take().expect("the networks are in place");
        let estimator = self.estimator.take().expect("the networks are in place");
        let restored = checkpoint::restore(ac.clone(), &h.actor_critic, &ck.blobs).and_then(|ac| {
            Ok((
                ac,
                checkpoint::restore(estimator.clone(), &h.estimator, &ck.blobs)?,
            ))
        });
        let (ac, estimator) = match restored {
            Ok(pair) => pair,
            Err(e) => {
                self.set_networks(ac, estimator);
                return Err(e);
            }
        };
        self.set_networks(ac, estimator);
        let adaptive = self.cfg.ppo.schedule == "adaptive";
        if all {
            self.ppo.load_optimizer(ck.blob(h.ppo_optimizer)?)?;
            self.estimator_learning
                .load_optimizer(ck.blob(h.estimator_optimizer)?)?;
            self.iteration = h.iteration;
            self.total_env_steps = h.total_env_steps;
            self.action_rng = Rng::new(h.action_rng);
            self.update_rng = Rng::new(h.update_rng);
            self.upright_pitch = h.upright_pitch;
            self.terrain_levels = h.terrain_levels.clone();
            self.terrain_mode_levels = h.terrain_mode_levels.clone();
            self.provenance = h.provenance.clone();
        }
        self.ppo.learning_rate = if adaptive {
            h.learning_rate
        } else {
            self.cfg.ppo.learning_rate
        };
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grid_other_than_asked_is_refused() {
        let grid = ["slope_up".to_string(), "stairs_up".to_string()];
        assert!(grid_as_asked(&grid, &grid).is_ok());
        assert!(grid_as_asked(&[], &grid).is_ok()); // the server's default, whatever it is
        assert!(grid_as_asked(&[], &[]).is_ok()); // flat ground
        let err = grid_as_asked(&grid, &[]).unwrap_err().to_string();
        assert!(err.contains("predates TerrainConfig.columns"), "{err}");
        assert!(grid_as_asked(&grid, &grid[..1]).is_err());
    }

    fn tiny() -> (TrainConfig, Dims) {
        let mut cfg = TrainConfig::default();
        cfg.policy.actor_hidden_dims = vec![8];
        cfg.policy.critic_hidden_dims = vec![8];
        cfg.estimator.hidden_dims = vec![8];
        cfg.estimator.mini_batch_size = 4;
        cfg.runner.num_steps_per_env = 3;
        let dims = Dims {
            obs: 2,
            labels: 1,
            privileged: 1,
            actions: 2,
            history_length: 2,
        };
        (cfg, dims)
    }

    /// Fill the storage with a fixed rollout (the same for every learner it is given to).
    fn fill(l: &mut Learner) {
        let (d, n) = (l.dims, l.num_envs);
        l.storage.clear();
        for t in 0..l.cfg.runner.num_steps_per_env {
            let f = |w: usize, k: f32| -> Vec<f32> {
                (0..n * w).map(|i| ((i as f32 + k) * 0.37).sin()).collect()
            };
            l.storage
                .add(&Step {
                    actor_obs: &f(d.actor_in(), t as f32),
                    critic_obs: &f(d.critic_in(), 1.0 + t as f32),
                    labels: &f(d.labels, 2.0),
                    actions: &f(d.actions, 3.0 + t as f32),
                    log_prob: &vec![-2.0; n],
                    mu: &f(d.actions, 4.0),
                    sigma: &vec![1.0; n * d.actions],
                    values: &f(1, 5.0),
                    rewards: &f(1, 6.0 + t as f32),
                    dones: &vec![t == 1; n],
                })
                .unwrap();
        }
        l.storage.compute_returns(&vec![0.5; n], 0.99, 0.95, true);
    }

    fn weights(l: &Learner) -> Vec<u8> {
        let mut b = Vec::new();
        checkpoint::collect(l.actor_critic(), &mut b).unwrap();
        checkpoint::collect(l.estimator(), &mut b).unwrap();
        b
    }

    /// Train a learner two updates, checkpoint, train a third; a fresh learner loaded from the
    /// checkpoint (through a file) and given the same rollout must land on the same weights, the
    /// same learning rate and the same generator states: the Adam moments came back (fresh ones
    /// would move the weights differently).
    #[test]
    fn a_checkpoint_resumes_the_optimisers_exactly() {
        let (cfg, dims) = tiny();
        let mut a = Learner::new(cfg.clone(), dims, 4);
        for _ in 0..2 {
            fill(&mut a);
            a.update().unwrap();
            a.iteration += 1;
        }
        let path = std::env::temp_dir().join(format!("unigait-ckpt-{}.ckpt", std::process::id()));
        a.to_checkpoint().unwrap().save(&path).unwrap();
        fill(&mut a);
        a.update().unwrap();

        let mut other = cfg.clone();
        other.runner.seed = 99; // different fresh networks: everything must come from the file
        let mut b = Learner::new(other.clone(), dims, 4);
        b.load(&Checkpoint::load(&path).unwrap(), true).unwrap();
        assert_eq!(b.iteration, 2);
        fill(&mut b);
        b.update().unwrap();
        assert_eq!(weights(&a), weights(&b));
        assert_eq!(a.learning_rate(), b.learning_rate());
        assert_eq!(a.update_rng.state(), b.update_rng.state());

        // The weights alone (fresh Adam) give other weights after the same update.
        let mut c = Learner::new(other, dims, 4);
        c.load(&Checkpoint::load(&path).unwrap(), false).unwrap();
        assert_eq!(c.iteration, 0);
        c.update_rng = Rng::new(Checkpoint::load(&path).unwrap().header.update_rng);
        fill(&mut c);
        c.update().unwrap();
        assert_ne!(weights(&a), weights(&c));
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn a_checkpoint_of_other_networks_is_refused() {
        let (cfg, dims) = tiny();
        let a = Learner::new(cfg.clone(), dims, 4);
        let ck = a.to_checkpoint().unwrap();
        let mut wider = cfg;
        wider.policy.actor_hidden_dims = vec![16];
        let mut b = Learner::new(wider, dims, 4);
        let err = b.load(&ck, true).unwrap_err().to_string();
        assert!(err.contains("policy.actor_hidden_dims = [8]"), "{err}");
    }
}
