//! Training recipes: the TOML files of `assets/recipes/`, shared with the Python learner
//! (client-py's `unigait.recipes`), read with the same keys and the same rules: stages in order,
//! each the one before's config (or the defaults, or `extends`'s) with its own tables merged in,
//! the task table merged key by key, unknown keys refused with the file and stage named.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::config::{TrainConfig, merged};

/// A recipe that cannot be read or resolved (the message names the file and the key).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct RecipeError(pub String);

/// Config sections a stage may set (`task` goes into `env.task`).
const SECTIONS: [&str; 5] = ["env", "policy", "ppo", "estimator", "runner"];

/// When a stage ends.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StopRule {
    /// Iterations of the stage (with `milestone`: at most this many).
    pub iterations: u64,
    /// Stop as soon as this milestone is met on the validation seed.
    #[serde(default)]
    pub milestone: Option<String>,
    /// Iterations between milestone checks.
    #[serde(default = "default_check_every")]
    pub check_every: u64,
    /// Seed of the milestone checks.
    #[serde(default = "default_validation_seed")]
    pub validation_seed: u64,
    /// Envs per scenario of the milestone checks.
    #[serde(default = "default_validation_envs")]
    pub validation_envs: u32,
    /// A second validation seed: a check met on `validation_seed` is judged again on this one,
    /// and the stage stops only if both are met (a milestone of few trials is met by one lucky
    /// draw far more often than by two independent ones).
    #[serde(default)]
    pub confirm_seed: Option<u64>,
}

impl StopRule {
    /// The seeds a milestone check judges the policy on, in order; each is judged only if the
    /// one before met the milestone.
    pub fn check_seeds(&self) -> Vec<u64> {
        std::iter::once(self.validation_seed)
            .chain(self.confirm_seed)
            .collect()
    }
}

fn default_check_every() -> u64 {
    100
}
fn default_validation_seed() -> u64 {
    2000
}
fn default_validation_envs() -> u32 {
    64
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRecipe {
    #[serde(default)]
    description: String,
    #[serde(default)]
    milestone: Option<String>,
    #[serde(default)]
    extends: Option<String>,
    #[serde(default)]
    stages: Vec<RawStage>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStage {
    #[serde(default)]
    name: String,
    #[serde(default)]
    note: String,
    #[serde(default)]
    start: Option<String>,
    #[serde(default)]
    start_best_of: Option<i64>,
    #[serde(default)]
    start_rank: Option<String>,
    #[serde(default)]
    carry: Option<String>,
    stop: Option<StopRule>,
    #[serde(default)]
    ran_at: Option<String>,
    #[serde(default)]
    runs_at_head: Option<bool>,
    #[serde(default)]
    env: Option<toml::Table>,
    #[serde(default)]
    task: Option<toml::Table>,
    #[serde(default)]
    policy: Option<toml::Table>,
    #[serde(default)]
    ppo: Option<toml::Table>,
    #[serde(default)]
    estimator: Option<toml::Table>,
    #[serde(default)]
    runner: Option<toml::Table>,
}

impl RawStage {
    fn section(&self, name: &str) -> Option<&toml::Table> {
        match name {
            "env" => self.env.as_ref(),
            "policy" => self.policy.as_ref(),
            "ppo" => self.ppo.as_ref(),
            "estimator" => self.estimator.as_ref(),
            "runner" => self.runner.as_ref(),
            _ => None,
        }
    }
}

/// How a stage starts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Start {
    /// Fresh networks.
    Fresh,
    /// The previous stage's final checkpoint.
    Previous,
    /// A checkpoint file (a Python `.pt` cannot be read by this learner).
    Checkpoint(PathBuf),
}

/// How `start_best_of`'s candidates are ranked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StartRank {
    /// Seeds on which every criterion is met, criteria met, summed margin, the later one; each
    /// scenario at the milestone's own size.
    Criteria,
    /// The chance of meeting the milestone on one unseen draw, every scenario on the stop rule's
    /// `validation_envs` ([`crate::pass_chance`]); then summed margin, the later one.
    PassChance,
}

/// One resolved stage.
#[derive(Debug, Clone, PartialEq)]
pub struct Stage {
    /// 0-based position.
    pub index: usize,
    /// Its name.
    pub name: String,
    /// Its note.
    pub note: String,
    /// How it starts.
    pub start: Start,
    /// With [`Start::Previous`] and a milestone: start from the best of the previous stage's
    /// last this many checkpoints, judged on the stop rule's milestone and check seeds (0: its
    /// final one). Checkpoints close together can differ by more than a stage moves them.
    pub start_best_of: u32,
    /// How those candidates are ranked (`start_rank`).
    pub start_rank: StartRank,
    /// From a checkpoint: `"weights"` or `"all"` (optimisers and counters too).
    pub carry: String,
    /// When it ends.
    pub stop: StopRule,
    /// Its whole config.
    pub config: TrainConfig,
    /// The commit it ran at, when that is no longer this code.
    pub ran_at: Option<String>,
    /// Whether it can train at this commit.
    pub runs_at_head: bool,
}

impl Stage {
    /// The stage's folder in a run's log directory (`01_quad`), as the Python learner names it.
    pub fn dir_name(&self) -> String {
        format!("{:02}_{}", self.index + 1, self.name)
    }
}

/// A recipe with its stages resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct Recipe {
    /// File stem.
    pub name: String,
    /// Its file.
    pub path: PathBuf,
    /// Its text as read.
    pub text: String,
    /// Its description.
    pub description: String,
    /// The milestone `ship` judges it by.
    pub milestone: Option<String>,
    /// The stages in order.
    pub stages: Vec<Stage>,
}

/// The folder of the packaged recipes: `$UNIGAIT_RECIPES_DIR`, else the repository's
/// `assets/recipes` (where this crate was built from), else `./assets/recipes`.
pub fn recipes_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("UNIGAIT_RECIPES_DIR") {
        return PathBuf::from(dir);
    }
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/recipes");
    if built.is_dir() {
        return built;
    }
    PathBuf::from("assets/recipes")
}

/// The file of recipe `name_or_path`: a `.toml` file as given, else `<dir>/<name>.toml`.
pub fn recipe_path(name_or_path: &str, dir: &Path) -> Result<PathBuf, RecipeError> {
    let path = Path::new(name_or_path);
    if path.extension().is_some_and(|e| e == "toml") && path.is_file() {
        return Ok(path.to_path_buf());
    }
    let packaged = dir.join(format!("{name_or_path}.toml"));
    if packaged.is_file() {
        return Ok(packaged);
    }
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let p = e.path();
            (p.extension()? == "toml").then(|| p.file_stem()?.to_str().map(String::from))?
        })
        .collect();
    names.sort();
    Err(RecipeError(format!(
        "unknown recipe {name_or_path:?}; recipes in {}: {names:?}",
        dir.display()
    )))
}

/// Read and resolve recipe `name_or_path` (a name looked up in `dir`, or a `.toml` file).
pub fn load_recipe(name_or_path: &str, dir: &Path) -> Result<Recipe, RecipeError> {
    load(name_or_path, dir, &mut Vec::new())
}

fn load(name_or_path: &str, dir: &Path, seen: &mut Vec<String>) -> Result<Recipe, RecipeError> {
    let path = recipe_path(name_or_path, dir)?;
    let where_ = path.display().to_string();
    let text = std::fs::read_to_string(&path)
        .map_err(|e| RecipeError(format!("{where_}: cannot read: {e}")))?;
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or_default()
        .to_string();
    let raw: RawRecipe = toml::from_str(&text).map_err(|e| {
        RecipeError(format!(
            "{where_}: {}",
            e.message().trim_end_matches('\n').replace('\n', " ")
        ))
    })?;
    if raw.stages.is_empty() {
        return Err(RecipeError(format!(
            "{where_}: a recipe needs at least one [[stages]]"
        )));
    }
    let mut cfg = TrainConfig::default();
    if let Some(extends) = &raw.extends {
        // "recipe" takes its last stage's config, "recipe:stage" that stage's.
        let (parent, parent_stage) = extends.split_once(':').unwrap_or((extends, ""));
        if seen.iter().any(|s| s == parent) || parent == stem {
            return Err(RecipeError(format!(
                "{where_}: extends {parent:?} in a loop"
            )));
        }
        seen.push(stem.clone());
        let parent_dir = path.parent().unwrap_or(dir);
        let parents = load(parent, parent_dir, seen)?.stages;
        let chosen = if parent_stage.is_empty() {
            parents.last()
        } else {
            parents.iter().find(|s| s.name == parent_stage)
        };
        cfg = chosen
            .ok_or_else(|| {
                RecipeError(format!(
                    "{where_}: extends {extends:?}: {parent} has no such stage"
                ))
            })?
            .config
            .clone();
    }
    let mut stages = Vec::new();
    for (i, s) in raw.stages.iter().enumerate() {
        let here = format!("{where_} stage {}", i + 1);
        let name_ok = !s.name.is_empty()
            && s.name.chars().all(|c| c.is_alphanumeric() || c == '_')
            && s.name.chars().any(|c| c.is_alphanumeric());
        if !name_ok || stages.iter().any(|st: &Stage| st.name == s.name) {
            return Err(RecipeError(format!(
                "{here}: needs a unique name of letters, digits and _"
            )));
        }
        let here = format!("{here} ({})", s.name);
        let start = match s
            .start
            .as_deref()
            .unwrap_or(if i == 0 { "fresh" } else { "previous" })
        {
            "fresh" => Start::Fresh,
            "previous" if i == 0 => {
                return Err(RecipeError(format!(
                    "{here}: the first stage has no previous stage to start from"
                )));
            }
            "previous" => Start::Previous,
            other => Start::Checkpoint(PathBuf::from(other)),
        };
        let carry = s.carry.clone().unwrap_or_else(|| "weights".into());
        if carry != "weights" && carry != "all" {
            return Err(RecipeError(format!(
                "{here}: carry must be 'weights' or 'all', got {carry:?}"
            )));
        }
        cfg = stage_config(&cfg, s, &here)?;
        let stop = s
            .stop
            .clone()
            .ok_or_else(|| RecipeError(format!("{here}: [stages.stop] must give iterations")))?;
        if stop.iterations < 1 || stop.check_every < 1 {
            return Err(RecipeError(format!(
                "{here} [stages.stop]: iterations and check_every must be >= 1"
            )));
        }
        if stop.confirm_seed.is_some() && stop.milestone.is_none() {
            return Err(RecipeError(format!(
                "{here} [stages.stop]: confirm_seed confirms a milestone: give one"
            )));
        }
        if stop.confirm_seed == Some(stop.validation_seed) {
            return Err(RecipeError(format!(
                "{here} [stages.stop]: confirm_seed must differ from validation_seed"
            )));
        }
        let start_best_of = match s.start_best_of.unwrap_or(0) {
            n @ 0..=1_000_000 => n as u32,
            _ => {
                return Err(RecipeError(format!(
                    "{here}: start_best_of must be a count of checkpoints (>= 0)"
                )));
            }
        };
        if start_best_of > 0 && (start != Start::Previous || stop.milestone.is_none()) {
            return Err(RecipeError(format!(
                "{here}: start_best_of chooses among the previous stage's checkpoints by the \
                 stage's milestone: give start = \"previous\" and [stages.stop] milestone"
            )));
        }
        let start_rank = match s.start_rank.as_deref() {
            None | Some("criteria") => StartRank::Criteria,
            Some("pass_chance") => StartRank::PassChance,
            Some(other) => {
                return Err(RecipeError(format!(
                    "{here}: start_rank must be one of criteria, pass_chance, got {other:?}"
                )));
            }
        };
        if s.start_rank.is_some() && start_best_of == 0 {
            return Err(RecipeError(format!(
                "{here}: start_rank ranks start_best_of's candidates: give both"
            )));
        }
        stages.push(Stage {
            index: i,
            name: s.name.clone(),
            note: s.note.clone(),
            start,
            start_best_of,
            start_rank,
            carry,
            stop,
            config: cfg.clone(),
            ran_at: s.ran_at.clone(),
            runs_at_head: s.runs_at_head.unwrap_or(true),
        });
    }
    Ok(Recipe {
        name: stem,
        path,
        text,
        description: raw.description,
        milestone: raw.milestone,
        stages,
    })
}

/// `base` with the stage's tables merged in: a section's keys replace the base's, the task
/// table merges key by key.
fn stage_config(base: &TrainConfig, s: &RawStage, here: &str) -> Result<TrainConfig, RecipeError> {
    let mut doc = base.to_table();
    for name in SECTIONS {
        let Some(update) = s.section(name) else {
            continue;
        };
        if name == "env"
            && (update.contains_key("task") || update.contains_key("task_overrides_toml"))
        {
            return Err(RecipeError(format!(
                "{here}: give the task as [stages.task] tables, not inside [stages.env]"
            )));
        }
        let section = doc
            .get_mut(name)
            .and_then(toml::Value::as_table_mut)
            .expect("every section is in the config's table");
        for (key, value) in update {
            section.insert(key.clone(), value.clone());
        }
    }
    if let Some(task) = &s.task {
        let env = doc
            .get_mut("env")
            .and_then(toml::Value::as_table_mut)
            .expect("env is in the config's table");
        let old = match env.remove("task") {
            Some(toml::Value::Table(t)) => t,
            _ => toml::Table::new(),
        };
        env.insert("task".into(), toml::Value::Table(merged(old, task)));
    }
    TrainConfig::from_table(doc).map_err(|e| RecipeError(format!("{here}: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) {
        std::fs::write(dir.join(format!("{name}.toml")), text).unwrap();
    }

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("unigait-recipe-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn the_shipped_recipes_resolve() {
        let dir = recipes_dir();
        let q = load_recipe("quad_flat", &dir).unwrap();
        assert_eq!(q.milestone.as_deref(), Some("M1"));
        let s = &q.stages[0];
        assert_eq!(s.dir_name(), "01_quad");
        assert_eq!(s.config.env.num_envs, 512);
        assert_eq!(s.config.runner.save_interval, 25);
        assert_eq!(s.stop.iterations, 3000);
        assert_eq!(s.stop.check_every, 100);
        let modes = s.config.env.task["modes"].as_table().unwrap();
        assert_eq!(modes["biped_probability"].as_float(), Some(0.0));
        // unified_flat: the second stage keeps the first's task and adds to it.
        let u = load_recipe("unified_flat", &dir).unwrap();
        let sharpen = &u.stages[1];
        assert_eq!(sharpen.start, Start::Previous);
        assert_eq!(sharpen.carry, "all");
        assert_eq!(sharpen.config.ppo.entropy_coef, 0.0025);
        assert_eq!(sharpen.config.policy.actor_hidden_dims, [256, 128, 64]);
        let w = sharpen.config.env.task["rewards"]["weights"]
            .as_table()
            .unwrap();
        assert_eq!(w["biped_body_contact"].as_float(), Some(-3.0));
        assert_eq!(w["biped_sideways_reach"].as_float(), Some(0.5));
        assert_eq!(u.stages[2].config.ppo.schedule, "fixed");
        // extends "unified_flat:upright": that stage's config, then the ablation's change.
        let a = load_recipe("ablation_no_task_indicator", &dir).unwrap();
        let t = &a.stages[0].config;
        assert_eq!(
            t.env.task["rewards"]["task_indicators"].as_bool(),
            Some(false)
        );
        assert_eq!(
            t.env.task["rewards"]["upright_pitch"].as_float(),
            Some(1.45)
        );
        assert_eq!(t.ppo.entropy_coef, 0.01);
        // Every shipped recipe reads.
        for entry in std::fs::read_dir(&dir).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().is_some_and(|e| e == "toml") {
                load_recipe(p.to_str().unwrap(), &dir).unwrap_or_else(|e| panic!("{e}"));
            }
        }
    }

    #[test]
    fn start_best_of_needs_the_previous_stage_and_a_milestone() {
        let d = tmp("best_of");
        let first = "[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 1\n";
        let second = |line: &str, stop: &str| {
            format!(
                "{first}[[stages]]\nname = \"b\"\nstart = \"previous\"\n{line}\n\
                 [stages.stop]\niterations = 2\n{stop}"
            )
        };
        write(
            &d,
            "ok",
            &second("start_best_of = 4", "milestone = \"M3\"\n"),
        );
        let stages = load_recipe("ok", &d).unwrap().stages;
        assert_eq!((stages[0].start_best_of, stages[1].start_best_of), (0, 4));
        assert_eq!(stages[1].start_rank, StartRank::Criteria);
        let ranked = "start_best_of = 4\nstart_rank = \"pass_chance\"";
        write(&d, "ranked", &second(ranked, "milestone = \"M3\"\n"));
        let stages = load_recipe("ranked", &d).unwrap().stages;
        assert_eq!(stages[1].start_rank, StartRank::PassChance);
        for (name, text, message) in [
            (
                "luck",
                second(
                    "start_best_of = 4\nstart_rank = \"luck\"",
                    "milestone = \"M3\"\n",
                ),
                "start_rank must be one of",
            ),
            (
                "rank_alone",
                second("start_rank = \"pass_chance\"", "milestone = \"M3\"\n"),
                "give both",
            ),
            (
                "bare",
                second("start_best_of = 4", ""),
                "give start = \"previous\"",
            ),
            (
                "negative",
                second("start_best_of = -1", "milestone = \"M3\"\n"),
                "count of checkpoints",
            ),
        ] {
            write(&d, name, &text);
            let e = load_recipe(name, &d).unwrap_err().0;
            assert!(e.contains(message), "{e}");
        }
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_confirm_seed_is_checked_after_the_validation_seed() {
        let d = tmp("confirm");
        let stage = "[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 4\n";
        write(
            &d,
            "both",
            &format!("{stage}milestone = \"M1\"\nvalidation_seed = 7\nconfirm_seed = 8\n"),
        );
        let rule = &load_recipe("both", &d).unwrap().stages[0].stop;
        assert_eq!(rule.confirm_seed, Some(8));
        assert_eq!(rule.check_seeds(), [7, 8]);
        write(&d, "one", &format!("{stage}milestone = \"M1\"\n"));
        assert_eq!(
            load_recipe("one", &d).unwrap().stages[0].stop.check_seeds(),
            [2000]
        );
        write(&d, "bare", &format!("{stage}confirm_seed = 8\n"));
        let e = load_recipe("bare", &d).unwrap_err().0;
        assert!(e.contains("confirms a milestone"), "{e}");
        write(
            &d,
            "same",
            &format!("{stage}milestone = \"M1\"\nconfirm_seed = 2000\n"),
        );
        let e = load_recipe("same", &d).unwrap_err().0;
        assert!(e.contains("must differ from validation_seed"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn unknown_keys_are_refused_with_the_place() {
        let d = tmp("unknown");
        write(
            &d,
            "top",
            "descripton = \"x\"\n[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 1\n",
        );
        let e = load_recipe("top", &d).unwrap_err().0;
        assert!(e.contains("descripton"), "{e}");
        write(
            &d,
            "stage",
            "[[stages]]\nname = \"a\"\nstopp = 1\n[stages.stop]\niterations = 1\n",
        );
        assert!(load_recipe("stage", &d).unwrap_err().0.contains("stopp"));
        write(
            &d,
            "stop",
            "[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 1\nevery = 3\n",
        );
        assert!(load_recipe("stop", &d).unwrap_err().0.contains("every"));
        write(
            &d,
            "key",
            "[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 1\n[stages.ppo]\nlr = 1.0\n",
        );
        let e = load_recipe("key", &d).unwrap_err().0;
        assert!(e.contains("stage 1 (a)") && e.contains("lr"), "{e}");
        write(&d, "nostop", "[[stages]]\nname = \"a\"\n");
        assert!(
            load_recipe("nostop", &d)
                .unwrap_err()
                .0
                .contains("must give iterations")
        );
        write(
            &d,
            "prev",
            "[[stages]]\nname = \"a\"\nstart = \"previous\"\n[stages.stop]\niterations = 1\n",
        );
        assert!(
            load_recipe("prev", &d)
                .unwrap_err()
                .0
                .contains("no previous stage")
        );
        write(
            &d,
            "task_in_env",
            "[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 1\n[stages.env]\ntask = {}\n",
        );
        assert!(
            load_recipe("task_in_env", &d)
                .unwrap_err()
                .0
                .contains("[stages.task]")
        );
        write(
            &d,
            "loop",
            "extends = \"loop\"\n[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 1\n",
        );
        assert!(load_recipe("loop", &d).unwrap_err().0.contains("in a loop"));
        assert!(
            load_recipe("missing", &d)
                .unwrap_err()
                .0
                .contains("unknown recipe")
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    /// An integer where a float goes is taken (as Python's config does): 1 -> 1.0.
    #[test]
    fn integers_coerce_to_floats() {
        let d = tmp("coerce");
        write(
            &d,
            "r",
            "[[stages]]\nname = \"a\"\n[stages.stop]\niterations = 2\n[stages.ppo]\nentropy_coef = 0\n",
        );
        let r = load_recipe("r", &d).unwrap();
        assert_eq!(r.stages[0].config.ppo.entropy_coef, 0.0);
        let _ = std::fs::remove_dir_all(&d);
    }
}
