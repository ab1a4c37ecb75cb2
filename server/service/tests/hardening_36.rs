//! Issue 36, the server side, over real loopback sockets: a model of empty protobuf entries
//! costs the server nothing (the `unigait-server` binary spawned, its peak RSS read from /proc),
//! policy worker crashes, transport limits, per-session calls in flight, stuck streams.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

use tonic::transport::Channel;
use tonic::{Code, Status};
use unigait_proto::f32_tensor;
use unigait_proto::v1::{self, simulator_client::SimulatorClient};

/// The `unigait-server` binary serving on a free loopback port, killed when dropped.
struct SpawnedServer {
    child: Child,
    addr: SocketAddr,
}

impl SpawnedServer {
    /// Start it with `args` after `serve --addr 127.0.0.1:0`, under an address-space cap of
    /// `address_space_mib` (a safety net: a server that tries to allocate gigabytes fails
    /// instead of taking the machine's memory).
    fn start(args: &[&str], address_space_mib: u64) -> Self {
        let exe = env!("CARGO_BIN_EXE_unigait-server");
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(format!(
                "ulimit -v {}; exec \"$0\" serve --addr 127.0.0.1:0 \"$@\"",
                address_space_mib << 10
            ))
            .arg(exe)
            .args(args)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn the server");
        let stdout = child.stdout.take().expect("stdout");
        let mut line = String::new();
        BufReader::new(stdout)
            .read_line(&mut line)
            .expect("the server's first line");
        let addr = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
            .parse()
            .expect("address");
        SpawnedServer { child, addr }
    }

    async fn client(&self) -> SimulatorClient<Channel> {
        let channel = Channel::from_shared(format!("http://{}", self.addr))
            .expect("uri")
            .connect()
            .await
            .expect("connect");
        SimulatorClient::new(channel)
            .max_decoding_message_size(64 << 20)
            .max_encoding_message_size(64 << 20)
    }

    /// A field of /proc/<pid>/status in KiB (VmHWM: the peak resident set).
    fn status_kib(&self, field: &str) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id()))
            .expect("the server is alive");
        status
            .lines()
            .find_map(|l| l.strip_prefix(field))
            .and_then(|v| v.trim_start_matches(':').trim().strip_suffix("kB"))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("no {field} in {status}"))
    }
}

impl Drop for SpawnedServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn step_request(id: &str, num_envs: usize) -> v1::StepRequest {
    v1::StepRequest {
        session_id: id.into(),
        actions: Some(f32_tensor(&vec![0.0; num_envs * 12], &[num_envs, 12])),
        reward_terms: false,
    }
}

async fn create(c: &mut SimulatorClient<Channel>, n: u32, seed: u64) -> String {
    c.create_session(v1::CreateSessionRequest {
        config: Some(v1::SessionConfig {
            num_envs: n,
            seed,
            ..Default::default()
        }),
    })
    .await
    .expect("create")
    .into_inner()
    .session_id
}

fn evaluate_request(policy: Vec<u8>) -> v1::EvaluateRequest {
    v1::EvaluateRequest {
        policy_onnx: policy.into(),
        scenario: "flat_quad".into(),
        num_envs: 1,
        seed: 1,
        ..Default::default()
    }
}

/// Steps `id` until `stop` is set; counts the steps that succeeded and returns the first error.
fn keep_stepping(
    mut c: SimulatorClient<Channel>,
    id: String,
    stop: Arc<AtomicBool>,
    ok: Arc<AtomicUsize>,
) -> tokio::task::JoinHandle<Option<Status>> {
    tokio::spawn(async move {
        while !stop.load(Ordering::Acquire) {
            if let Err(s) = c.step(step_request(&id, 1)).await {
                return Some(s);
            }
            ok.fetch_add(1, Ordering::Relaxed);
        }
        None
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_a_model_of_empty_nodes_costs_the_server_nothing() {
    let server = SpawnedServer::start(&["--threads", "1"], 4096);
    let mut c = server.client().await;
    let id = create(&mut c, 1, 1).await;
    c.step(step_request(&id, 1)).await.expect("a first step");
    let before_kib = server.status_kib("VmHWM");
    let stop = Arc::new(AtomicBool::new(false));
    let ok = Arc::new(AtomicUsize::new(0));
    let stepper = keep_stepping(c.clone(), id.clone(), stop.clone(), ok.clone());
    // ModelProto.graph (field 7) holding 15 MiB of empty NodeProto entries (GraphProto field 1,
    // bytes 0x0a 0x00): 7,864,320 nodes, each a ~170-byte struct once decoded (over 2 GB).
    let nodes = (15 << 20) / 2;
    let mut model = vec![0x3a];
    let mut len = nodes as u64 * 2;
    while len >= 0x80 {
        model.push((len as u8) | 0x80);
        len >>= 7;
    }
    model.push(len as u8);
    model.extend([0x0a, 0x00].repeat(nodes));
    let status = c
        .evaluate(evaluate_request(model))
        .await
        .expect_err("refused");
    stop.store(true, Ordering::Release);
    let stepped = stepper.await.expect("join");
    assert_eq!(status.code(), Code::ResourceExhausted, "{status:?}");
    assert!(
        status.message().contains("7864320") && status.message().contains("nodes"),
        "{}",
        status.message()
    );
    assert!(stepped.is_none(), "the other session failed: {stepped:?}");
    c.step(step_request(&id, 1))
        .await
        .expect("the session lives on");
    // The server holds the 15 MiB request (and tonic's buffer of it), never the decoded nodes.
    let after_kib = server.status_kib("VmHWM");
    eprintln!(
        "server peak RSS {before_kib} KiB before, {after_kib} KiB after; {} concurrent steps",
        ok.load(Ordering::Relaxed)
    );
    assert!(
        after_kib < before_kib + (128 << 10),
        "peak RSS grew from {before_kib} to {after_kib} KiB"
    );
}

fn test_policy() -> Vec<u8> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/test_policy.onnx"
    );
    std::fs::read(path).expect("tests/data/test_policy.onnx")
}

#[test]
fn issue_36_a_crashed_policy_worker_is_reported_as_a_crash() {
    use unigait_policy::{Policy, PolicyError, PolicySpec, SandboxLimits, SandboxedPolicy};
    let exe = std::path::Path::new(env!("CARGO_BIN_EXE_unigait-server"));
    let spec = PolicySpec::default();
    let history = vec![0.0; spec.input_width()];
    let mut actions = vec![0.0; spec.num_actions];
    for (signal, name) in [("SEGV", "SIGSEGV"), ("ILL", "SIGILL"), ("KILL", "SIGKILL")] {
        let policy = SandboxedPolicy::spawn(exe, &test_policy(), spec, SandboxLimits::default())
            .expect("the test policy loads");
        policy
            .act(&history, 1, &mut actions)
            .expect("a first batch");
        // Rust's runtime catches a SIGSEGV that is not a stack overflow once (it restores the
        // default action and returns; a real fault then faults again and kills): signal until
        // the worker is a zombie (its parent, the policy, has not reaped it yet).
        let pid = policy.worker_pid();
        let dead = (0..100).any(|_| {
            let killed = Command::new("kill")
                .args([format!("-{signal}"), pid.to_string()])
                .status()
                .expect("kill");
            assert!(killed.success());
            std::thread::sleep(Duration::from_millis(20));
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            stat.rsplit(')')
                .next()
                .is_some_and(|rest| rest.trim_start().starts_with('Z'))
        });
        assert!(dead, "the worker outlived its signals");
        for attempt in 0..2 {
            // The first call finds the worker dead; the next gets the same error.
            match policy.act(&history, 1, &mut actions) {
                Err(PolicyError::Crashed(m)) => {
                    assert!(m.contains(name) && m.contains("crashed"), "{m}");
                    assert!(!m.contains("needed more"), "{m}");
                }
                other => panic!("{signal}, call {attempt}: {other:?}"),
            }
        }
    }
}
