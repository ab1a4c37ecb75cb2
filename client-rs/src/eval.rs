//! Evaluating an ONNX policy on the server: `unigait-client evaluate` and `unigait-client record`.
//!
//! The server rolls the policy out on its own envs over a named scenario (see the server's
//! scenario list: the Table VI columns `stairs_up_quad` ... `stairs_down_biped`, `table_vi`,
//! `transition_biped_to_quad`, `transition_quad_to_biped`, `tracking_quad`, `tracking_biped`,
//! `flat_quad`, `flat_biped`) and answers with metrics, a JSON report and, for `record`, a
//! rerun recording of one trial (`--record-env`, default 0): written to a file (`--out`), sent
//! to a running viewer (`--connect`), or served from this process for a viewer to join
//! (`--serve`, until Ctrl-C or `--serve-for`).

use std::collections::HashMap;
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result};
use unigait_proto::v1;
use unigait_rrd::{DEFAULT_SERVE_PORT, MemoryLimit, ServeOptions, Served};

use crate::Client;

/// The policy, scenario and envs an evaluation runs.
#[derive(Clone, Debug, clap::Args)]
pub struct RolloutArgs {
    /// The ONNX policy (input [batch, 3, 53], output [batch, 12]); the quad policy of the
    /// two-policy baseline when --biped-policy is given.
    #[arg(long)]
    pub policy: PathBuf,
    /// Scenario name, e.g. stairs_up_quad, table_vi, transition_biped_to_quad.
    #[arg(long)]
    pub scenario: String,
    /// A biped policy: evaluate the two-policy baseline (switched at the mode change).
    #[arg(long)]
    pub biped_policy: Option<PathBuf>,
    /// Envs (trials); 0 = the scenario's default.
    #[arg(long, default_value_t = 0)]
    pub envs: u32,
    /// Seed of the server's envs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// A TOML line overriding the server's task config for this evaluation, e.g.
    /// `--set 'physics.engine = "articulated"'` (repeatable).
    #[arg(long = "set", value_name = "TOML")]
    pub overrides: Vec<String>,
}

/// `unigait-client evaluate`: evaluate a policy and print its metrics.
#[derive(Clone, Debug, clap::Args)]
pub struct EvalArgs {
    /// What to evaluate.
    #[command(flatten)]
    pub rollout: RolloutArgs,
    /// Print the full JSON report on stdout (the table goes to stderr).
    #[arg(long)]
    pub json: bool,
}

/// A viewer's gRPC proxy, where `rerun` listens by default.
pub const DEFAULT_VIEWER_URL: &str = "rerun+http://127.0.0.1:9876/proxy";

/// How long `--connect` waits for the viewer to take the recording.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(30);

/// `unigait-client record`: evaluate a policy and save, send or serve a rerun recording of one env.
#[derive(Clone, Debug, clap::Args)]
#[command(group(
    clap::ArgGroup::new("output")
        .required(true)
        .args(["out", "connect", "serve"])
))]
pub struct RecordArgs {
    /// What to evaluate.
    #[command(flatten)]
    pub rollout: RolloutArgs,
    /// Write the recording to this file (open it with `rerun rollout.rrd`).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Send the recording to a running viewer (start one with `rerun`; bare --connect: its
    /// default rerun+http://127.0.0.1:9876/proxy).
    #[arg(long, value_name = "URL", num_args = 0..=1, default_missing_value = DEFAULT_VIEWER_URL)]
    pub connect: Option<String>,
    /// Serve the recording from this process for a viewer to join with
    /// `rerun --connect rerun+http://HOST:PORT/proxy` (the URL is printed). Bare --serve:
    /// 127.0.0.1:9876; a bare PORT listens on loopback; port 0 takes a free port. The proxy has
    /// no authentication: bind beyond loopback (0.0.0.0:PORT) only on a trusted network.
    #[arg(
        long,
        value_name = "ADDR:PORT",
        num_args = 0..=1,
        default_missing_value = "127.0.0.1:9876",
        value_parser = parse_serve_addr
    )]
    pub serve: Option<SocketAddr>,
    /// With --serve: stop serving after this many seconds (default: until Ctrl-C).
    // `requires` alone lets `--out F --serve-for 3` through: clap deems a requirement that
    // conflicts with a present flag met. Hence the explicit conflicts.
    #[arg(
        long,
        value_name = "SECONDS",
        requires = "serve",
        conflicts_with_all = ["out", "connect"],
        value_parser = parse_seconds
    )]
    pub serve_for: Option<Duration>,
    /// With --serve: cap on the data buffered for viewers (e.g. 256MB, 2GB, 10%; default
    /// 1GiB); past it the oldest data is dropped, so a viewer would miss the rollout's start.
    #[arg(
        long,
        value_name = "LIMIT",
        requires = "serve",
        conflicts_with_all = ["out", "connect"],
        value_parser = parse_memory_limit
    )]
    pub serve_memory_limit: Option<MemoryLimit>,
    /// The trial the recording follows (camera, plots, gait diagram), numbered across the
    /// scenario's cases as the report lists them (a traversal's forward trials, then its
    /// backward ones); the lowest indices of its case are the other tabs of the 3D view.
    #[arg(long, value_name = "K", default_value_t = 0)]
    pub record_env: u32,
}

/// Where `unigait-client record` puts the recording.
#[derive(Clone, Debug, PartialEq)]
pub enum RecordOutput {
    /// An `.rrd` file.
    File(PathBuf),
    /// A running viewer's gRPC proxy URL.
    Connect(String),
    /// Served from this process, for `until` (None: until Ctrl-C).
    Serve {
        /// Address and memory limit.
        options: ServeOptions,
        /// How long to serve.
        until: Option<Duration>,
    },
}

impl RecordArgs {
    /// The output the flags ask for (clap makes exactly one of them present).
    pub fn output(&self) -> Result<RecordOutput> {
        if let Some(out) = &self.out {
            return Ok(RecordOutput::File(out.clone()));
        }
        if let Some(url) = &self.connect {
            return Ok(RecordOutput::Connect(url.clone()));
        }
        if let Some(addr) = self.serve {
            let mut options = ServeOptions {
                addr,
                ..ServeOptions::default()
            };
            if let Some(limit) = self.serve_memory_limit {
                options.memory_limit = limit;
            }
            return Ok(RecordOutput::Serve {
                options,
                until: self.serve_for,
            });
        }
        anyhow::bail!("give one of --out, --connect, --serve")
    }
}

/// `ADDR:PORT`, or a bare `PORT` on loopback (serving beyond loopback must be asked for).
fn parse_serve_addr(s: &str) -> Result<SocketAddr, String> {
    if let Ok(port) = s.parse::<u16>() {
        return Ok(SocketAddr::from((Ipv4Addr::LOCALHOST, port)));
    }
    s.parse().map_err(|_| {
        format!("expected ADDR:PORT (e.g. 127.0.0.1:{DEFAULT_SERVE_PORT}) or a port, got `{s}`")
    })
}

fn parse_seconds(s: &str) -> Result<Duration, String> {
    let secs: f64 = s
        .parse()
        .map_err(|_| format!("expected seconds, got `{s}`"))?;
    Duration::try_from_secs_f64(secs).map_err(|_| format!("expected seconds >= 0, got `{s}`"))
}

fn parse_memory_limit(s: &str) -> Result<MemoryLimit, String> {
    MemoryLimit::parse(s)
}

fn read_policy(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("cannot read policy `{}`", path.display()))
}

/// An Evaluate request from policy files; `record_env`: a recording following that env.
pub fn request(args: &RolloutArgs, record_env: Option<u32>) -> Result<v1::EvaluateRequest> {
    Ok(v1::EvaluateRequest {
        policy_onnx: read_policy(&args.policy)?.into(),
        biped_policy_onnx: match &args.biped_policy {
            Some(p) => read_policy(p)?.into(),
            None => Default::default(),
        },
        scenario: args.scenario.clone(),
        num_envs: args.envs,
        seed: args.seed,
        record: record_env.is_some(),
        record_env,
        task_overrides_toml: args.overrides.join("\n"),
    })
}

/// The metrics as an aligned two-column table, sorted by name.
pub fn format_table(metrics: &HashMap<String, f64>) -> String {
    let mut rows: Vec<(&String, &f64)> = metrics.iter().collect();
    rows.sort_by(|a, b| a.0.cmp(b.0));
    let width = rows.iter().map(|(k, _)| k.len()).max().unwrap_or(6).max(6);
    let mut out = format!("{:<width$}  value\n", "metric");
    for (k, v) in rows {
        let value = if v.fract() == 0.0 && v.abs() < 1e12 {
            format!("{v:.0}")
        } else {
            format!("{v:.4}")
        };
        out.push_str(&format!("{k:<width$}  {value}\n"));
    }
    out
}

/// `unigait-client evaluate`: print the metrics table (and the JSON report with `--json`).
pub async fn run_eval(client: &mut Client, args: &EvalArgs) -> Result<()> {
    let reply = client
        .evaluate(request(&args.rollout, None)?)
        .await
        .with_context(|| format!("evaluating on `{}`", args.rollout.scenario))?;
    let table = format_table(&reply.metrics);
    if args.json {
        eprint!("{table}");
        println!("{}", reply.report_json);
    } else {
        print!("{table}");
    }
    Ok(())
}

/// `unigait-client record`: print the metrics table and write, send or serve the recording.
pub async fn run_record(client: &mut Client, args: &RecordArgs) -> Result<()> {
    // Flags and the serve address first: neither must cost a rollout.
    let output = args.output()?;
    if let RecordOutput::Serve { options, .. } = &output {
        options.check()?;
    }
    let reply = client
        .evaluate(request(&args.rollout, Some(args.record_env))?)
        .await
        .with_context(|| format!("recording `{}`", args.rollout.scenario))?;
    if reply.recording_rrd.is_empty() {
        anyhow::bail!("the server sent no recording");
    }
    deliver(
        reply.recording_rrd.into(),
        output,
        &format_table(&reply.metrics),
    )
    .await
}

/// `unigait-client replay`: send or serve a saved recording (e.g. the main job's
/// `runs/main/rollout.rrd`), its viewer layout included, to viewers.
#[derive(Clone, Debug, clap::Args)]
#[command(group(
    clap::ArgGroup::new("output")
        .required(true)
        .args(["connect", "serve"])
))]
pub struct ReplayArgs {
    /// The `.rrd` recording.
    pub file: PathBuf,
    /// Send it to a running viewer (bare --connect: rerun+http://127.0.0.1:9876/proxy).
    #[arg(long, value_name = "URL", num_args = 0..=1, default_missing_value = DEFAULT_VIEWER_URL)]
    pub connect: Option<String>,
    /// Serve it for viewers to join (as `record --serve`).
    #[arg(
        long,
        value_name = "ADDR:PORT",
        num_args = 0..=1,
        default_missing_value = "127.0.0.1:9876",
        value_parser = parse_serve_addr
    )]
    pub serve: Option<SocketAddr>,
    /// With --serve: stop serving after this many seconds (default: until Ctrl-C).
    #[arg(
        long,
        value_name = "SECONDS",
        requires = "serve",
        conflicts_with = "connect",
        value_parser = parse_seconds
    )]
    pub serve_for: Option<Duration>,
    /// With --connect: send the rollout up to this policy step only; the viewer, following
    /// the stream, stops there (scripts/render_recording.py photographs it).
    #[arg(long, value_name = "STEP", requires = "connect")]
    pub until_step: Option<i64>,
}

impl ReplayArgs {
    /// The output the flags ask for (clap makes exactly one of them present).
    pub fn output(&self) -> Result<RecordOutput> {
        if let Some(url) = &self.connect {
            return Ok(RecordOutput::Connect(url.clone()));
        }
        if let Some(addr) = self.serve {
            return Ok(RecordOutput::Serve {
                options: ServeOptions {
                    addr,
                    ..ServeOptions::default()
                },
                until: self.serve_for,
            });
        }
        anyhow::bail!("give one of --connect, --serve")
    }
}

/// `unigait-client replay`: send or serve a saved recording. Needs no simulation server.
pub async fn run_replay(args: &ReplayArgs) -> Result<()> {
    let output = args.output()?;
    let rrd = std::fs::read(&args.file)
        .with_context(|| format!("cannot read `{}`", args.file.display()))?;
    if let (Some(last), RecordOutput::Connect(url)) = (args.until_step, &output) {
        let to = url.clone();
        tokio::task::spawn_blocking(move || {
            unigait_rrd::send_rrd_until(&rrd, &to, CONNECT_TIMEOUT, Some(last))
        })
        .await??;
        eprintln!("sent the recording up to step {last} to the viewer at {url}");
        return Ok(());
    }
    deliver(rrd, output, "").await
}

/// Write, send or serve a recording; `table` (the metrics) goes to stdout.
async fn deliver(rrd: Vec<u8>, output: RecordOutput, table: &str) -> Result<()> {
    match output {
        RecordOutput::File(out) => {
            std::fs::write(&out, &rrd)
                .with_context(|| format!("cannot write `{}`", out.display()))?;
            print!("{table}");
            eprintln!(
                "wrote {} ({} bytes): open it with `rerun {}`",
                out.display(),
                rrd.len(),
                out.display()
            );
        }
        RecordOutput::Connect(url) => {
            print!("{table}");
            let to = url.clone();
            // rerun's sinks block until the viewer has the data: off the async workers.
            tokio::task::spawn_blocking(move || unigait_rrd::send_rrd(&rrd, &to, CONNECT_TIMEOUT))
                .await??;
            eprintln!("sent the recording to the viewer at {url}");
        }
        RecordOutput::Serve { options, until } => {
            let served = tokio::task::spawn_blocking(move || Served::rrd(&rrd, &options)).await??;
            print!("{table}");
            let url = served.url();
            let how_long = match until {
                Some(d) => format!("for {} s or until Ctrl-C", d.as_secs_f64()),
                None => "until Ctrl-C".into(),
            };
            eprintln!(
                "serving the recording on {} {how_long}: join with `rerun --connect {url}`",
                served.addr()
            );
            let stopped = match until {
                Some(d) => tokio::select! {
                    r = tokio::signal::ctrl_c() => r,
                    () = tokio::time::sleep(d) => Ok(()),
                },
                None => tokio::signal::ctrl_c().await,
            };
            // Stop serving even if Ctrl-C could not be watched, then report that.
            tokio::task::spawn_blocking(move || served.shutdown()).await??;
            stopped.context("cannot watch for Ctrl-C")?;
            eprintln!("stopped serving");
        }
    }
    Ok(())
}

#[cfg(test)]
mod test {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        record: RecordArgs,
    }

    fn parse(flags: &[&str]) -> Result<RecordOutput> {
        let argv = ["unigait", "--policy", "p.onnx", "--scenario", "flat_quad"];
        let cli = Cli::try_parse_from(argv.iter().chain(flags))?;
        cli.record.output()
    }

    fn serve(addr: &str, until: Option<Duration>, memory_limit: MemoryLimit) -> RecordOutput {
        RecordOutput::Serve {
            options: ServeOptions {
                addr: addr.parse().expect("an address"),
                memory_limit,
            },
            until,
        }
    }

    #[test]
    fn record_outputs_from_flags() {
        let default_limit = ServeOptions::default().memory_limit;
        assert_eq!(
            parse(&["--out", "r.rrd"]).unwrap(),
            RecordOutput::File("r.rrd".into())
        );
        assert_eq!(
            parse(&["--connect"]).unwrap(),
            RecordOutput::Connect(DEFAULT_VIEWER_URL.into())
        );
        assert_eq!(
            parse(&["--serve"]).unwrap(),
            serve("127.0.0.1:9876", None, default_limit)
        );
        assert_eq!(
            parse(&["--serve", "9000", "--serve-for", "2.5"]).unwrap(),
            serve(
                "127.0.0.1:9000",
                Some(Duration::from_millis(2500)),
                default_limit
            )
        );
        assert_eq!(
            parse(&["--serve", "0.0.0.0:9000", "--serve-memory-limit", "256MB"]).unwrap(),
            serve("0.0.0.0:9000", None, MemoryLimit::from_bytes(256_000_000))
        );
    }

    #[test]
    fn record_output_flags_are_checked() {
        for bad in [
            &[][..],
            &["--out", "r.rrd", "--serve"],
            &["--connect", "--serve"],
            &["--out", "r.rrd", "--serve-for", "3"],
            &["--connect", "--serve-memory-limit", "1GB"],
            &["--serve-for", "3"],
            &["--serve", "localhost:9000"],
            &["--serve", "--serve-for", "-1"],
            &["--serve", "--serve-for", "soon"],
            &["--serve", "--serve-memory-limit", "lots"],
        ] {
            assert!(parse(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[derive(Debug, Parser)]
    struct ReplayCli {
        #[command(flatten)]
        replay: ReplayArgs,
    }

    #[test]
    fn replay_outputs_from_flags() {
        let parse = |flags: &[&str]| -> Result<RecordOutput> {
            let argv = ["unigait", "rollout.rrd"];
            ReplayCli::try_parse_from(argv.iter().chain(flags))?
                .replay
                .output()
        };
        assert_eq!(
            parse(&["--connect"]).unwrap(),
            RecordOutput::Connect(DEFAULT_VIEWER_URL.into())
        );
        assert_eq!(
            parse(&["--serve", "0", "--serve-for", "1"]).unwrap(),
            serve(
                "127.0.0.1:0",
                Some(Duration::from_secs(1)),
                ServeOptions::default().memory_limit
            )
        );
        for bad in [&[][..], &["--connect", "--serve"], &["--serve-for", "1"]] {
            assert!(parse(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn table_is_sorted_and_aligned() {
        let metrics = HashMap::from([
            ("trials".to_string(), 20.0),
            ("success_rate".to_string(), 0.95),
        ]);
        let t = format_table(&metrics);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines[1], "success_rate  0.9500");
        assert_eq!(lines[2], "trials        20");
    }
}
