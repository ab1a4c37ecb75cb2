//! `unigait-learner train --set`: config lines merged into every stage of a recipe.

use unigait_learner::recipe::{load_recipe, recipes_dir};
use unigait_learner::run::{Overrides, run_recipe};

fn overrides(sets: &[&str]) -> Overrides {
    Overrides {
        iterations: None,
        num_envs: Some(16),
        seed: None,
        sets: sets.iter().map(|s| s.to_string()).collect(),
        tensorboard: false,
    }
}

#[test]
fn set_lines_reach_every_stage_before_the_flags() {
    let recipe = load_recipe("unified_flat", &recipes_dir()).unwrap();
    let before: Vec<f64> = recipe
        .stages
        .iter()
        .map(|s| s.config.ppo.entropy_coef)
        .collect();
    assert_eq!(before.len(), 3);
    let sets = [
        "ppo.entropy_coef=0.004",
        "env.task.physics.engine=\"articulated\"",
        "env.num_envs=64",
    ];
    let changed = overrides(&sets).apply(recipe).unwrap();
    for s in &changed.stages {
        assert_eq!(s.config.ppo.entropy_coef, 0.004, "{}", s.name);
        // The recipe pins rapier; the line overrides it.
        assert_eq!(s.config.task_engine(), Some("articulated"), "{}", s.name);
        // --num-envs comes after the lines.
        assert_eq!(s.config.env.num_envs, 16, "{}", s.name);
    }
}

#[test]
fn a_bad_set_line_fails_before_the_run_starts() {
    let dir = std::env::temp_dir().join(format!("unigait-set-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    for (line, named) in [
        ("ppo.entropy=0.1", "entropy"),
        ("entropy_coef=0.1", "section.key=value"),
    ] {
        let recipe = load_recipe("quad_flat", &recipes_dir()).unwrap();
        // No server listens there: the line is refused before anything connects.
        let err = runtime
            .block_on(run_recipe(recipe, &overrides(&[line]), &dir, "127.0.0.1:9"))
            .unwrap_err()
            .to_string();
        assert!(err.contains(named), "{line}: {err}");
        assert!(!dir.exists(), "{line}: the log directory was started");
    }
}
