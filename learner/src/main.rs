//! `unigait-learner`: train the paper's policy over the unigait protocol with no Python.
//!
//! ```text
//! unigait-learner train --recipe quad_flat --log-dir runs/quad_flat_rs [--server ADDR]
//!                       [--iterations N] [--num-envs N] [--seed N]
//! unigait-learner export --checkpoint runs/quad_flat_rs/final.ckpt --out policy.onnx
//! ```

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use unigait_learner::checkpoint::Checkpoint;
use unigait_learner::recipe::{load_recipe, recipes_dir};
use unigait_learner::run::{Overrides, export_checkpoint, run_recipe};
use unigait_learner::server::{LocalServer, server_binary};

#[derive(Parser)]
#[command(name = "unigait-learner", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train every stage of a recipe (the same command again resumes where it stopped).
    Train(TrainArgs),
    /// Export a checkpoint's fused estimator + actor as the ONNX policy the server serves.
    Export {
        /// A `.ckpt` of this learner.
        #[arg(long)]
        checkpoint: PathBuf,
        /// Where the ONNX file goes.
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(clap::Args)]
struct TrainArgs {
    /// The server (HOST:PORT). Without it, a local `unigait-server` is started for the run
    /// (`--server-bin`, else $UNIGAIT_SERVER_BIN, else beside this binary, else on PATH).
    #[arg(long)]
    server: Option<String>,
    /// A recipe of assets/recipes (e.g. quad_flat) or a .toml file.
    #[arg(long)]
    recipe: String,
    /// Each stage's iterations (default: the recipe's).
    #[arg(long)]
    iterations: Option<u64>,
    /// Envs of every stage (default: the recipe's).
    #[arg(long)]
    num_envs: Option<u32>,
    /// Seed of the sessions and the learner (default: the recipe's).
    #[arg(long)]
    seed: Option<u64>,
    /// A config line for every stage, `section.key=value` (repeatable), e.g.
    /// `ppo.entropy_coef=0.005` or `env.task.physics.engine="rapier"`.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    sets: Vec<String>,
    /// Also write each iteration's scalars as TensorBoard events beside each stage's
    /// progress.csv (`tensorboard --logdir LOG_DIR`).
    #[arg(long)]
    tensorboard: bool,
    /// The run's folder: stages, progress.csv, checkpoints, final.ckpt, policy.onnx. A folder
    /// holding a run of the same recipe is resumed.
    #[arg(long)]
    log_dir: PathBuf,
    /// The server binary for a local server.
    #[arg(long)]
    server_bin: Option<PathBuf>,
    /// More `serve` flags for a local server (repeatable, e.g. --server-arg=--threads=2).
    #[arg(long = "server-arg", allow_hyphen_values = true)]
    server_args: Vec<String>,
    /// Where recipe names are looked up (default: $UNIGAIT_RECIPES_DIR or the repository's
    /// assets/recipes).
    #[arg(long)]
    recipes_dir: Option<PathBuf>,
}

fn train(args: TrainArgs) -> Result<()> {
    let dir = args.recipes_dir.clone().unwrap_or_else(recipes_dir);
    let recipe = load_recipe(&args.recipe, &dir)?;
    let overrides = Overrides {
        iterations: args.iterations,
        num_envs: args.num_envs,
        seed: args.seed,
        sets: args.sets,
        tensorboard: args.tensorboard,
    };
    let mut local = None;
    let address = match args.server {
        Some(a) => a,
        None => {
            let bin = server_binary(args.server_bin.as_deref());
            tracing::info!("no --server given: starting {}", bin.display());
            let server = LocalServer::start(&bin, &args.server_args)?;
            tracing::info!("local server listening on {}", server.address);
            let a = server.address.clone();
            local = Some(server);
            a
        }
    };
    // The update runs on this thread inside `block_on`; the connection's task runs on the one
    // worker, so it answers the server's keepalive pings however long an update takes (on a
    // current-thread runtime a 80 s update under load lost the connection).
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    let summary = runtime.block_on(run_recipe(recipe, &overrides, &args.log_dir, &address));
    drop(local);
    let summary = summary?;
    println!(
        "trained to iteration {} ({} env steps): {}, {}",
        summary.iteration,
        summary.total_env_steps,
        summary.final_checkpoint.display(),
        summary.policy.display()
    );
    Ok(())
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        // Colour codes only on a terminal: logs redirected to a file stay plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    match Cli::parse().command {
        Command::Train(args) => train(args),
        Command::Export { checkpoint, out } => {
            let ck = Checkpoint::load(&checkpoint)?;
            let bytes = export_checkpoint(&ck)?;
            std::fs::write(&out, bytes).with_context(|| format!("writing {}", out.display()))?;
            println!("{}", out.display());
            Ok(())
        }
    }
}
