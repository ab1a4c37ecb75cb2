//! The training config: the Python learner's `TrainConfig` (client-py's `unigait.config`), the
//! same sections, keys and defaults, so the recipes in `assets/recipes/` read the same in both.
//!
//! Keys the Rust learner has no use for (torch's device and threads, the PNG's interval,
//! TensorBoard) are accepted and ignored, so that a recipe valid for one learner is valid for
//! the other; unknown keys are errors, as in Python.

use serde::{Deserialize, Serialize};

use crate::ppo::{EstimatorConfig, PpoConfig};

/// Where and what to simulate (`[env]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvConfig {
    /// Server addresses (the Rust learner uses the first; `--server` overrides).
    pub servers: Vec<String>,
    /// Binary of a local server (empty: `$UNIGAIT_SERVER_BIN` or beside this binary).
    pub server_bin: String,
    /// Envs in the batch.
    pub num_envs: u32,
    /// Session seed.
    pub seed: u64,
    /// The task config's overrides as a nested table (sent to the server as TOML).
    pub task: toml::Table,
    /// `"flat"`, `"curriculum"` or a pinned terrain type.
    pub terrain: String,
    /// Level of a pinned type, or the curriculum's highest starting level.
    pub terrain_level: u32,
    /// The curriculum grid's column types, in order (empty: the server's default 20).
    pub terrain_columns: Vec<String>,
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            servers: Vec::new(),
            server_bin: String::new(),
            num_envs: 256,
            seed: 1,
            task: toml::Table::new(),
            terrain: "flat".into(),
            terrain_level: 0,
            terrain_columns: Vec::new(),
        }
    }
}

/// Network shapes (`[policy]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PolicyConfig {
    /// Actor MLP hidden sizes.
    pub actor_hidden_dims: Vec<usize>,
    /// Critic MLP hidden sizes.
    pub critic_hidden_dims: Vec<usize>,
    /// Only `"elu"`.
    pub activation: String,
    /// Initial action std.
    pub init_noise_std: f64,
    /// Observations in the history (3).
    pub history_length: usize,
}

impl Default for PolicyConfig {
    fn default() -> Self {
        Self {
            actor_hidden_dims: vec![512, 256, 128],
            critic_hidden_dims: vec![512, 256, 128],
            activation: "elu".into(),
            init_noise_std: 1.0,
            history_length: 3,
        }
    }
}

/// PPO hyper-parameters (`[ppo]`), as the Python `PPOConfig`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PpoSection {
    /// Passes over the rollout per update.
    pub num_learning_epochs: usize,
    /// Mini-batches per pass.
    pub num_mini_batches: usize,
    /// Ratio and value clip.
    pub clip_param: f64,
    /// Discount.
    pub gamma: f64,
    /// GAE lambda.
    pub lam: f64,
    /// Weight of the value loss.
    pub value_loss_coef: f64,
    /// Weight of the entropy bonus.
    pub entropy_coef: f64,
    /// Initial learning rate.
    pub learning_rate: f64,
    /// Global gradient-norm clip.
    pub max_grad_norm: f64,
    /// Clip the value update like the ratio.
    pub use_clipped_value_loss: bool,
    /// `"adaptive"` (KL-driven) or `"fixed"`.
    pub schedule: String,
    /// Target KL of the adaptive schedule.
    pub desired_kl: f64,
    /// Normalise advantages over the batch.
    pub normalize_advantage: bool,
    /// Floor of every action dim's std after each Adam step (0: none).
    pub min_action_std: f64,
    /// |mean action| past which the bound loss pays (0: none).
    pub action_mean_bound: f64,
    /// Weight of the bound loss.
    pub bound_loss_coef: f64,
    /// Weight of the mirror loss (0: none; decision record 0033).
    pub mirror_loss_coef: f64,
}

impl Default for PpoSection {
    fn default() -> Self {
        let d = PpoConfig::default();
        Self {
            num_learning_epochs: d.num_learning_epochs,
            num_mini_batches: d.num_mini_batches,
            // As decimal literals (PpoConfig holds them as f32).
            clip_param: 0.2,
            gamma: 0.99,
            lam: 0.95,
            value_loss_coef: d.value_loss_coef,
            entropy_coef: d.entropy_coef,
            learning_rate: d.learning_rate,
            max_grad_norm: d.max_grad_norm,
            use_clipped_value_loss: d.use_clipped_value_loss,
            schedule: "adaptive".into(),
            desired_kl: d.desired_kl,
            normalize_advantage: d.normalize_advantage,
            min_action_std: d.min_action_std,
            action_mean_bound: d.action_mean_bound,
            bound_loss_coef: d.bound_loss_coef,
            mirror_loss_coef: d.mirror_loss_coef,
        }
    }
}

/// Estimator hyper-parameters (`[estimator]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorSection {
    /// Hidden sizes.
    pub hidden_dims: Vec<usize>,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Samples per step.
    pub mini_batch_size: usize,
    /// Passes over the rollout per iteration.
    pub num_epochs: usize,
}

impl Default for EstimatorSection {
    fn default() -> Self {
        let d = EstimatorConfig::default();
        Self {
            hidden_dims: d.hidden_dims,
            learning_rate: d.learning_rate,
            mini_batch_size: d.mini_batch_size,
            num_epochs: d.num_epochs,
        }
    }
}

/// The training loop (`[runner]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunnerConfig {
    /// Steps per env per iteration.
    pub num_steps_per_env: usize,
    /// Iterations of a run without a recipe (a recipe's stages give their own).
    pub max_iterations: u64,
    /// Checkpoint every this many iterations.
    pub save_interval: u64,
    /// Python only (its PNG); accepted.
    pub plot_interval: u64,
    /// Python only (a recipe decides the folder); accepted.
    pub log_dir: String,
    /// Python only (torch's device); accepted.
    pub device: String,
    /// Python only (torch's threads); accepted.
    pub torch_threads: i64,
    /// Python only; accepted.
    pub update_threads: i64,
    /// Seed of the initialisation, the action noise and the shuffles.
    pub seed: u64,
    /// One line per iteration on stderr (the Rust learner always logs one).
    pub quiet: bool,
    /// Each iteration's scalars also as TensorBoard events beside `progress.csv`.
    pub tensorboard: bool,
}

impl Default for RunnerConfig {
    fn default() -> Self {
        Self {
            num_steps_per_env: 24,
            max_iterations: 500,
            save_interval: 50,
            plot_interval: 10,
            log_dir: "runs/unigait".into(),
            device: "cpu".into(),
            torch_threads: 1,
            update_threads: 2,
            seed: 1,
            quiet: false,
            tensorboard: false,
        }
    }
}

/// Everything a training run needs.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// `[env]`.
    pub env: EnvConfig,
    /// `[policy]`.
    pub policy: PolicyConfig,
    /// `[ppo]`.
    pub ppo: PpoSection,
    /// `[estimator]`.
    pub estimator: EstimatorSection,
    /// `[runner]`.
    pub runner: RunnerConfig,
}

/// A config that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// A value the learner does not implement.
    #[error("{0}")]
    Unsupported(String),
    /// TOML that does not make a config.
    #[error("{0}")]
    Toml(String),
}

impl TrainConfig {
    /// The config as a TOML table (the shape recipes merge into).
    pub fn to_table(&self) -> toml::Table {
        toml::Table::try_from(self).expect("a config is a TOML table")
    }

    /// A config from a table, unknown keys refused.
    pub fn from_table(table: toml::Table) -> Result<Self, ConfigError> {
        let cfg: Self = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Toml(e.message().to_string()))?;
        cfg.check()?;
        Ok(cfg)
    }

    /// The config as TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a config serialises")
    }

    /// Refuse what this learner does not implement.
    pub fn check(&self) -> Result<(), ConfigError> {
        if self.policy.activation != "elu" {
            return Err(ConfigError::Unsupported(format!(
                "policy.activation {:?}: the Rust learner has only \"elu\"",
                self.policy.activation
            )));
        }
        if !matches!(self.ppo.schedule.as_str(), "adaptive" | "fixed") {
            return Err(ConfigError::Unsupported(format!(
                "ppo.schedule must be \"adaptive\" or \"fixed\", got {:?}",
                self.ppo.schedule
            )));
        }
        if self.env.num_envs == 0 || self.runner.num_steps_per_env == 0 {
            return Err(ConfigError::Unsupported(
                "env.num_envs and runner.num_steps_per_env must be >= 1".into(),
            ));
        }
        if self.runner.save_interval == 0 || self.policy.history_length == 0 {
            return Err(ConfigError::Unsupported(
                "runner.save_interval and policy.history_length must be >= 1".into(),
            ));
        }
        Ok(())
    }

    /// The task overrides as the TOML fragment a session takes (empty: defaults).
    pub fn task_toml(&self) -> String {
        if self.env.task.is_empty() {
            String::new()
        } else {
            toml::to_string(&self.env.task).expect("a table serialises")
        }
    }

    /// The physics engine the task chooses (None: the server's default).
    pub fn task_engine(&self) -> Option<&str> {
        self.env
            .task
            .get("physics")
            .and_then(|p| p.get("engine"))
            .and_then(toml::Value::as_str)
    }

    /// The PPO update's settings.
    pub fn ppo_config(&self) -> PpoConfig {
        let p = &self.ppo;
        PpoConfig {
            num_learning_epochs: p.num_learning_epochs,
            num_mini_batches: p.num_mini_batches,
            clip_param: p.clip_param as f32,
            gamma: p.gamma as f32,
            lam: p.lam as f32,
            value_loss_coef: p.value_loss_coef,
            entropy_coef: p.entropy_coef,
            learning_rate: p.learning_rate,
            max_grad_norm: p.max_grad_norm,
            use_clipped_value_loss: p.use_clipped_value_loss,
            adaptive: p.schedule == "adaptive",
            desired_kl: p.desired_kl,
            normalize_advantage: p.normalize_advantage,
            min_action_std: p.min_action_std,
            action_mean_bound: p.action_mean_bound,
            bound_loss_coef: p.bound_loss_coef,
            mirror_loss_coef: p.mirror_loss_coef,
            // torch's intra-op threads in the Python learner; here, the mini-batch's shares.
            update_threads: usize::try_from(self.runner.update_threads.max(1)).unwrap_or(1),
        }
    }

    /// The estimator's settings.
    pub fn estimator_config(&self) -> EstimatorConfig {
        let e = &self.estimator;
        EstimatorConfig {
            hidden_dims: e.hidden_dims.clone(),
            learning_rate: e.learning_rate,
            mini_batch_size: e.mini_batch_size,
            num_epochs: e.num_epochs,
        }
    }
}

/// A `--set` line, `section.key=value` (`ppo.entropy_coef=0.005`,
/// `env.task.physics.engine="rapier"`), as the table to merge into a config. The value is TOML;
/// a bare word that is not TOML is taken as a string, as in the Python learner's `--set`.
pub fn set_line(text: &str) -> Result<toml::Table, ConfigError> {
    let bad = || {
        ConfigError::Toml(format!(
            "--set must look like section.key=value, got {text:?}"
        ))
    };
    let (path, raw) = text.split_once('=').ok_or_else(bad)?;
    let keys: Vec<&str> = path.trim().split('.').map(str::trim).collect();
    if keys.len() < 2 || keys.iter().any(|k| k.is_empty()) {
        return Err(bad());
    }
    let raw = raw.trim();
    let mut value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    for key in keys[1..].iter().rev() {
        value = toml::Value::Table(toml::Table::from_iter([(key.to_string(), value)]));
    }
    Ok(toml::Table::from_iter([(keys[0].to_string(), value)]))
}

/// `base` with `update` merged in, tables recursively (the task table's rule).
pub fn merged(mut base: toml::Table, update: &toml::Table) -> toml::Table {
    for (key, value) in update {
        match (base.get_mut(key), value) {
            (Some(toml::Value::Table(old)), toml::Value::Table(new)) => {
                let inner = std::mem::take(old);
                *old = merged(inner, new);
            }
            _ => {
                base.insert(key.clone(), value.clone());
            }
        }
    }
    base
}

/// The engine of a checkpoint or policy that does not say: every one written before the
/// learners recorded the engine trained on rapier unless its task chose (decision record 0026).
pub const ENGINE_BEFORE_RECORDING: &str = "rapier";

/// The task overrides that evaluate a policy on `engine`, the one it trained on (decision
/// records 0023 and 0026).
pub fn engine_overrides(engine: &str) -> String {
    format!("physics.engine = {}", toml::Value::from(engine))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_python_learners() {
        let cfg = TrainConfig::default();
        assert_eq!(cfg.env.num_envs, 256);
        assert_eq!(cfg.policy.actor_hidden_dims, [512, 256, 128]);
        assert_eq!(cfg.runner.num_steps_per_env, 24);
        assert_eq!(cfg.runner.save_interval, 50);
        assert_eq!(cfg.ppo.learning_rate, 1e-3);
        assert_eq!(cfg.estimator.mini_batch_size, 768);
        // The round trip through TOML keeps everything.
        assert_eq!(TrainConfig::from_table(cfg.to_table()).unwrap(), cfg);
    }

    #[test]
    fn unknown_keys_and_unsupported_values_are_refused() {
        let mut t = TrainConfig::default().to_table();
        t["ppo"]
            .as_table_mut()
            .unwrap()
            .insert("learnin_rate".into(), toml::Value::Float(1e-4));
        let err = TrainConfig::from_table(t).unwrap_err().to_string();
        assert!(err.contains("learnin_rate"), "{err}");
        let mut t = TrainConfig::default().to_table();
        t["policy"]
            .as_table_mut()
            .unwrap()
            .insert("activation".into(), "tanh".into());
        let err = TrainConfig::from_table(t).unwrap_err().to_string();
        assert!(err.contains("only \"elu\""), "{err}");
    }

    #[test]
    fn set_lines_merge_into_a_config_and_bad_ones_are_named() {
        let mut t = TrainConfig::default().to_table();
        for line in [
            "ppo.entropy_coef=0.005",
            "env.task.physics.engine = \"rapier\"",
            "env.task.rewards.weights.quad_foot_clearance=3",
            "env.terrain=curriculum",
            "env.terrain_columns = [\"slope_up\", \"stairs_up\"]",
        ] {
            t = merged(t, &set_line(line).unwrap());
        }
        let cfg = TrainConfig::from_table(t).unwrap();
        assert_eq!(cfg.ppo.entropy_coef, 0.005);
        assert_eq!(cfg.task_engine(), Some("rapier"));
        assert_eq!(
            cfg.env.task["rewards"]["weights"]["quad_foot_clearance"].as_integer(),
            Some(3)
        );
        assert_eq!(cfg.env.terrain, "curriculum");
        assert_eq!(cfg.env.terrain_columns, ["slope_up", "stairs_up"]);
        let session = crate::learner::session_config(&cfg, &Default::default());
        let terrain = session.terrain.expect("terrain");
        assert_eq!(terrain.columns, ["slope_up", "stairs_up"]);
        for bad in ["entropy_coef=0.1", "ppo.=1", "ppo.entropy_coef"] {
            let err = set_line(bad).unwrap_err().to_string();
            assert!(err.contains("section.key=value"), "{err}");
        }
        let unknown = merged(
            TrainConfig::default().to_table(),
            &set_line("ppo.entropy=0.1").unwrap(),
        );
        let err = TrainConfig::from_table(unknown).unwrap_err().to_string();
        assert!(err.contains("entropy"), "{err}");
    }

    #[test]
    fn the_task_names_its_engine_or_leaves_it_to_the_server() {
        let mut cfg = TrainConfig::default();
        assert_eq!(cfg.task_engine(), None);
        cfg.env.task = toml::from_str("[physics]\nengine = \"articulated\"\n").unwrap();
        assert_eq!(cfg.task_engine(), Some("articulated"));
        assert_eq!(
            engine_overrides("articulated"),
            "physics.engine = \"articulated\""
        );
    }

    #[test]
    fn tables_merge_recursively_values_replace() {
        let base: toml::Table = toml::from_str("a = 1\n[t]\nx = 1\ny = 2\n").unwrap();
        let update: toml::Table = toml::from_str("a = 3\n[t]\ny = 5\nz = 6\n").unwrap();
        let m = merged(base, &update);
        let expected: toml::Table = toml::from_str("a = 3\n[t]\nx = 1\ny = 5\nz = 6\n").unwrap();
        assert_eq!(m, expected);
    }
}
