//! `unigait`: command-line client of the unigait service.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use unigait_client::{Client, compliance, v1};

const DEFAULT_SERVER: &str = "127.0.0.1:50051";

/// The host part of a server address (`https://host:port/...`, `host:port`, `[::1]:port`).
fn host_of(addr: &str) -> String {
    let rest = addr.split_once("://").map_or(addr, |(_, r)| r);
    let authority = rest.split('/').next().unwrap_or(rest);
    if let Some(v6) = authority.strip_prefix('[') {
        return v6.split(']').next().unwrap_or(v6).to_string();
    }
    authority
        .rsplit_once(':')
        .map_or(authority, |(h, _)| h)
        .to_string()
}

async fn connect(cli: &Cli) -> Result<Client> {
    let token = match (&cli.token, &cli.token_file) {
        (Some(t), _) => Some(t.trim().to_string()),
        (None, Some(path)) => Some(
            std::fs::read_to_string(path)
                .with_context(|| format!("cannot read the token file {}", path.display()))?
                .trim()
                .to_string(),
        ),
        (None, None) => None,
    };
    let ca = match &cli.tls_ca {
        Some(path) => Some(
            std::fs::read(path)
                .with_context(|| format!("cannot read the CA certificate {}", path.display()))?,
        ),
        None => None,
    };
    let domain = cli
        .tls_domain
        .clone()
        .unwrap_or_else(|| host_of(&cli.server));
    let tls = ca.as_deref().map(|ca| (ca, domain.as_str()));
    let connected = Client::connect_with(&cli.server, token.as_deref(), tls).await;
    match connected {
        Ok(c) => Ok(c),
        Err(e @ unigait_client::ClientError::Connect { .. }) => Err(anyhow::Error::new(e).context(
            format!(
                "no unigait server answers at {}; start one with `unigait-server serve --addr {}` (or pass --server HOST:PORT)",
                cli.server,
                if cli.server.contains("://") { DEFAULT_SERVER } else { &cli.server }
            ),
        )),
        Err(e) => Err(e.into()),
    }
}

#[derive(Debug, Parser)]
#[command(
    name = "unigait-client",
    version,
    about = "Command-line client of the unigait service"
)]
struct Cli {
    /// Server address: HOST:PORT, http://HOST:PORT, or https://HOST:PORT (with --tls-ca).
    #[arg(long, global = true, default_value = DEFAULT_SERVER)]
    server: String,
    /// Bearer token (for servers beyond loopback). Prefer the environment or --token-file: a
    /// token on the command line shows in the process list.
    #[arg(long, global = true, env = "UNIGAIT_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// File holding the bearer token.
    #[arg(
        long,
        global = true,
        env = "UNIGAIT_TOKEN_FILE",
        conflicts_with = "token"
    )]
    token_file: Option<PathBuf>,
    /// CA certificate (PEM) to check the server's TLS certificate with; turns TLS on.
    #[arg(long, global = true, env = "UNIGAIT_TLS_CA")]
    tls_ca: Option<PathBuf>,
    /// Name the server's certificate must carry (default: the host of --server).
    #[arg(long, global = true)]
    tls_domain: Option<String>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Server version and limits, and the spec a session config gets.
    Info {
        /// Envs of the probe session.
        #[arg(long, default_value_t = 1)]
        envs: u32,
        /// Task overrides (TOML) of the probe session.
        #[arg(long, default_value = "")]
        overrides: String,
    },
    /// Env steps per second over the wire (same JSON fields as `unigait-server bench`).
    Bench(BenchArgs),
    /// Run the protocol compliance suite against the server.
    Check,
    /// Evaluate an ONNX policy on one of the paper's scenarios (server-side rollouts); the same
    /// verb as `python -m unigait evaluate` (`eval` is kept as an alias).
    #[command(alias = "eval")]
    Evaluate(unigait_client::eval::EvalArgs),
    /// Evaluate a policy and write, send or serve a rerun recording of the rollout.
    Record(unigait_client::eval::RecordArgs),
    /// Send a saved rerun recording to a viewer or serve it (no simulation server needed).
    Replay(unigait_client::eval::ReplayArgs),
}

#[derive(Clone, Copy, Debug, ValueEnum, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
enum Actions {
    Stand,
    Random,
}

#[derive(Debug, clap::Args)]
struct BenchArgs {
    #[arg(long, default_value_t = 512)]
    envs: u32,
    #[arg(long, default_value_t = 200)]
    steps: usize,
    #[arg(long, value_enum, default_value_t = Actions::Random)]
    actions: Actions,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[arg(long)]
    json: bool,
}

#[derive(Serialize)]
struct RemoteBench {
    env_steps_per_sec: f64,
    physics_steps_per_sec: f64,
    env_steps_per_sec_per_thread: f64,
    envs: u32,
    threads: u32,
    actions: Actions,
    steps: usize,
    transport: &'static str,
    wall_s: f64,
}

async fn bench(client: &mut Client, args: &BenchArgs) -> Result<RemoteBench> {
    let info = client.server_info().await?;
    let config = v1::SessionConfig {
        num_envs: args.envs,
        seed: args.seed,
        ..Default::default()
    };
    let mut session = client.create_session(config).await?;
    let decimation = session.spec.0.decimation as f64;
    let n = args.envs as usize * 12;
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let pool: Vec<Vec<f32>> = match args.actions {
        Actions::Stand => vec![vec![0.0; n]],
        Actions::Random => (0..16)
            .map(|_| (0..n).map(|_| rng.random_range(-1.0f32..=1.0)).collect())
            .collect(),
    };
    let mut stream = session.stream().await?;
    for i in 0..20 {
        stream.step(&pool[i % pool.len()]).await?;
    }
    let start = Instant::now();
    for i in 0..args.steps {
        stream.step(&pool[i % pool.len()]).await?;
    }
    let wall = start.elapsed().as_secs_f64();
    drop(stream);
    session.close().await?;
    let rate = (args.envs as usize * args.steps) as f64 / wall;
    Ok(RemoteBench {
        env_steps_per_sec: rate,
        physics_steps_per_sec: rate * decimation,
        env_steps_per_sec_per_thread: rate / f64::from(info.threads.max(1)),
        envs: args.envs,
        threads: info.threads,
        actions: args.actions,
        steps: args.steps,
        transport: "grpc",
        wall_s: wall,
    })
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        // Colour codes only on a terminal: logs redirected to a file stay plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let cli = Cli::parse();
    if let Command::Replay(args) = &cli.command {
        return unigait_client::eval::run_replay(args).await;
    }
    let mut client = connect(&cli).await?;
    match cli.command {
        Command::Info { envs, overrides } => {
            let info = client.server_info().await?;
            println!(
                "server {} (protocol {}), {} threads",
                info.server_version, info.protocol_version, info.threads
            );
            println!(
                "limits: {} envs per session, {} sessions ({} open), messages up to {} bytes",
                info.max_envs_per_session,
                info.max_sessions,
                info.active_sessions,
                info.max_message_bytes
            );
            let config = v1::SessionConfig {
                num_envs: envs,
                task_overrides_toml: overrides,
                ..Default::default()
            };
            let session = client.create_session(config).await?;
            let spec = &session.spec.0;
            println!(
                "session: {} envs, policy dt {} s ({} x {} s), episodes of {} steps, terrain {}",
                spec.num_envs,
                spec.policy_dt,
                spec.decimation,
                spec.physics_dt,
                spec.max_episode_steps,
                spec.terrain
            );
            for t in &spec.tensors {
                let fields: Vec<String> = t
                    .fields
                    .iter()
                    .map(|f| format!("{}[{}..{}]", f.name, f.offset, f.offset + f.size))
                    .collect();
                println!("  {:<22} {:?} {}", t.name, t.shape, fields.join(" "));
            }
            println!("  reward terms: {}", spec.reward_terms.join(", "));
            session.close().await?;
        }
        Command::Bench(args) => {
            let report = bench(&mut client, &args).await?;
            if args.json {
                println!("{}", serde_json::to_string(&report)?);
            } else {
                println!("{}", serde_json::to_string_pretty(&report)?);
            }
        }
        Command::Evaluate(args) => unigait_client::eval::run_eval(&mut client, &args).await?,
        Command::Record(args) => unigait_client::eval::run_record(&mut client, &args).await?,
        // Handled before connecting.
        Command::Replay(_) => {}
        Command::Check => {
            let outcomes = compliance::run_all(&client).await;
            let failed = outcomes.iter().filter(|o| !o.passed).count();
            for o in &outcomes {
                let mark = if o.passed { "ok  " } else { "FAIL" };
                println!(
                    "{mark} {}{}{}",
                    o.name,
                    if o.passed { "" } else { ": " },
                    o.detail
                );
            }
            println!("{} passed, {} failed", outcomes.len() - failed, failed);
            if failed > 0 {
                bail!("{failed} compliance checks failed");
            }
        }
    }
    Ok(())
}
