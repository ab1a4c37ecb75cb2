//! `unigait-server`: serve batched Go2 envs over gRPC, or benchmark the core in process.

// Binary-only commands: the in-process benchmark and the start probe.
mod bench;
mod probe;

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use unigait_policy::SandboxLimits;
use unigait_server::{
    Limits, ServeOptions, TransportLimits, check_token, is_loopback, serve, shutdown_signal,
};
use unigait_sim::task::TaskConfig;

/// The unigait simulation service.
#[derive(Debug, Parser)]
#[command(name = "unigait-server", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Serve the Simulator gRPC service.
    Serve(ServeArgs),
    /// Measure env steps per second of the simulation core, in process.
    Bench(bench::BenchArgs),
    /// Share of episodes a termination ends early when every env holds the default stance.
    Probe(probe::ProbeArgs),
    /// Load and run one client policy under limits, talking over stdin/stdout (started by the
    /// server itself).
    #[command(name = "policy-worker", hide = true)]
    PolicyWorker,
}

#[derive(Debug, clap::Args)]
struct ServeArgs {
    /// Address to bind. Port 0 picks a free port (printed on stdout).
    #[arg(long, default_value = "127.0.0.1:50051")]
    addr: SocketAddr,
    /// Allow an address beyond loopback (then --tls-cert, --tls-key and --token-file are required).
    #[arg(long)]
    allow_remote: bool,
    /// TLS certificate (PEM).
    #[arg(long)]
    tls_cert: Option<PathBuf>,
    /// TLS private key (PEM).
    #[arg(long)]
    tls_key: Option<PathBuf>,
    /// File holding the bearer token clients must send.
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// Task config (TOML) sessions start from; default: the embedded assets/task.toml.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Env worker threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Largest number of envs in one session.
    #[arg(long, default_value_t = Limits::default().max_envs_per_session)]
    max_envs: usize,
    /// Largest number of concurrent sessions.
    #[arg(long, default_value_t = Limits::default().max_sessions)]
    max_sessions: usize,
    /// Seconds an unused session lives (a client whose stream broke may re-attach meanwhile).
    #[arg(long, default_value_t = Limits::default().idle_timeout_s)]
    idle_timeout: u64,
    /// Largest number of envs over all sessions.
    #[arg(long, default_value_t = Limits::default().max_total_envs)]
    max_total_envs: usize,
    /// Seconds a step stream may wait for its client's next request.
    #[arg(long, default_value_t = Limits::default().stream_idle_timeout_s)]
    stream_idle_timeout: u64,
    /// Evaluations running at once.
    #[arg(long, default_value_t = Limits::default().max_concurrent_evaluations)]
    max_evaluations: usize,
    /// Seconds one evaluation may run.
    #[arg(long, default_value_t = Limits::default().max_evaluation_s)]
    max_evaluation_seconds: u64,
    /// Calls on one session in flight at once; more are refused (RESOURCE_EXHAUSTED).
    #[arg(long, default_value_t = Limits::default().max_calls_per_session)]
    max_calls_per_session: usize,
    /// Address space of a policy worker (MiB).
    #[arg(long, default_value_t = SandboxLimits::default().memory_bytes >> 20)]
    policy_memory_mib: u64,
    /// Seconds a shutdown waits for calls in flight.
    #[arg(long, default_value_t = 10)]
    drain_timeout: u64,
    /// Shut down when stdin reaches its end: a parent that holds the other end of a pipe
    /// takes its server with it however it dies (SIGKILL too), with no code run in the
    /// child between fork and exec.
    #[arg(long)]
    exit_on_stdin_eof: bool,
    /// Connections open at once; beyond it new ones wait in the listen backlog.
    #[arg(long, default_value_t = TransportLimits::default().max_connections)]
    max_connections: usize,
    /// HTTP/2 streams (calls) open at once on one connection.
    #[arg(long, default_value_t = TransportLimits::default().max_concurrent_streams)]
    max_concurrent_streams: u32,
    /// Seconds a new connection has to send its first bytes and finish its TLS handshake.
    #[arg(long, default_value_t = TransportLimits::default().handshake_timeout.as_secs())]
    handshake_timeout: u64,
    /// Seconds after which a connection is asked to reconnect (0: never).
    #[arg(long, default_value_t = 0)]
    max_connection_age: u64,
}

fn read(path: &PathBuf) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))
}

async fn run_serve(args: ServeArgs) -> Result<()> {
    let remote = !is_loopback(&args.addr);
    if remote && !args.allow_remote {
        bail!(
            "{} is not a loopback address; pass --allow-remote (with TLS and a token) to serve beyond this machine",
            args.addr
        );
    }
    let tls = match (&args.tls_cert, &args.tls_key) {
        (Some(c), Some(k)) => Some((read(c)?, read(k)?)),
        (None, None) => None,
        _ => bail!("--tls-cert and --tls-key go together"),
    };
    let token = match &args.token_file {
        Some(p) => Some(
            String::from_utf8(read(p)?)
                .context("the token file is not UTF-8")?
                .trim()
                .to_string(),
        ),
        None => None,
    };
    if let Some(t) = &token {
        check_token(t).context("--token-file")?;
    }
    if remote && (tls.is_none() || token.is_none()) {
        bail!("serving beyond loopback needs --tls-cert, --tls-key and --token-file");
    }
    let base_config = match &args.config {
        Some(p) => {
            TaskConfig::from_toml(&String::from_utf8(read(p)?).context("the config is not UTF-8")?)?
        }
        None => TaskConfig::embedded_default(),
    };
    let options = ServeOptions {
        limits: Limits {
            max_envs_per_session: args.max_envs,
            max_sessions: args.max_sessions,
            idle_timeout_s: args.idle_timeout,
            max_total_envs: args.max_total_envs,
            stream_idle_timeout_s: args.stream_idle_timeout,
            max_concurrent_evaluations: args.max_evaluations,
            max_evaluation_s: args.max_evaluation_seconds,
            max_calls_per_session: args.max_calls_per_session.max(1),
            ..Limits::default()
        },
        threads: args.threads,
        base_config,
        tls,
        token,
        policy_worker: Some(std::env::current_exe().context("cannot find this executable")?),
        sandbox: SandboxLimits {
            memory_bytes: args.policy_memory_mib << 20,
            cpu_seconds: args.max_evaluation_seconds,
            ..SandboxLimits::default()
        },
        drain_timeout: std::time::Duration::from_secs(args.drain_timeout),
        transport: TransportLimits {
            max_connections: args.max_connections,
            max_concurrent_streams: args.max_concurrent_streams,
            handshake_timeout: std::time::Duration::from_secs(args.handshake_timeout.max(1)),
            max_connection_age: (args.max_connection_age > 0)
                .then(|| std::time::Duration::from_secs(args.max_connection_age)),
            ..TransportLimits::default()
        },
        ..ServeOptions::default()
    };
    let listener = tokio::net::TcpListener::bind(args.addr)
        .await
        .with_context(|| format!("cannot bind {}", args.addr))?;
    let local = listener.local_addr()?;
    // Scripts and tests wait for this line.
    println!("listening on {local}");
    tracing::info!(%local, threads = options.threads, "serving");
    let exit_on_eof = args.exit_on_stdin_eof;
    let shutdown = async move {
        tokio::select! {
            () = shutdown_signal() => {},
            () = stdin_closed(), if exit_on_eof => {
                tracing::info!("stdin closed: the process that started the server is gone; shutting down");
            }
        }
    };
    serve(listener, options, shutdown).await?;
    Ok(())
}

/// Resolves when stdin reaches its end (or cannot be read). A plain thread reads it: tokio's
/// stdin is a feature the workspace does not build.
async fn stdin_closed() {
    let (closed, rx) = tokio::sync::oneshot::channel::<()>();
    std::thread::spawn(move || {
        use std::io::Read;
        let mut stdin = std::io::stdin().lock();
        let mut buf = [0u8; 256];
        while matches!(stdin.read(&mut buf), Ok(n) if n > 0) {}
        let _ = closed.send(());
    });
    let _ = rx.await;
}

fn main() -> Result<()> {
    // The policy worker starts with nothing else running: it caps its own resources first.
    if std::env::args().nth(1).as_deref() == Some(unigait_policy::WORKER_SUBCOMMAND) {
        return unigait_policy::run_worker().context("policy worker");
    }
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        // Colour codes only on a terminal: logs redirected to a file stay plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    match Cli::parse().command {
        Command::Serve(args) => {
            let runtime = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()?;
            runtime.block_on(run_serve(args))
        }
        Command::Bench(args) => {
            let report = bench::run(&args)?;
            if args.json {
                println!("{}", serde_json::to_string(&report)?);
            } else {
                println!("{}", serde_json::to_string_pretty(&report)?);
            }
            Ok(())
        }
        Command::Probe(args) => {
            println!("{}", serde_json::to_string_pretty(&probe::run(&args)?)?);
            Ok(())
        }
        Command::PolicyWorker => Ok(unigait_policy::run_worker()?),
    }
}
