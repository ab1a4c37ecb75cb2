//! A recipe run: every stage in order, each in its own folder of the log directory, carrying on
//! where an interrupted run stopped (client-py's `unigait.runners.recipe_runner`).
//!
//! The log directory holds `recipe.toml` and `run.json` (the recipe as it started, the
//! command's overrides), one folder per stage (`01_quad/`: `progress.csv`, `model_<it>.ckpt`,
//! `model_latest.ckpt`, `stage.json`, and once it has ended `done.json` and `policy.onnx`),
//! and at the end `final.ckpt` and `policy.onnx`, the fused policy the server serves. Running
//! the same command again resumes the stage in progress from its latest checkpoint (networks,
//! optimisers, counters, generators) and goes on; a larger `--iterations` extends the last
//! stage.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::json;
use unigait_client::Client;

use crate::checkpoint::Checkpoint;
use crate::config::{TrainConfig, engine_overrides, merged, set_line};
use crate::learner::{Envs, Learner, Scalars, StartLevels, session_config};
use crate::log::ProgressLog;
use crate::milestone::{self, load_milestone, milestones_file};
use crate::mirror::ActorMirror;
use crate::onnx::export_policy;
use crate::recipe::{Recipe, Stage, Start, StartRank};
use crate::tensorboard::EventWriter;
use crate::{Error, Result};

const RECIPE_FILE: &str = "recipe.toml";
const RUN_FILE: &str = "run.json";
const STAGE_FILE: &str = "stage.json";
const DONE_FILE: &str = "done.json";
const LATEST: &str = "model_latest.ckpt";

/// What the command line changes in every stage.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Overrides {
    /// Each stage's length (its stop rule's iterations).
    pub iterations: Option<u64>,
    /// `env.num_envs`.
    pub num_envs: Option<u32>,
    /// `env.seed` and `runner.seed`.
    pub seed: Option<u64>,
    /// `--set` lines (`section.key=value`), merged into every stage before the above.
    pub sets: Vec<String>,
    /// `runner.tensorboard` in every stage (how a run is watched: not part of what it is, so a
    /// resume may differ).
    pub tensorboard: bool,
}

impl Overrides {
    /// `recipe` with the overrides in every stage.
    pub fn apply(&self, mut recipe: Recipe) -> Result<Recipe> {
        let updates = self
            .sets
            .iter()
            .map(|line| set_line(line))
            .collect::<Result<Vec<_>, _>>()?;
        for s in &mut recipe.stages {
            if !updates.is_empty() {
                let table = updates.iter().fold(s.config.to_table(), merged);
                s.config = TrainConfig::from_table(table)
                    .map_err(|e| Error::Run(format!("--set, stage {}: {e}", s.name)))?;
            }
            if let Some(n) = self.iterations {
                s.stop.iterations = n;
            }
            if let Some(n) = self.num_envs {
                s.config.env.num_envs = n;
            }
            if self.tensorboard {
                s.config.runner.tensorboard = true;
            }
            if let Some(seed) = self.seed {
                s.config.env.seed = seed;
                s.config.runner.seed = seed;
            }
        }
        Ok(recipe)
    }
}

/// How a run ended.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    /// The last stage's final checkpoint, copied to `final.ckpt`.
    pub final_checkpoint: PathBuf,
    /// The exported policy.
    pub policy: PathBuf,
    /// The last stage's last iteration.
    pub iteration: u64,
    /// Env steps of the last stage's networks.
    pub total_env_steps: u64,
}

fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    let tmp = path.with_extension("partial");
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::Run(e.to_string()))?;
    std::fs::write(&tmp, text + "\n")?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

fn read_json(path: &Path) -> Result<serde_json::Value> {
    let text = std::fs::read_to_string(path)?;
    serde_json::from_str(&text).map_err(|e| Error::Run(format!("{}: {e}", path.display())))
}

/// Start `log_dir` for `recipe`, or check that it holds a run of the same recipe and envs.
fn prepare_log_dir(recipe: &Recipe, overrides: &Overrides, log_dir: &Path) -> Result<()> {
    let stored = log_dir.join(RECIPE_FILE);
    let run = json!({
        "recipe": recipe.name,
        "source": recipe.path.display().to_string(),
        "learner": "unigait-learner",
        "num_envs": overrides.num_envs,
        "seed": overrides.seed,
        "sets": overrides.sets,
    });
    if stored.exists() {
        let same_text = std::fs::read_to_string(&stored)? == recipe.text;
        let old = read_json(&log_dir.join(RUN_FILE)).unwrap_or_default();
        // A run from before --set existed recorded no sets: the same as none.
        let old_sets = old.get("sets").cloned().unwrap_or_else(|| json!([]));
        let same_envs = old.get("num_envs") == run.get("num_envs")
            && old.get("seed") == run.get("seed")
            && old_sets == run["sets"];
        if !same_text || !same_envs {
            return Err(Error::Run(format!(
                "{} holds a run of another recipe text, --num-envs, --seed or --set than this one ({}): \
                 give another --log-dir",
                log_dir.display(),
                old.get("recipe").and_then(|r| r.as_str()).unwrap_or("?"),
            )));
        }
    } else if log_dir.exists() && std::fs::read_dir(log_dir)?.next().is_some() {
        return Err(Error::Run(format!(
            "{} is not empty and holds no recipe run: give another --log-dir",
            log_dir.display()
        )));
    }
    std::fs::create_dir_all(log_dir)?;
    std::fs::write(&stored, &recipe.text)?;
    write_json(&log_dir.join(RUN_FILE), &run)
}

/// The fused policy of a checkpoint as ONNX bytes (what the server evaluates).
pub fn export_checkpoint(ck: &Checkpoint) -> Result<Vec<u8>> {
    let cfg = TrainConfig::from_table(
        toml::from_str(&ck.header.config_toml)
            .map_err(|e| Error::Checkpoint(format!("its config: {e}")))?,
    )?;
    let dims = ck.header.dims;
    let mut learner = Learner::new(cfg, dims, 1);
    learner.load(ck, false)?;
    learner.physics_engine = ck.header.trained_engine();
    policy_onnx(&learner)
}

/// The learner's fused policy as ONNX bytes.
pub fn policy_onnx(learner: &Learner) -> Result<Vec<u8>> {
    let d = learner.dims;
    export_policy(
        learner.estimator(),
        &learner.actor_critic().actor,
        d.history_length,
        d.obs,
        d.actions,
        &learner.physics_engine,
    )
}

/// The config a stage runs with, given the checkpoint it starts from: the upright curriculum
/// starts where that run left it, a curriculum run's envs on the levels they had reached (as
/// the Python learner's `resume_upright_curriculum` and `resumed_terrain_levels`).
fn resumed_config(mut cfg: TrainConfig, source: Option<&Checkpoint>) -> (TrainConfig, StartLevels) {
    let Some(ck) = source else {
        return (cfg, StartLevels::default());
    };
    let curriculum_on = cfg
        .env
        .task
        .get("rewards")
        .and_then(|r| r.get("upright_curriculum"))
        .and_then(|c| c.get("enabled"))
        .and_then(toml::Value::as_bool)
        .unwrap_or(false);
    if let (true, Some(pitch)) = (curriculum_on, ck.header.upright_pitch) {
        let update: toml::Table = [(
            "rewards".to_string(),
            toml::Value::Table(
                [(
                    "upright_curriculum".to_string(),
                    toml::Value::Table(
                        [("start".to_string(), toml::Value::Float(f64::from(pitch)))]
                            .into_iter()
                            .collect(),
                    ),
                )]
                .into_iter()
                .collect(),
            ),
        )]
        .into_iter()
        .collect();
        cfg.env.task = crate::config::merged(std::mem::take(&mut cfg.env.task), &update);
    }
    let (levels, mode_levels) = (&ck.header.terrain_levels, &ck.header.terrain_mode_levels);
    let n = cfg.env.num_envs as usize;
    let start = if cfg.env.terrain == "curriculum" && levels.len() == n {
        StartLevels {
            levels: levels.clone(),
            mode_levels: if mode_levels.len() == 2 * n {
                mode_levels.clone()
            } else {
                Vec::new()
            },
        }
    } else {
        StartLevels::default()
    };
    (cfg, start)
}

/// One line per iteration on the log.
fn progress_line(s: &Scalars) -> String {
    let get = |k: &str| s.iter().find(|(n, _)| n == k).map_or(f64::NAN, |(_, v)| *v);
    format!(
        "it {:5} | {:6.0} steps/s | reward/step {:+.4} | ep. reward {:+.3} | ep. len {:6.1} | \
         lr {:.2e} | std {:.3} | sim/inf/upd {:.0}%/{:.0}%/{:.0}%",
        get("iteration"),
        get("env_steps_per_s"),
        get("mean_step_reward"),
        get("mean_episode_reward"),
        get("mean_episode_length"),
        get("learning_rate"),
        get("action_std"),
        100.0 * get("time_share/simulation"),
        100.0 * get("time_share/inference"),
        100.0 * get("time_share/update"),
    )
}

/// Train one stage to its stop rule, resuming its own latest checkpoint if it has one; its
/// final checkpoint.
async fn run_stage(
    recipe: &Recipe,
    stage: &Stage,
    stage_dir: &Path,
    previous_final: Option<&Path>,
    client: &mut Client,
) -> Result<(PathBuf, u64)> {
    let latest = stage_dir.join(LATEST);
    let resuming = latest.exists() && stage_dir.join(STAGE_FILE).exists();
    if !resuming && stage_dir.exists() {
        // Killed before its first checkpoint: nothing to resume, and its rows would repeat.
        std::fs::remove_dir_all(stage_dir)?;
    }
    std::fs::create_dir_all(stage_dir)?;
    let source: Option<PathBuf> = if resuming {
        Some(latest.clone())
    } else {
        match &stage.start {
            Start::Fresh => None,
            Start::Previous => previous_final.map(Path::to_path_buf),
            Start::Checkpoint(p) if p.extension().is_some_and(|e| e == "pt") => {
                return Err(Error::Run(format!(
                    "stage {} starts from {}, a Python checkpoint: the Rust learner reads its own \
                     .ckpt files",
                    stage.name,
                    p.display()
                )));
            }
            Start::Checkpoint(p) => Some(p.clone()),
        }
    };
    let mut start_selection = None;
    let source = match (&source, previous_final) {
        (Some(_), Some(previous)) if !resuming && stage.start_best_of > 0 => {
            let (chosen, record) = best_start(stage, previous, client).await?;
            start_selection = Some(record);
            Some(chosen)
        }
        _ => source,
    };
    let source_ck = source.as_deref().map(Checkpoint::load).transpose()?;
    let (cfg, start) = resumed_config(stage.config.clone(), source_ck.as_ref());
    let mut envs = Envs::open(
        client,
        session_config(&cfg, &start),
        cfg.policy.history_length,
    )
    .await?;
    let result = train_stage(
        recipe,
        stage,
        stage_dir,
        cfg,
        &mut envs,
        source_ck,
        resuming,
        start_selection,
        client,
    )
    .await;
    let closed = envs.close().await;
    let out = result?;
    closed?;
    Ok(out)
}

#[allow(clippy::too_many_arguments)]
async fn train_stage(
    recipe: &Recipe,
    stage: &Stage,
    stage_dir: &Path,
    cfg: TrainConfig,
    envs: &mut Envs,
    source: Option<Checkpoint>,
    resuming: bool,
    start_selection: Option<serde_json::Value>,
    client: &mut Client,
) -> Result<(PathBuf, u64)> {
    let save_interval = cfg.runner.save_interval;
    let mut learner = Learner::new(cfg, envs.dims, envs.num_envs);
    if learner.cfg.ppo.mirror_loss_coef > 0.0 {
        learner.set_mirror(ActorMirror::from_spec(
            &envs.spec,
            envs.dims.history_length,
        )?);
    }
    if !envs.physics_engine.is_empty() {
        learner.physics_engine = envs.physics_engine.clone();
    }
    let mut log = ProgressLog::open(stage_dir)?;
    let mut events = if learner.cfg.runner.tensorboard {
        Some(EventWriter::create(stage_dir)?)
    } else {
        None
    };
    let start_iteration = if resuming {
        let ck = source.as_ref().expect("a resumed stage has its checkpoint");
        learner.load(ck, true)?;
        log.drop_after(learner.iteration)?;
        let start = read_json(&stage_dir.join(STAGE_FILE))?
            .get("start_iteration")
            .and_then(serde_json::Value::as_u64)
            .ok_or_else(|| Error::Run(format!("{}: no start_iteration", STAGE_FILE)))?;
        tracing::info!(
            "stage {}: resumed at iteration {}",
            stage.dir_name(),
            learner.iteration
        );
        start
    } else {
        if let Some(ck) = &source {
            learner.load(ck, stage.carry == "all")?;
        }
        let mut record = json!({
            "start_iteration": learner.iteration,
            "carry": stage.carry,
            "started_from": match &stage.start {
                Start::Fresh => serde_json::Value::Null,
                _ => json!(stage.start_label()),
            },
        });
        if let Some(selection) = start_selection {
            record["start_selection"] = selection;
        }
        write_json(&stage_dir.join(STAGE_FILE), &record)?;
        learner.iteration
    };
    learner.provenance = json!({
        "recipe": recipe.name,
        "recipe_text": recipe.text,
        "stage": stage.index + 1,
        "stage_name": stage.name,
        "learner": concat!("unigait-learner ", env!("CARGO_PKG_VERSION")),
    });
    let target = start_iteration + stage.stop.iterations;
    tracing::info!(
        "stage {}: {} envs, iterations {}-{}",
        stage.dir_name(),
        envs.num_envs,
        learner.iteration + 1,
        target
    );
    let save = |learner: &Learner| -> Result<PathBuf> {
        let ck = learner.to_checkpoint()?;
        let path = stage_dir.join(format!("model_{}.ckpt", learner.iteration));
        ck.save(&path)?;
        ck.save(&stage_dir.join(LATEST))?;
        Ok(path)
    };
    let rule = &stage.stop;
    let milestone = rule
        .milestone
        .as_deref()
        .map(|m| load_milestone(m, &milestones_file()))
        .transpose()?;
    let mut reason = "iterations".to_string();
    while learner.iteration < target {
        let scalars = learner.iterate(envs).await?;
        log.log(&scalars)?;
        if let Some(events) = events.as_mut() {
            events.log(learner.iteration, &scalars)?;
        }
        tracing::info!("{}", progress_line(&scalars));
        let check = milestone
            .as_ref()
            .filter(|_| (learner.iteration - start_iteration).is_multiple_of(rule.check_every));
        if learner.iteration.is_multiple_of(save_interval)
            || learner.iteration == target
            || check.is_some()
        {
            save(&learner)?;
        }
        if let Some(m) = check {
            // The stage's stop rule: the current policy on the validation seed (and, once met
            // there, on the confirm seed), as the Python learner's recipe runner judges it
            // (validation.jsonl has the same rows).
            let onnx = policy_onnx(&learner)?;
            let seeds = rule.check_seeds();
            let mut met_on = Vec::new();
            for &seed in &seeds {
                let evals = milestone::evaluate(
                    client,
                    m,
                    &onnx,
                    rule.validation_envs,
                    seed,
                    &engine_overrides(&learner.physics_engine),
                )
                .await?;
                let met = m.score(&evals);
                let record = json!({
                    "iteration": learner.iteration,
                    "milestone": m.name,
                    "criteria_met": met,
                    "criteria": m.criteria(),
                    "unmet": m.unmet(&evals),
                    "seed": seed,
                    "evals": evals,
                });
                let mut f = std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(stage_dir.join("validation.jsonl"))?;
                writeln!(f, "{record}")?;
                tracing::info!(
                    "stage {}: iteration {}: {} {met}/{} on seed {seed}",
                    stage.dir_name(),
                    learner.iteration,
                    m.name,
                    m.criteria(),
                );
                for unmet in m.unmet(&evals) {
                    tracing::info!("  unmet: {unmet}");
                }
                if !m.met(&evals) {
                    break;
                }
                met_on.push(seed.to_string());
            }
            if met_on.len() == seeds.len() {
                reason = format!("milestone {} met on seed {}", m.name, met_on.join(" and "));
                break;
            }
        }
    }
    let final_path = stage_dir.join(format!("model_{}.ckpt", learner.iteration));
    if !final_path.exists() {
        save(&learner)?;
    }
    std::fs::write(stage_dir.join("policy.onnx"), policy_onnx(&learner)?)?;
    write_json(
        &stage_dir.join(DONE_FILE),
        &json!({
            "final_checkpoint": final_path.file_name().and_then(|n| n.to_str()),
            "iteration": learner.iteration,
            "stage_iterations": learner.iteration - start_iteration,
            "env_steps": learner.total_env_steps,
            "reason": reason,
        }),
    )?;
    Ok((final_path, learner.iteration))
}

/// One candidate of [`best_start`]: its iteration, path and (seed, criteria met, margin) per
/// check seed.
struct Candidate {
    iteration: u64,
    path: PathBuf,
    scores: Vec<(u64, usize, f64)>,
    /// The pass chance, when ranked by it.
    chance: Option<f64>,
}

impl Candidate {
    fn seeds_met(&self, criteria: usize) -> usize {
        self.scores.iter().filter(|s| s.1 == criteria).count()
    }
    fn met(&self) -> usize {
        self.scores.iter().map(|s| s.1).sum()
    }
    fn margin(&self) -> f64 {
        self.scores.iter().map(|s| s.2).sum()
    }
}

/// The numbered checkpoints (`model_<iteration>.ckpt`) of `folder`, the last `last` by
/// iteration, oldest first.
fn recent_checkpoints(folder: &Path, last: usize) -> Result<Vec<(u64, PathBuf)>> {
    let mut found: Vec<(u64, PathBuf)> = std::fs::read_dir(folder)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter_map(|p| {
            let name = p.file_name()?.to_str()?;
            let iteration = name.strip_prefix("model_")?.strip_suffix(".ckpt")?;
            Some((iteration.parse().ok()?, p))
        })
        .collect();
    found.sort();
    Ok(found.split_off(found.len().saturating_sub(last)))
}

/// The best of the previous stage's last `stage.start_best_of` checkpoints, judged on the
/// stage's milestone on every check seed, and how it was chosen (`stage.json`'s
/// `start_selection`), as the Python learner's recipe runner chooses: seeds on which every
/// criterion is met, then criteria met, summed margin, the later checkpoint. A run folder that
/// kept only the previous stage's final checkpoint starts from that.
async fn best_start(
    stage: &Stage,
    previous_final: &Path,
    client: &mut Client,
) -> Result<(PathBuf, serde_json::Value)> {
    let rule = &stage.stop;
    let name = rule.milestone.as_deref().ok_or_else(|| {
        Error::Run(format!(
            "stage {}: start_best_of needs a milestone",
            stage.name
        ))
    })?;
    let m = load_milestone(name, &milestones_file())?;
    let folder = previous_final.parent().unwrap_or(Path::new("."));
    let found = recent_checkpoints(folder, stage.start_best_of as usize)?;
    if found.is_empty() {
        tracing::info!(
            "stage {}: no numbered checkpoints in {}; starts from its final",
            stage.dir_name(),
            folder.display()
        );
        let chosen = previous_final.to_path_buf();
        let record = json!({"candidates": [], "chosen": chosen.display().to_string()});
        return Ok((chosen, record));
    }
    let seeds = rule.check_seeds();
    let by_chance = stage.start_rank == StartRank::PassChance;
    let envs = rule.validation_envs;
    let mut candidates = Vec::new();
    for (iteration, path) in found {
        let ck = Checkpoint::load(&path)?;
        let onnx = export_checkpoint(&ck)?;
        let engine = engine_overrides(&ck.header.trained_engine());
        let mut scores = Vec::new();
        let mut per_seed = Vec::new();
        for &seed in &seeds {
            let evals = if by_chance {
                milestone::evaluate_at(client, &m, &onnx, envs, seed, &engine).await?
            } else {
                milestone::evaluate(client, &m, &onnx, envs, seed, &engine).await?
            };
            scores.push((seed, m.score(&evals), m.margin(&evals)));
            per_seed.push(evals);
        }
        let chance = by_chance.then(|| m.pass_chance(&per_seed, envs));
        candidates.push(Candidate {
            iteration,
            path,
            scores,
            chance,
        });
    }
    let criteria = m.criteria();
    let best = candidates
        .iter()
        .max_by(|a, b| {
            let ranked = if by_chance {
                a.chance.unwrap_or(0.0).total_cmp(&b.chance.unwrap_or(0.0))
            } else {
                (a.seeds_met(criteria), a.met()).cmp(&(b.seeds_met(criteria), b.met()))
            };
            ranked
                .then(a.margin().total_cmp(&b.margin()))
                .then(a.iteration.cmp(&b.iteration))
        })
        .map(|c| c.path.clone())
        .unwrap_or_else(|| previous_final.to_path_buf());
    let listed: Vec<String> = candidates
        .iter()
        .map(|c| {
            let met: Vec<String> = c
                .scores
                .iter()
                .map(|s| format!("{}/{criteria}", s.1))
                .collect();
            let chance = c
                .chance
                .map_or(String::new(), |p| format!(" (chance {p:.2})"));
            format!("{}: {}{chance}", c.iteration, met.join(" + "))
        })
        .collect();
    tracing::info!(
        "stage {}: starts from {}, the best of {} on {}{}, seeds {:?} ({})",
        stage.dir_name(),
        best.display(),
        candidates.len(),
        m.name,
        if by_chance { " by the pass chance" } else { "" },
        seeds,
        listed.join(", ")
    );
    let record = json!({
        "milestone": m.name,
        "seeds": seeds,
        "rank": if by_chance { "pass_chance" } else { "criteria" },
        "candidates": candidates.iter().map(|c| {
            let mut one = json!({
                "iteration": c.iteration,
                "scores": c.scores.iter().map(|&(seed, met, margin)| json!({
                    "seed": seed, "met": met, "margin": margin,
                })).collect::<Vec<_>>(),
            });
            if let Some(p) = c.chance {
                one["chance"] = json!(p);
            }
            one
        }).collect::<Vec<_>>(),
        "chosen": best.display().to_string(),
    });
    Ok((best, record))
}

impl Stage {
    fn start_label(&self) -> String {
        match &self.start {
            Start::Fresh => "fresh".into(),
            Start::Previous => "previous".into(),
            Start::Checkpoint(p) => p.display().to_string(),
        }
    }
}

/// Whether the stage in `stage_dir` has met its milestone or trained to `iterations` past its
/// start.
fn stage_ended(stage_dir: &Path, iterations: u64) -> Result<bool> {
    let (latest, started) = (stage_dir.join(LATEST), stage_dir.join(STAGE_FILE));
    if !latest.exists() || !started.exists() {
        return Ok(false);
    }
    let done = stage_dir.join(DONE_FILE);
    if done.exists()
        && read_json(&done)?
            .get("reason")
            .and_then(serde_json::Value::as_str)
            .is_some_and(|r| r.starts_with("milestone"))
    {
        return Ok(true);
    }
    let start = read_json(&started)?
        .get("start_iteration")
        .and_then(serde_json::Value::as_u64)
        .unwrap_or(0);
    Ok(Checkpoint::load(&latest)?.header.iteration >= start + iterations)
}

/// Every stage of `recipe` not ended yet, in order, over the server at `address`; then
/// `final.ckpt` and `policy.onnx` in `log_dir`.
pub async fn run_recipe(
    recipe: Recipe,
    overrides: &Overrides,
    log_dir: &Path,
    address: &str,
) -> Result<RunSummary> {
    if let Some(s) = recipe.stages.iter().find(|s| !s.runs_at_head) {
        return Err(Error::Run(format!(
            "recipe {} records stages that ran on code that no longer exists ({}): it documents \
             history; train a recipe that runs at this commit",
            recipe.name, s.name
        )));
    }
    let recipe = overrides.apply(recipe)?;
    prepare_log_dir(&recipe, overrides, log_dir)?;
    let mut client = Client::connect(address).await?;
    let mut final_path: Option<PathBuf> = None;
    for (i, stage) in recipe.stages.iter().enumerate() {
        let stage_dir = log_dir.join(stage.dir_name());
        // A stage is over when it reached its length, or when a later stage has started
        // from it (its history is not rewritten).
        let later_started = recipe.stages[i + 1..]
            .iter()
            .any(|s| log_dir.join(s.dir_name()).join(STAGE_FILE).exists());
        if later_started || stage_ended(&stage_dir, stage.stop.iterations)? {
            tracing::info!("stage {}: ended before", stage.dir_name());
            final_path = Some(stage_dir.join(LATEST));
            continue;
        }
        let (path, _) = run_stage(
            &recipe,
            stage,
            &stage_dir,
            final_path.as_deref(),
            &mut client,
        )
        .await?;
        final_path = Some(path);
    }
    let final_path = final_path.ok_or_else(|| Error::Run("a recipe without stages".into()))?;
    let ck = Checkpoint::load(&final_path)?;
    ck.save(&log_dir.join("final.ckpt"))?;
    let policy = log_dir.join("policy.onnx");
    std::fs::write(&policy, export_checkpoint(&ck)?)?;
    tracing::info!(
        "recipe {} done: {} (from {}), {}",
        recipe.name,
        log_dir.join("final.ckpt").display(),
        final_path.display(),
        policy.display()
    );
    Ok(RunSummary {
        final_checkpoint: log_dir.join("final.ckpt"),
        policy,
        iteration: ck.header.iteration,
        total_env_steps: ck.header.total_env_steps,
    })
}
