//! Issue 36, the server side, over real loopback sockets: a model of empty protobuf entries
//! costs the server nothing (the `unigait-server` binary spawned, its peak RSS read from /proc),
//! policy worker crashes, transport limits, per-session calls in flight, stuck streams.

mod common;

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
        Self::start_under(args, &format!("ulimit -v {}", address_space_mib << 10))
    }

    /// Start it with `args` after the shell commands `limits` (`ulimit ...`).
    fn start_under(args: &[&str], limits: &str) -> Self {
        let exe = env!("CARGO_BIN_EXE_unigait-server");
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(format!(
                "{limits}; exec \"$0\" serve --addr 127.0.0.1:0 \"$@\""
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
        common::connect(self.addr).await
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
        draw_envs: Vec::new(),
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

/// The soft limit on open files of this process (from /proc/self/limits).
/// The policy worker runs with no new privileges, and in its own network namespace wherever this
/// machine lets an unprivileged process make one (checked by making one here first).
#[test]
fn issue_36_the_policy_worker_runs_confined() {
    use unigait_policy::{Policy, PolicySpec, SandboxLimits, SandboxedPolicy};
    let exe = std::path::Path::new(env!("CARGO_BIN_EXE_unigait-server"));
    let spec = PolicySpec::default();
    let history = vec![0.0; spec.input_width()];
    let mut actions = vec![0.0; spec.num_actions];
    let policy = SandboxedPolicy::spawn(exe, &test_policy(), spec, SandboxLimits::default())
        .expect("the test policy loads");
    policy
        .act(&history, 1, &mut actions)
        .expect("it still acts");
    let pid = policy.worker_pid();
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("worker status");
    assert!(
        status
            .lines()
            .any(|l| l.split_whitespace().eq(["NoNewPrivs:", "1"])),
        "the worker may gain privileges:\n{status}"
    );
    let namespaces_allowed = Command::new("unshare")
        .args(["--user", "--net", "true"])
        .status()
        .is_ok_and(|s| s.success());
    let net = |p: &str| std::fs::read_link(format!("/proc/{p}/ns/net")).expect("net namespace");
    if namespaces_allowed {
        assert_ne!(
            net(&pid.to_string()),
            net("self"),
            "the worker shares the host's network"
        );
    } else {
        eprintln!("unprivileged namespaces are not allowed here: network isolation not checked");
    }
}

/// The policy worker runs under a seccomp filter installed before it decodes the model: its
/// status says so, a real policy still loads and acts (the same actions as in process, at batch
/// 1 and at a batch large enough for tract's cache-blocked kernels), and a forbidden call (open
/// a file, made by the worker's test-only argument) kills it with SIGSYS, reported as a crash.
#[test]
fn issue_36_the_policy_worker_runs_under_a_seccomp_filter() {
    use unigait_policy::{
        OnnxPolicy, Policy, PolicyError, PolicySpec, SECCOMP_SELF_TEST_ARG, SandboxLimits,
        SandboxedPolicy,
    };
    let exe = std::path::Path::new(env!("CARGO_BIN_EXE_unigait-server"));
    let spec = PolicySpec::default();
    let policy = SandboxedPolicy::spawn(exe, &test_policy(), spec, SandboxLimits::default())
        .expect("the test policy loads under the filter");
    let status = std::fs::read_to_string(format!("/proc/{}/status", policy.worker_pid()))
        .expect("worker status");
    assert!(
        status
            .lines()
            .any(|l| l.split_whitespace().eq(["Seccomp:", "2"])),
        "the worker has no seccomp filter:\n{status}"
    );
    let local = OnnxPolicy::from_bytes(&test_policy(), spec).expect("in process");
    for batch in [1, 3000] {
        let history: Vec<f32> = (0..batch * spec.input_width())
            .map(|i| ((i % 97) as f32 - 48.0) / 50.0)
            .collect();
        let mut sandboxed = vec![0.0; batch * spec.num_actions];
        let mut expected = vec![0.0; batch * spec.num_actions];
        policy
            .act(&history, batch, &mut sandboxed)
            .unwrap_or_else(|e| panic!("batch {batch} under the filter: {e}"));
        local.act(&history, batch, &mut expected).expect("local");
        assert_eq!(sandboxed, expected, "batch {batch}");
        assert!(expected.iter().any(|&v| v != 0.0));
    }

    // The worker's test-only argument, through a wrapper (the server never passes it).
    let dir = std::env::temp_dir().join(format!("unigait-36-seccomp-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let wrapper = dir.join("worker.sh");
    std::fs::write(
        &wrapper,
        format!(
            "#!/bin/sh\nexec '{}' \"$1\" {SECCOMP_SELF_TEST_ARG}\n",
            exe.display()
        ),
    )
    .expect("write the wrapper");
    Command::new("chmod")
        .arg("+x")
        .arg(&wrapper)
        .status()
        .expect("chmod");
    let probe = SandboxedPolicy::spawn(&wrapper, &test_policy(), spec, SandboxLimits::default())
        .expect("loads");
    let history = vec![0.0; spec.input_width()];
    let mut actions = vec![0.0; spec.num_actions];
    match probe.act(&history, 1, &mut actions) {
        Err(PolicyError::Crashed(m)) => assert!(m.contains("SIGSYS"), "{m}"),
        other => panic!("the forbidden call went through: {other:?}"),
    }
    let _ = std::fs::remove_dir_all(&dir);
}

fn open_files_limit() -> usize {
    std::fs::read_to_string("/proc/self/limits")
        .ok()
        .and_then(|l| {
            l.lines()
                .find(|l| l.starts_with("Max open files"))
                .and_then(|l| l.split_whitespace().nth(3).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(1024)
}

/// Whether the server closed `stream` (EOF or a reset) before `deadline` (a hang guard).
fn closed_by_server(stream: &mut std::net::TcpStream, deadline: std::time::Instant) -> bool {
    use std::io::Read;
    let mut buf = [0u8; 256];
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        stream
            .set_read_timeout(Some(left.max(Duration::from_millis(1))))
            .expect("timeout");
        match stream.read(&mut buf) {
            Ok(0) => return true,
            // TLS alerts or HTTP/2 frames the server sends before it closes.
            Ok(_) => continue,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return false;
            }
            Err(_) => return true,
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_idle_connections_are_dropped_and_a_client_still_gets_service() {
    // The server holds up to 512 connections and gives each 1 s to start talking.
    let server = SpawnedServer::start(
        &[
            "--threads",
            "1",
            "--max-connections",
            "512",
            "--handshake-timeout",
            "1",
        ],
        4096,
    );
    let addr = server.addr;
    let n = 1500.min(open_files_limit().saturating_sub(300));
    let idle = tokio::task::spawn_blocking(move || {
        (0..n)
            .map(|_| {
                std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(10))
                    .expect("connect (the listen backlog holds what the server has not accepted)")
            })
            .collect::<Vec<_>>()
    })
    .await
    .expect("join");
    // A well-behaved client, queued behind them, is served once idle ones are dropped.
    let mut c = server.client().await;
    let info = c
        .get_server_info(v1::GetServerInfoRequest {})
        .await
        .expect("served")
        .into_inner();
    assert_eq!(info.active_sessions, 0);
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let closed = tokio::task::spawn_blocking(move || {
        idle.into_iter()
            .filter_map(|mut s| closed_by_server(&mut s, deadline).then_some(()))
            .count()
    })
    .await
    .expect("join");
    assert_eq!(closed, n, "every idle connection is closed by the server");
    c.get_server_info(v1::GetServerInfoRequest {})
        .await
        .expect("still served");
}

/// A self-signed certificate for `localhost` (the openssl command), written to a temp dir.
fn self_signed_localhost() -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = std::env::temp_dir().join(format!("unigait-36-tls-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let (cert, key) = (dir.join("cert.pem"), dir.join("key.pem"));
    let status = Command::new("openssl")
        .args([
            "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
        ])
        .args(["-subj", "/CN=localhost"])
        .args(["-addext", "subjectAltName=DNS:localhost"])
        .arg("-keyout")
        .arg(&key)
        .arg("-out")
        .arg(&cert)
        .stderr(Stdio::null())
        .status()
        .expect("openssl runs");
    assert!(status.success(), "openssl could not make a certificate");
    (cert, key)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_half_open_tls_handshakes_time_out() {
    use std::io::Write;
    let (cert, key) = self_signed_localhost();
    let (cert, key) = (cert.display().to_string(), key.display().to_string());
    let server = SpawnedServer::start(
        &[
            "--threads",
            "1",
            "--tls-cert",
            &cert,
            "--tls-key",
            &key,
            "--handshake-timeout",
            "1",
        ],
        4096,
    );
    let addr = server.addr;
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let closed = tokio::task::spawn_blocking(move || {
        let mut streams: Vec<std::net::TcpStream> = (0..50)
            .map(|_| std::net::TcpStream::connect(addr).expect("connect"))
            .collect();
        // Half the connections send nothing, half the start of a ClientHello (a handshake
        // record announcing 512 bytes, then 40 of them) and stall.
        for s in streams.iter_mut().skip(25) {
            let mut hello = vec![0x16, 0x03, 0x01, 0x02, 0x00, 0x01, 0x00, 0x01, 0xfc];
            hello.extend([0u8; 31]);
            s.write_all(&hello).expect("write");
        }
        streams
            .iter_mut()
            .map(|s| closed_by_server(s, deadline))
            .filter(|&closed| closed)
            .count()
    })
    .await
    .expect("join");
    assert_eq!(
        closed, 50,
        "every stalled handshake is closed by the server"
    );
}

/// A server in this process, on a loopback port; stopped when `stop` is sent or dropped.
struct InProcess {
    addr: SocketAddr,
    _stop: tokio::sync::oneshot::Sender<()>,
}

async fn in_process(options: unigait_server::ServeOptions) -> InProcess {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr");
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(unigait_server::serve(listener, options, async {
        let _ = stopped.await;
    }));
    InProcess { addr, _stop: stop }
}

async fn channel(addr: SocketAddr) -> Channel {
    Channel::from_shared(format!("http://{addr}"))
        .expect("uri")
        .connect()
        .await
        .expect("connect")
}

const TOKEN: &str = "0123456789abcdef-test-token";

fn with_token<T>(message: T) -> tonic::Request<T> {
    let mut r = tonic::Request::new(message);
    r.metadata_mut().insert(
        "authorization",
        format!("Bearer {TOKEN}").parse().expect("header"),
    );
    r
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_health_watch_needs_the_token_beyond_loopback() {
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_client::HealthClient;
    let server = in_process(unigait_server::ServeOptions {
        threads: 1,
        token: Some(TOKEN.into()),
        assume_remote: true,
        ..Default::default()
    })
    .await;
    let mut health = HealthClient::new(channel(server.addr).await);
    let check = HealthCheckRequest {
        service: String::new(),
    };
    // Check stays open for probes; Watch (a stream held open) needs the token.
    health.check(check.clone()).await.expect("check");
    let refused = health.watch(check.clone()).await;
    assert_eq!(refused.expect_err("no token").code(), Code::Unauthenticated);
    let mut watch = health
        .watch(with_token(check))
        .await
        .expect("watch with the token")
        .into_inner();
    let first = watch.message().await.expect("status").expect("a status");
    assert_eq!(
        first.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_streams_per_connection_are_limited() {
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_client::HealthClient;
    let server = in_process(unigait_server::ServeOptions {
        threads: 1,
        transport: unigait_server::TransportLimits {
            max_concurrent_streams: 3,
            ..Default::default()
        },
        ..Default::default()
    })
    .await;
    let channel = channel(server.addr).await;
    let mut health = HealthClient::new(channel.clone());
    let check = HealthCheckRequest {
        service: String::new(),
    };
    // Three Watch streams stay open on the connection: the server's limit.
    let mut watches = Vec::new();
    for _ in 0..3 {
        let mut w = health
            .watch(check.clone())
            .await
            .expect("watch")
            .into_inner();
        w.message().await.expect("status").expect("a status");
        watches.push(w);
    }
    // A fourth call on the same connection waits for a stream to close (the client holds it
    // back, as the server's SETTINGS say), so its deadline passes.
    let mut c = SimulatorClient::new(channel.clone());
    let mut r = tonic::Request::new(v1::GetServerInfoRequest {});
    r.set_timeout(Duration::from_millis(500));
    let waited = c.get_server_info(r).await;
    // The client's own deadline ends it: CANCELLED (tonic's "Timeout expired") or
    // DEADLINE_EXCEEDED.
    let code = waited.expect_err("held back").code();
    assert!(
        matches!(code, Code::DeadlineExceeded | Code::Cancelled),
        "{code:?}"
    );
    drop(watches.pop());
    c.get_server_info(v1::GetServerInfoRequest {})
        .await
        .expect("served once a stream closed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_a_flood_of_calls_on_one_session_is_refused_and_others_step() {
    let server = in_process(unigait_server::ServeOptions {
        threads: 1,
        ..Default::default()
    })
    .await;
    let channel = channel(server.addr).await;
    let mut c = SimulatorClient::new(channel.clone());
    let big = create(&mut c, 512, 1).await;
    let small = create(&mut c, 1, 2).await;
    let flood: Vec<_> = (0..100)
        .map(|_| {
            let mut c = c.clone();
            let big = big.clone();
            tokio::spawn(async move {
                c.reset(v1::ResetRequest {
                    session_id: big,
                    mask: None,
                })
                .await
            })
        })
        .collect();
    c.step(step_request(&small, 1))
        .await
        .expect("the other session steps");
    let (mut ok, mut refused) = (0, 0);
    for call in flood {
        match call.await.expect("join") {
            Ok(_) => ok += 1,
            Err(s) => {
                assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
                assert!(s.message().contains("in flight"), "{}", s.message());
                refused += 1;
            }
        }
    }
    eprintln!("flood: {ok} served, {refused} refused");
    assert!(ok >= 1 && refused >= 1, "{ok} served, {refused} refused");
    assert_eq!(ok + refused, 100);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_a_stream_whose_client_does_not_read_ends() {
    let server = in_process(unigait_server::ServeOptions {
        threads: 1,
        limits: unigait_server::Limits {
            stream_idle_timeout_s: 1,
            ..Default::default()
        },
        ..Default::default()
    })
    .await;
    // A small HTTP/2 window, so a few unread replies fill it.
    let channel = Channel::from_shared(format!("http://{}", server.addr))
        .expect("uri")
        .initial_stream_window_size(Some(65_535))
        .initial_connection_window_size(Some(65_535))
        .connect()
        .await
        .expect("connect");
    let mut c = SimulatorClient::new(channel);
    // Unary calls go on a connection of their own: the stream's unread replies fill the first
    // one's window.
    let mut probe = SimulatorClient::new(self::channel(server.addr).await);
    let n = 256;
    let id = create(&mut c, n as u32, 3).await;
    let (tx, requests) = tokio::sync::mpsc::channel(64);
    let replies = c
        .step_stream(tokio_stream::wrappers::ReceiverStream::new(requests))
        .await
        .expect("open")
        .into_inner();
    // Requests keep coming; replies are never read.
    let sender = {
        let id = id.clone();
        tokio::spawn(async move {
            for _ in 0..64 {
                if tx.send(step_request(&id, n)).await.is_err() {
                    break;
                }
            }
        })
    };
    // Once the server gives up sending (after the stream idle timeout), the stream ends and
    // frees the session for unary calls (refused with FAILED_PRECONDITION while it is open).
    let guard = std::time::Instant::now() + Duration::from_secs(20);
    // First the stream claims the session (with its first request) ...
    let bounded = |r: v1::StepRequest| {
        let mut r = tonic::Request::new(r);
        r.set_timeout(Duration::from_secs(10));
        r
    };
    loop {
        match probe.step(bounded(step_request(&id, n))).await {
            Err(s) if s.code() == Code::FailedPrecondition => break,
            Ok(_) => assert!(std::time::Instant::now() < guard, "the stream never opened"),
            Err(s) => panic!("{s:?}"),
        }
    }
    // ... then lets it go.
    let mut refused = 1;
    loop {
        match probe.step(bounded(step_request(&id, n))).await {
            Ok(_) => break,
            Err(s) if s.code() == Code::FailedPrecondition => {
                refused += 1;
                assert!(
                    std::time::Instant::now() < guard,
                    "the stuck stream still holds the session"
                );
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(s) => panic!("{s:?}"),
        }
    }
    assert!(
        refused >= 1,
        "the stream held the session while it could send"
    );
    sender.abort();
    drop(replies);
}

// --- Coded in round one, tested here: accept back-off, connection age, keepalive, drain, the
// second Ctrl-C, reflection.

/// CPU seconds (user + system) process `pid` has used, from /proc/<pid>/stat (in clock ticks
/// of 1/100 s, the Linux default USER_HZ).
fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("stat");
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .expect("fields")
        .split_whitespace()
        .collect();
    let ticks: u64 =
        fields[11].parse::<u64>().expect("utime") + fields[12].parse::<u64>().expect("stime");
    ticks as f64 / 100.0
}

fn open_fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|d| d.count())
        .unwrap_or(0)
}

/// A server with 64 file descriptors is sent 150 connections (its listen backlog holds 128): once its descriptors are gone,
/// accept fails, and the server waits between attempts (5 ms doubling to 1 s) instead of
/// retrying at once, so it uses little CPU while exhausted (measured: its CPU time over 3 s);
/// once the connections go, it serves again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_accept_backs_off_while_out_of_file_descriptors() {
    let server = SpawnedServer::start_under(
        &[
            "--threads",
            "1",
            "--max-connections",
            "1000",
            "--handshake-timeout",
            "120",
        ],
        "ulimit -n 64",
    );
    let (addr, pid) = (server.addr, server.child.id());
    let clients = tokio::task::spawn_blocking(move || {
        (0..150)
            .map(|_| std::net::TcpStream::connect(addr).expect("connect (the backlog holds them)"))
            .collect::<Vec<_>>()
    })
    .await
    .expect("join");
    // Exhausted: every descriptor in use (hang guard: 30 s).
    let guard = std::time::Instant::now() + Duration::from_secs(30);
    while open_fds(pid) < 63 {
        assert!(
            std::time::Instant::now() < guard,
            "only {} fds open",
            open_fds(pid)
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Let the back-off reach its longer waits, then measure 3 s of exhaustion.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let before = cpu_seconds(pid);
    tokio::time::sleep(Duration::from_secs(3)).await;
    let used = cpu_seconds(pid) - before;
    assert!(open_fds(pid) >= 63, "no longer exhausted");
    eprintln!("CPU time over 3 s while out of file descriptors: {used:.2} s");
    assert!(used < 0.3, "the server spun: {used:.2} CPU s in 3 s");
    drop(clients);
    let served = tokio::time::timeout(Duration::from_secs(30), async {
        server
            .client()
            .await
            .get_server_info(v1::GetServerInfoRequest {})
            .await
    })
    .await
    .expect("served again within 30 s (hang guard)");
    served.expect("served once the connections are gone");
}

/// The HTTP/2 client preface and an empty SETTINGS frame.
const H2_PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\0\0\0\x04\0\0\0\0\0";
const H2_PING: u8 = 6;
const H2_GOAWAY: u8 = 7;

/// A raw HTTP/2 connection (no client library: it answers nothing but SETTINGS).
fn h2_connect(addr: SocketAddr) -> std::net::TcpStream {
    use std::io::Write;
    let mut s = std::net::TcpStream::connect(addr).expect("connect");
    s.write_all(H2_PREFACE).expect("preface");
    s
}

/// Reads one frame from `s` (its type, flags and payload) before `guard`; None on EOF, error
/// or time-out. Acknowledges SETTINGS and answers PINGs, as a live client does.
fn h2_frame(s: &mut std::net::TcpStream, guard: std::time::Instant) -> Option<(u8, u8)> {
    use std::io::{Read, Write};
    let left = guard.saturating_duration_since(std::time::Instant::now());
    if left.is_zero() {
        return None;
    }
    s.set_read_timeout(Some(left)).expect("timeout");
    let mut header = [0u8; 9];
    s.read_exact(&mut header).ok()?;
    let len = u32::from_be_bytes([0, header[0], header[1], header[2]]) as usize;
    let mut payload = vec![0u8; len];
    s.read_exact(&mut payload).ok()?;
    let (kind, flags) = (header[3], header[4]);
    if kind == 4 && flags & 1 == 0 {
        s.write_all(&[0, 0, 0, 4, 1, 0, 0, 0, 0]).ok()?;
    }
    if kind == H2_PING && flags & 1 == 0 {
        s.write_all(&[0, 0, 8, H2_PING, 1, 0, 0, 0, 0]).ok()?;
        s.write_all(&payload).ok()?;
    }
    Some((kind, flags))
}

/// Reads frames until one of type `kind` (true) or EOF, an error or `guard` (false).
fn h2_wait_for(s: &mut std::net::TcpStream, kind: u8, guard: std::time::Instant) -> bool {
    std::iter::from_fn(|| h2_frame(s, guard)).any(|(k, _)| k == kind)
}

/// Whether the server closes `s` before `guard` (reading and answering frames meanwhile).
fn h2_closed(s: &mut std::net::TcpStream, guard: std::time::Instant) -> bool {
    while h2_frame(s, guard).is_some() {}
    !guard
        .saturating_duration_since(std::time::Instant::now())
        .is_zero()
}

/// `--max-connection-age 1`: a connection gets GOAWAY after a second and, with no call in
/// flight, is then closed. Without the age no GOAWAY ever comes; with tonic's age "grace" (set
/// until this test) none came either: the connection was cut at age + grace instead.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_a_connection_past_its_maximum_age_is_sent_away() {
    let server = in_process(unigait_server::ServeOptions {
        threads: 1,
        transport: unigait_server::TransportLimits {
            max_connection_age: Some(Duration::from_secs(1)),
            ..Default::default()
        },
        ..Default::default()
    })
    .await;
    let addr = server.addr;
    let (goaway, closed) = tokio::task::spawn_blocking(move || {
        let mut s = h2_connect(addr);
        let guard = std::time::Instant::now() + Duration::from_secs(20);
        let goaway = h2_wait_for(&mut s, H2_GOAWAY, guard);
        (goaway, h2_closed(&mut s, guard))
    })
    .await
    .expect("join");
    assert!(goaway, "no GOAWAY within 20 s");
    assert!(closed, "the connection stayed open after its grace period");
}

/// Accepted connections carry TCP keepalive (read back from the server's own socket: the
/// server runs in this process) and the server sends HTTP/2 PINGs at the keepalive interval.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_connections_have_tcp_and_http2_keepalive() {
    use std::os::fd::BorrowedFd;
    let server = in_process(unigait_server::ServeOptions {
        threads: 1,
        keepalive: Duration::from_secs(1),
        ..Default::default()
    })
    .await;
    let addr = server.addr;
    let mut client = h2_connect(addr);
    let local = client.local_addr().expect("local");
    let (client, ping) = tokio::task::spawn_blocking(move || {
        let guard = std::time::Instant::now() + Duration::from_secs(20);
        let ping = h2_wait_for(&mut client, H2_PING, guard);
        (client, ping)
    })
    .await
    .expect("join");
    assert!(ping, "no HTTP/2 PING within 20 s");
    // The server's end of this connection, among this process's descriptors.
    let accepted = std::fs::read_dir("/proc/self/fd")
        .expect("fds")
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<i32>().ok())
        .find(|&fd| {
            // SAFETY: the descriptor is open for this test's whole run (the server holds it)
            // and is only borrowed for the two address lookups.
            let fd = unsafe { BorrowedFd::borrow_raw(fd) };
            let sock = socket2::SockRef::from(&fd);
            let mine = |a: std::io::Result<socket2::SockAddr>| a.ok().and_then(|a| a.as_socket());
            mine(sock.local_addr()) == Some(addr) && mine(sock.peer_addr()) == Some(local)
        })
        .expect("the accepted socket");
    // SAFETY: as above.
    let fd = unsafe { BorrowedFd::borrow_raw(accepted) };
    let sock = socket2::SockRef::from(&fd);
    assert!(sock.keepalive().expect("SO_KEEPALIVE"), "no TCP keepalive");
    assert_eq!(
        sock.tcp_keepalive_time().expect("TCP_KEEPIDLE"),
        Duration::from_secs(1)
    );
    assert_eq!(
        sock.tcp_keepalive_interval().expect("TCP_KEEPINTVL"),
        Duration::from_secs(10)
    );
    assert_eq!(sock.tcp_keepalive_retries().expect("TCP_KEEPCNT"), 3);
    drop(client);
}

/// A drain seen from outside: health turns NOT_SERVING on a Watch, an open step stream ends
/// UNAVAILABLE, and `serve` returns once the clients are gone, with a drain deadline (300 s) far
/// beyond the test's hang guard (30 s), so it cannot pass on the deadline.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_a_drain_reports_not_serving_and_ends_without_its_deadline() {
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr");
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let serving = tokio::spawn(unigait_server::serve(
        listener,
        unigait_server::ServeOptions {
            threads: 1,
            drain_timeout: Duration::from_secs(300),
            ..Default::default()
        },
        async {
            let _ = stopped.await;
        },
    ));
    let channel = channel(addr).await;
    let mut c = SimulatorClient::new(channel.clone());
    let id = create(&mut c, 1, 1).await;
    let (tx, requests) = tokio::sync::mpsc::channel(4);
    let mut replies = c
        .step_stream(tokio_stream::wrappers::ReceiverStream::new(requests))
        .await
        .expect("open")
        .into_inner();
    tx.send(step_request(&id, 1)).await.expect("send");
    replies.message().await.expect("a step").expect("a reply");
    let mut watch = HealthClient::new(channel.clone())
        .watch(HealthCheckRequest {
            service: String::new(),
        })
        .await
        .expect("watch")
        .into_inner();
    let first = watch.message().await.expect("status").expect("a status");
    assert_eq!(first.status, ServingStatus::Serving as i32);

    stop.send(()).expect("the server is running");
    let next = watch.message().await.expect("status").expect("a status");
    assert_eq!(next.status, ServingStatus::NotServing as i32);
    let ended = replies.message().await.expect_err("the stream ends");
    assert_eq!(ended.code(), Code::Unavailable, "{ended:?}");
    drop((watch, replies, tx, c, channel));
    tokio::time::timeout(Duration::from_secs(30), serving)
        .await
        .expect("serve returned after the drain, long before its 300 s deadline")
        .expect("join")
        .expect("serve returns Ok");
}

/// The real binary: a first SIGINT drains (health turns NOT_SERVING on a Watch, which holds the
/// drain open: its deadline is 300 s), a second one ends the process at once with 130.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_a_second_sigint_ends_a_draining_server_at_once() {
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;
    let mut server = SpawnedServer::start(&["--threads", "1", "--drain-timeout", "300"], 4096);
    let pid = server.child.id().to_string();
    let interrupt = || {
        let sent = Command::new("kill")
            .args(["-INT", &pid])
            .status()
            .expect("kill");
        assert!(sent.success());
    };
    let mut watch = HealthClient::new(channel(server.addr).await)
        .watch(HealthCheckRequest {
            service: String::new(),
        })
        .await
        .expect("watch")
        .into_inner();
    let first = watch.message().await.expect("status").expect("a status");
    assert_eq!(first.status, ServingStatus::Serving as i32);
    interrupt();
    let next = watch.message().await.expect("status").expect("a status");
    assert_eq!(next.status, ServingStatus::NotServing as i32);
    assert!(
        server.child.try_wait().expect("wait").is_none(),
        "the first SIGINT did not drain"
    );
    // Signal again until it exits (hang guard: 10 s); a server that ignored the second SIGINT
    // would drain for 300 s.
    let mut status = None;
    for _ in 0..50 {
        interrupt();
        tokio::time::sleep(Duration::from_millis(200)).await;
        status = server.child.try_wait().expect("wait");
        if status.is_some() {
            break;
        }
    }
    let status = status.expect("the server still runs after a second SIGINT");
    assert_eq!(status.code(), Some(130), "{status:?}");
    drop(watch);
}

/// Reflection v1alpha (what older grpcurl and Postman ask for) is served beside v1; beyond
/// loopback both need the token, on loopback neither does.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_reflection_v1alpha_is_served_and_needs_the_token_beyond_loopback() {
    use tonic_reflection::pb::{v1, v1alpha};
    async fn list_v1alpha(addr: SocketAddr, token: bool) -> Result<Vec<String>, Status> {
        use v1alpha::server_reflection_request::MessageRequest;
        use v1alpha::server_reflection_response::MessageResponse;
        let request = v1alpha::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::ListServices(String::new())),
        };
        let stream = tokio_stream::iter(vec![request]);
        let request = if token {
            with_token(stream)
        } else {
            tonic::Request::new(stream)
        };
        let mut client =
            v1alpha::server_reflection_client::ServerReflectionClient::new(channel(addr).await);
        let mut replies = client.server_reflection_info(request).await?.into_inner();
        match replies.message().await?.and_then(|r| r.message_response) {
            Some(MessageResponse::ListServicesResponse(list)) => {
                Ok(list.service.into_iter().map(|s| s.name).collect())
            }
            other => panic!("{other:?}"),
        }
    }
    async fn list_v1(addr: SocketAddr, token: bool) -> Result<Vec<String>, Status> {
        use v1::server_reflection_request::MessageRequest;
        use v1::server_reflection_response::MessageResponse;
        let request = v1::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::ListServices(String::new())),
        };
        let stream = tokio_stream::iter(vec![request]);
        let request = if token {
            with_token(stream)
        } else {
            tonic::Request::new(stream)
        };
        let mut client =
            v1::server_reflection_client::ServerReflectionClient::new(channel(addr).await);
        let mut replies = client.server_reflection_info(request).await?.into_inner();
        match replies.message().await?.and_then(|r| r.message_response) {
            Some(MessageResponse::ListServicesResponse(list)) => {
                Ok(list.service.into_iter().map(|s| s.name).collect())
            }
            other => panic!("{other:?}"),
        }
    }
    let simulator = "unigait.v1.Simulator".to_string();
    let remote = in_process(unigait_server::ServeOptions {
        threads: 1,
        token: Some(TOKEN.into()),
        assume_remote: true,
        ..Default::default()
    })
    .await;
    for (version, refused) in [
        ("v1alpha", list_v1alpha(remote.addr, false).await),
        ("v1", list_v1(remote.addr, false).await),
    ] {
        let code = refused.expect_err(version).code();
        assert_eq!(code, Code::Unauthenticated, "{version}");
    }
    assert!(
        list_v1alpha(remote.addr, true)
            .await
            .expect("v1alpha")
            .contains(&simulator)
    );
    assert!(
        list_v1(remote.addr, true)
            .await
            .expect("v1")
            .contains(&simulator)
    );
    let local = in_process(unigait_server::ServeOptions {
        threads: 1,
        token: Some(TOKEN.into()),
        ..Default::default()
    })
    .await;
    assert!(
        list_v1alpha(local.addr, false)
            .await
            .expect("v1alpha")
            .contains(&simulator)
    );
    assert!(
        list_v1(local.addr, false)
            .await
            .expect("v1")
            .contains(&simulator)
    );
}
