//! Soak the server over loopback: 8 concurrent clients create sessions, step them over streams,
//! and either close them or vanish mid-stream (their connection dropped with a step in flight),
//! for a bounded time. Reports requests served, sessions leaked once the idle timeout has
//! passed (must be 0) and the server's RSS at start, middle and end.
//!
//! ```sh
//! cargo build --release -p unigait-server -p unigait-client --examples
//! ./target/release/examples/soak --seconds 120
//! ```

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use unigait_client::{Client, v1};

const CLIENTS: usize = 8;
const IDLE_TIMEOUT_S: u64 = 2;

struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

async fn client_loop(
    addr: String,
    seed: u64,
    until: Instant,
    served: Arc<AtomicU64>,
) -> Result<()> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    while Instant::now() < until {
        // A fresh connection per session, so vanishing drops a real connection.
        let mut client = Client::connect(&addr).await?;
        let envs = rng.random_range(1..=16u32);
        let mut session = match client
            .create_session(v1::SessionConfig {
                num_envs: envs,
                seed: rng.random(),
                ..Default::default()
            })
            .await
        {
            Ok(s) => s,
            // Over the session limit while others' vanished sessions wait for the idle timeout.
            Err(e) if e.code() == Some(tonic::Code::ResourceExhausted) => {
                tokio::time::sleep(Duration::from_millis(200)).await;
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        served.fetch_add(1, Ordering::Relaxed);
        let mut stream = session.stream().await?;
        let steps = rng.random_range(5..60);
        let vanish = rng.random_bool(0.3);
        for k in 0..steps {
            let actions: Vec<f32> = (0..envs as usize * 12)
                .map(|_| rng.random_range(-1.0f32..=1.0))
                .collect();
            if vanish && k == steps / 2 {
                // Leave with a step in flight: no close, the connection just goes.
                stream.send(&actions, false).await?;
                break;
            }
            stream.step(&actions).await?;
            served.fetch_add(1, Ordering::Relaxed);
        }
        if vanish {
            drop(stream);
            drop(session);
            drop(client);
            continue;
        }
        drop(stream);
        session.close().await?;
        served.fetch_add(1, Ordering::Relaxed);
    }
    Ok(())
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let seconds: u64 = match args.iter().position(|a| a == "--seconds") {
        Some(i) => args.get(i + 1).context("--seconds N")?.parse()?,
        None => 60,
    };
    if seconds > 600 {
        bail!("the soak is bounded: at most 600 s");
    }
    let exe = std::env::current_exe()?;
    let server_bin = exe
        .parent()
        .and_then(|p| p.parent())
        .map(|p| p.join("unigait-server"))
        .context("no target directory")?;
    let mut child = Command::new(&server_bin)
        .args(["serve", "--addr", "127.0.0.1:0", "--threads", "2"])
        .args(["--idle-timeout", &IDLE_TIMEOUT_S.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .with_context(|| format!("cannot start {}", server_bin.display()))?;
    let stdout = child.stdout.take().context("stdout")?;
    let pid = child.id();
    let server = Server(child);
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line)?;
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .context("the server did not print its address")?
        .to_string();
    let rss_start = rss_kib(pid);
    let start = Instant::now();
    let until = start + Duration::from_secs(seconds);
    let served = Arc::new(AtomicU64::new(0));
    let tasks: Vec<_> = (0..CLIENTS)
        .map(|i| tokio::spawn(client_loop(addr.clone(), i as u64, until, served.clone())))
        .collect();
    tokio::time::sleep(Duration::from_secs(seconds / 2)).await;
    let rss_middle = rss_kib(pid);
    for t in tasks {
        t.await??;
    }
    let rss_end_busy = rss_kib(pid);
    // Vanished clients' sessions go at the idle timeout (the reaper runs every timeout / 2).
    tokio::time::sleep(Duration::from_secs(IDLE_TIMEOUT_S * 2 + 1)).await;
    let mut observer = Client::connect(&addr).await?;
    let info = observer.server_info().await?;
    let rss_end = rss_kib(pid);
    let report = serde_json::json!({
        "seconds": start.elapsed().as_secs_f64(),
        "clients": CLIENTS,
        "requests_served": served.load(Ordering::Relaxed),
        "sessions_leaked": info.active_sessions,
        "envs_leaked": info.active_envs,
        "rss_kib_start": rss_start,
        "rss_kib_middle": rss_middle,
        "rss_kib_end_busy": rss_end_busy,
        "rss_kib_end_idle": rss_end,
    });
    println!("{}", serde_json::to_string_pretty(&report)?);
    drop(server);
    if info.active_sessions != 0 {
        bail!("{} sessions leaked", info.active_sessions);
    }
    Ok(())
}
