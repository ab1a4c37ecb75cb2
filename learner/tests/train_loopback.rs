//! The learner against the real server over loopback: a few iterations of `quad_flat` with 16
//! envs, a resume that carries on at the right iteration with the checkpoint's state, and the
//! exported policy evaluated by the server.
//!
//! Needs `target/<profile>/unigait-server` (the test command builds the workspace first) or
//! `$UNIGAIT_SERVER_BIN`.

use std::path::{Path, PathBuf};

use prost::Message;

use unigait_client::{Client, v1};
use unigait_learner::checkpoint::Checkpoint;
use unigait_learner::config::TrainConfig;
use unigait_learner::learner::Learner;
use unigait_learner::recipe::{load_recipe, recipes_dir};
use unigait_learner::run::{Overrides, RunSummary, export_checkpoint, run_recipe};
use unigait_learner::server::{LocalServer, server_binary};

const ENVS: u32 = 16;

fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    (header, rows)
}

fn column(header: &[String], rows: &[Vec<String>], name: &str) -> Vec<f64> {
    let i = header
        .iter()
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"));
    rows.iter()
        .map(|r| r[i].parse().unwrap_or(f64::NAN))
        .collect()
}

fn fresh_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("unigait-learner-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn trains_resumes_and_exports_against_the_real_server() {
    let bin = server_binary(None);
    assert!(
        bin.is_file(),
        "no server binary at {}: build it (cargo build --release -p unigait-server) or set \
         UNIGAIT_SERVER_BIN",
        bin.display()
    );
    let server = LocalServer::start(&bin, &["--threads".into(), "1".into()]).unwrap();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let dir = fresh_dir("loopback");
    let recipe = || load_recipe("quad_flat", &recipes_dir()).unwrap();
    let overrides = |iterations| Overrides {
        iterations: Some(iterations),
        num_envs: Some(ENVS),
        seed: Some(3),
        sets: Vec::new(),
        tensorboard: true,
    };

    // Two iterations.
    let first = runtime
        .block_on(run_recipe(recipe(), &overrides(2), &dir, &server.address))
        .unwrap();
    assert_eq!(first.iteration, 2);
    assert_eq!(first.total_env_steps, 2 * 24 * u64::from(ENVS));
    let stage = dir.join("01_quad");
    let (header, rows) = csv(&stage.join("progress.csv"));
    for name in [
        "iteration",
        "total_env_steps",
        "env_steps_per_s",
        "mean_step_reward",
        "mean_episode_reward",
        "mean_episode_length",
        "step_reward/quad_tracking_lin_vel",
        "episode_reward/quad_tracking_lin_vel",
        "learning_rate",
        "action_std",
        "estimator_loss",
        "time_share/update",
    ] {
        assert!(header.iter().any(|c| c == name), "{name} in {header:?}");
    }
    // The Python learner's columns, in its order: the biped's pose, then the terrain level per
    // terrain type and per mode. Four legs on flat ground: level 0, and no biped env-step.
    let at = |name: &str| header.iter().position(|c| c == name).expect(name);
    assert!(at("biped_share") < at("physics_blowups"));
    assert!(at("physics_blowups") < at("biped_pose/pitch"));
    assert!(at("biped_pose/rear_feet_up_share") < at("terrain_level/flat"));
    assert!(at("terrain_level/flat") < at("terrain_level/quad"));
    assert!(at("terrain_level/biped") < at("episodes"));
    // The rollout's extremes close the row, as in the Python learner; no bound loss unless set.
    assert!(at("estimator_loss") < at("rollout/max_abs/labels"));
    assert!(at("rollout/max_abs/rewards") < at("rollout/max_abs_column/labels"));
    assert!(!header.iter().any(|c| c == "bound_loss"));
    for v in column(&header, &rows, "rollout/max_abs/actor_obs") {
        assert!(v.is_finite() && v > 0.0 && v <= 100.0, "{v}");
    }
    assert_eq!(column(&header, &rows, "terrain_level/flat"), [0.0, 0.0]);
    assert_eq!(column(&header, &rows, "physics_blowups"), [0.0, 0.0]);
    assert_eq!(column(&header, &rows, "terrain_level/quad"), [0.0, 0.0]);
    for row in &rows {
        assert_eq!(row[at("terrain_level/biped")], "", "NaN: no biped env-step");
        assert_eq!(
            row[at("biped_pose/upright_share")],
            "",
            "NaN: no biped env-step"
        );
    }
    assert_eq!(column(&header, &rows, "iteration"), [1.0, 2.0]);
    // With a mirror loss the run builds the maps from the real server's spec and logs the
    // figure after the KL (decision record 0033).
    let mirrored_dir = fresh_dir("loopback_mirror");
    let mirrored = Overrides {
        sets: vec!["ppo.mirror_loss_coef=0.2".into()],
        ..overrides(1)
    };
    runtime
        .block_on(run_recipe(
            recipe(),
            &mirrored,
            &mirrored_dir,
            &server.address,
        ))
        .unwrap();
    let (m_header, m_rows) = csv(&mirrored_dir.join("01_quad").join("progress.csv"));
    let m_at = |name: &str| m_header.iter().position(|c| c == name).expect(name);
    assert!(m_at("kl") < m_at("mirror_loss") && m_at("mirror_loss") < m_at("learning_rate"));
    let figure = column(&m_header, &m_rows, "mirror_loss");
    assert!(figure.len() == 1 && figure[0] > 0.0, "{figure:?}");
    assert!(!header.iter().any(|c| c == "mirror_loss"));
    // --tensorboard: the same names and values, step = iteration, in one event file.
    let files: Vec<PathBuf> = std::fs::read_dir(&stage)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains("events.out.tfevents."))
        .collect();
    assert_eq!(files.len(), 1, "{files:?}");
    let bytes = std::fs::read(&files[0]).unwrap();
    let mut events = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let len = u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize;
        let payload = &bytes[at + 12..at + 12 + len];
        events.push(unigait_learner::tensorboard::Event::decode(payload).unwrap());
        at += 16 + len;
    }
    assert_eq!(events.iter().map(|e| e.step).collect::<Vec<_>>(), [0, 1, 2]);
    let kl = column(&header, &rows, "kl");
    for (event, kl) in events[1..].iter().zip(kl) {
        let values = &event.summary.as_ref().unwrap().value;
        let tags: Vec<&str> = values.iter().map(|v| v.tag.as_str()).collect();
        assert_eq!(tags, header.iter().map(String::as_str).collect::<Vec<_>>());
        let logged = values
            .iter()
            .find(|v| v.tag == "kl")
            .unwrap()
            .simple_value
            .unwrap();
        assert!(
            (f64::from(logged) - kl).abs() <= 1e-5 * kl.abs().max(1e-6),
            "{logged} {kl}"
        );
    }
    assert_eq!(column(&header, &rows, "total_env_steps"), [384.0, 768.0]);
    // Rewards came from the server: a standing start earns something per step.
    let reward = column(&header, &rows, "mean_step_reward");
    assert!(
        reward.iter().all(|r| r.is_finite() && *r != 0.0),
        "{reward:?}"
    );
    let ck2 = Checkpoint::load(&stage.join("model_2.ckpt")).unwrap();
    assert_eq!(ck2.header.iteration, 2);
    // Each env's level and its (quad, biped) levels, as the server reported them: flat ground.
    assert_eq!(ck2.header.terrain_levels, vec![0; ENVS as usize]);
    assert_eq!(ck2.header.terrain_mode_levels, vec![0; 2 * ENVS as usize]);
    // The engine the session reported is recorded, and named in the stage's policy.
    let engine = ck2.header.physics_engine.clone();
    assert!(
        ["rapier", "articulated"].contains(&engine.as_str()),
        "{engine:?}"
    );
    let onnx = std::fs::read(stage.join("policy.onnx")).unwrap();
    assert_eq!(unigait_policy::trained_engine(&onnx).unwrap(), Some(engine));

    // The resumed learner holds exactly the checkpoint's state: networks, both optimisers,
    // counters, learning rate, generators (a checkpoint of it has the same header and weights).
    let cfg = TrainConfig::from_table(toml::from_str(&ck2.header.config_toml).unwrap()).unwrap();
    assert_eq!(cfg.env.num_envs, ENVS);
    let mut resumed = Learner::new(cfg, ck2.header.dims, ENVS as usize);
    resumed.load(&ck2, true).unwrap();
    let again = resumed.to_checkpoint().unwrap();
    assert_eq!(again.header.iteration, 2);
    assert_eq!(again.header.learning_rate, ck2.header.learning_rate);
    assert_eq!(again.header.action_rng, ck2.header.action_rng);
    assert_eq!(again.header.update_rng, ck2.header.update_rng);
    let weights = |ck: &Checkpoint| {
        let end = ck.header.ppo_optimizer.offset;
        ck.blobs[..end].to_vec()
    };
    assert_eq!(weights(&again), weights(&ck2));
    // Adam keeps two moments per parameter value: the resumed optimiser holds them for every
    // parameter (the record's byte order varies with a hash map's, so not compared bytewise;
    // the unit test `a_checkpoint_resumes_the_optimisers_exactly` checks the values).
    let ac_bytes: usize = again
        .header
        .actor_critic
        .iter()
        .map(|t| 4 * t.shape.iter().product::<usize>())
        .sum();
    for ck in [&again, &ck2] {
        assert!(
            ck.header.ppo_optimizer.len >= 2 * ac_bytes,
            "{} < 2 x {ac_bytes}",
            ck.header.ppo_optimizer.len
        );
    }

    // The same command with more iterations carries on at iteration 3.
    let second = runtime
        .block_on(run_recipe(recipe(), &overrides(4), &dir, &server.address))
        .unwrap();
    assert_eq!(second.iteration, 4);
    assert_eq!(second.total_env_steps, 4 * 24 * u64::from(ENVS));
    let (header, rows) = csv(&stage.join("progress.csv"));
    assert_eq!(column(&header, &rows, "iteration"), [1.0, 2.0, 3.0, 4.0]);
    let ck4 = Checkpoint::load(&stage.join("model_4.ckpt")).unwrap();
    assert_eq!(ck4.header.iteration, 4);
    assert_ne!(weights(&ck4), weights(&ck2), "the resumed run trained");
    // Another recipe text in the same folder is refused.
    let mut other = recipe();
    other.text.push_str("\n# changed\n");
    let err = runtime
        .block_on(run_recipe(other, &overrides(4), &dir, &server.address))
        .unwrap_err()
        .to_string();
    assert!(err.contains("another recipe text"), "{err}");

    // The exported policy: the run's policy.onnx is the final checkpoint's, and the server
    // evaluates it.
    let onnx = std::fs::read(dir.join("policy.onnx")).unwrap();
    assert_eq!(onnx, export_checkpoint(&ck4).unwrap());
    let response = runtime
        .block_on(async {
            let mut client = Client::connect(&server.address).await?;
            client
                .evaluate(v1::EvaluateRequest {
                    policy_onnx: onnx.into(),
                    scenario: "tracking_quad".into(),
                    num_envs: 2,
                    seed: 5,
                    ..Default::default()
                })
                .await
        })
        .unwrap();
    // M1's scenario ran the policy: its episodes ended or ran out (an untrained one falls).
    let m = &response.metrics;
    let rate = m["tracking/quad/termination_rate"];
    assert!((0.0..=1.0).contains(&rate), "{m:?}");
    assert!(m["wall_s"] > 0.0, "{m:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Run the recipe `text` against a local server (one thread) in a fresh folder: the folder, the
/// run's log directory in it, and the run's summary.
fn run_recipe_text(tag: &str, text: &str) -> (PathBuf, PathBuf, RunSummary) {
    let bin = server_binary(None);
    assert!(bin.is_file(), "no server binary at {}", bin.display());
    let server = LocalServer::start(&bin, &["--threads".into(), "1".into()]).unwrap();
    let dir = fresh_dir(tag);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join(format!("{tag}.toml"));
    std::fs::write(&file, text).unwrap();
    let recipe = load_recipe(file.to_str().unwrap(), &recipes_dir()).unwrap();
    let log_dir = dir.join("run");
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let summary = runtime
        .block_on(run_recipe(
            recipe,
            &Overrides::default(),
            &log_dir,
            &server.address,
        ))
        .unwrap();
    (dir, log_dir, summary)
}

/// A stage with a milestone judges its policy on the validation seed every `check_every`
/// iterations and writes the record (an untrained policy does not meet M1: the stage runs out
/// its iterations, and its confirm seed is never asked).
#[test]
fn a_milestone_stage_checks_on_the_validation_seed() {
    let (dir, log_dir, summary) = run_recipe_text(
        "milestone",
        "milestone = \"M1\"\n[[stages]]\nname = \"quad\"\n[stages.stop]\niterations = 2\n\
         milestone = \"M1\"\ncheck_every = 1\nvalidation_envs = 2\nvalidation_seed = 9\n\
         confirm_seed = 10\n\
         [stages.env]\nnum_envs = 16\n[stages.task.modes]\nbiped_probability = 0.0\n",
    );
    assert_eq!(summary.iteration, 2);
    let text = std::fs::read_to_string(log_dir.join("01_quad/validation.jsonl")).unwrap();
    let records: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(records.len(), 2, "{text}");
    for (i, r) in records.iter().enumerate() {
        assert_eq!(r["iteration"], i as u64 + 1);
        assert_eq!(r["milestone"], "M1");
        assert_eq!(r["criteria"], 3);
        assert_eq!(r["seed"], 9);
        assert!(r["evals"]["tracking_quad"]["tracking/quad/termination_rate"].is_number());
    }
    let done: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(log_dir.join("01_quad/done.json")).unwrap())
            .unwrap();
    assert_eq!(done["reason"], "iterations");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `start_best_of` starts a stage from the best of the previous stage's last checkpoints,
/// each judged on the stage's milestone and seed, and records the choice in `stage.json`.
#[test]
fn a_stage_starts_from_the_best_of_the_previous_stages_checkpoints() {
    let (dir, log_dir, _) = run_recipe_text(
        "best_of",
        "milestone = \"M1\"\n[[stages]]\nname = \"first\"\n[stages.stop]\niterations = 3\n\
         [stages.env]\nnum_envs = 16\n[stages.runner]\nsave_interval = 1\n\
         [stages.task.modes]\nbiped_probability = 0.0\n\
         [[stages]]\nname = \"second\"\nstart = \"previous\"\ncarry = \"all\"\n\
         start_best_of = 2\n[stages.stop]\niterations = 1\nmilestone = \"M1\"\n\
         check_every = 5\nvalidation_envs = 2\nvalidation_seed = 9\n",
    );
    let stage: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(log_dir.join("02_second/stage.json")).unwrap(),
    )
    .unwrap();
    let selection = &stage["start_selection"];
    assert_eq!(selection["milestone"], "M1");
    assert_eq!(selection["seeds"], serde_json::json!([9]));
    let candidates = selection["candidates"].as_array().unwrap();
    let iterations: Vec<u64> = candidates
        .iter()
        .map(|c| c["iteration"].as_u64().unwrap())
        .collect();
    assert_eq!(iterations, [2, 3], "{selection}");
    for c in candidates {
        let score = &c["scores"][0];
        assert_eq!(score["seed"], 9);
        assert!(score["met"].as_u64().unwrap() <= 3, "{score}");
        assert!(score["margin"].as_f64().unwrap().abs() <= 3.0, "{score}");
    }
    // carry = "all": the stage goes on from the chosen checkpoint's iteration.
    let chosen = selection["chosen"].as_str().unwrap();
    let chosen_iteration = if chosen.ends_with("model_2.ckpt") {
        2
    } else {
        3
    };
    assert!(
        chosen.ends_with(&format!("model_{chosen_iteration}.ckpt")),
        "{chosen}"
    );
    assert_eq!(stage["start_iteration"], chosen_iteration);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `start_rank = "pass_chance"` ranks the candidates by the chance of meeting the milestone on
/// one draw (every scenario on `validation_envs`), then the summed margin, the later one.
#[test]
fn a_stage_starts_from_the_best_pass_chance() {
    let (dir, log_dir, _) = run_recipe_text(
        "best_chance",
        "milestone = \"M2\"\n[[stages]]\nname = \"first\"\n[stages.stop]\niterations = 3\n\
         [stages.env]\nnum_envs = 16\n[stages.runner]\nsave_interval = 1\n\
         [[stages]]\nname = \"second\"\nstart = \"previous\"\ncarry = \"all\"\n\
         start_best_of = 2\nstart_rank = \"pass_chance\"\n[stages.stop]\niterations = 1\n\
         milestone = \"M2\"\ncheck_every = 5\nvalidation_envs = 2\nvalidation_seed = 9\n",
    );
    let stage: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(log_dir.join("02_second/stage.json")).unwrap(),
    )
    .unwrap();
    let selection = &stage["start_selection"];
    assert_eq!(selection["rank"], "pass_chance");
    let candidates = selection["candidates"].as_array().unwrap();
    let key = |c: &serde_json::Value| {
        let chance = c["chance"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&chance), "{c}");
        let margin = c["scores"][0]["margin"].as_f64().unwrap();
        (chance, margin, c["iteration"].as_u64().unwrap())
    };
    let best = candidates
        .iter()
        .map(key)
        .max_by(|a, b| {
            a.0.total_cmp(&b.0)
                .then(a.1.total_cmp(&b.1))
                .then(a.2.cmp(&b.2))
        })
        .unwrap();
    let chosen = selection["chosen"].as_str().unwrap();
    assert!(
        chosen.ends_with(&format!("model_{}.ckpt", best.2)),
        "{selection}"
    );
    assert_eq!(stage["start_iteration"], best.2);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `env.terrain_columns` builds the grid the run asks for (decision record 0037), and the log
/// counts the types the server reports for it.
#[test]
fn a_run_on_a_grid_of_its_own_logs_its_columns() {
    let server =
        LocalServer::start(&server_binary(None), &["--threads".into(), "1".into()]).unwrap();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let dir = fresh_dir("grid");
    let overrides = Overrides {
        iterations: Some(1),
        num_envs: Some(ENVS),
        seed: Some(3),
        sets: vec![
            "env.terrain = \"curriculum\"".into(),
            "env.terrain_columns = [\"stairs_down\", \"slope_up\", \"slope_up\"]".into(),
        ],
        tensorboard: false,
    };
    let recipe = load_recipe("quad_flat", &recipes_dir()).unwrap();
    runtime
        .block_on(run_recipe(recipe, &overrides, &dir, &server.address))
        .unwrap();
    let (header, _) = csv(&dir.join("01_quad").join("progress.csv"));
    let mut levels: Vec<&str> = header
        .iter()
        .map(String::as_str)
        .filter(|h| h.starts_with("terrain_level/") && h.matches('/').count() == 1)
        .collect();
    levels.sort_unstable();
    assert_eq!(
        levels,
        [
            "terrain_level/biped",
            "terrain_level/quad",
            "terrain_level/slope_up",
            "terrain_level/stairs_down"
        ]
    );
    let _ = std::fs::remove_dir_all(&dir);
}
