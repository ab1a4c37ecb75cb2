//! The real server over a real loopback socket (127.0.0.1, port 0): the compliance suite,
//! concurrent sessions, limits, and a client that vanishes mid-stream.

use std::net::SocketAddr;
use std::time::Duration;

use tokio::sync::oneshot;
use tonic::Code;
use unigait_client::{Client, compliance, v1};
use unigait_server::{Limits, ServeOptions, serve};
use unigait_sim::task::TaskConfig;

struct TestServer {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<()>,
}

impl TestServer {
    async fn start(limits: Limits) -> Self {
        Self::start_with_token(limits, None).await
    }

    async fn start_with_token(limits: Limits, token: Option<&str>) -> Self {
        Self::start_secured(limits, token, None).await
    }

    async fn start_secured(
        limits: Limits,
        token: Option<&str>,
        tls: Option<(Vec<u8>, Vec<u8>)>,
    ) -> Self {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .expect("bind");
        let addr = listener.local_addr().expect("addr");
        let (stop, stopped) = oneshot::channel::<()>();
        let options = ServeOptions {
            limits,
            threads: 2,
            base_config: TaskConfig::embedded_default(),
            tls,
            token: token.map(str::to_string),
            ..ServeOptions::default()
        };
        let task = tokio::spawn(async move {
            serve(listener, options, async {
                let _ = stopped.await;
            })
            .await
            .expect("server runs");
        });
        TestServer {
            addr,
            stop: Some(stop),
            task,
        }
    }

    async fn client(&self) -> Client {
        Client::connect(&self.addr.to_string())
            .await
            .expect("connect")
    }

    async fn shutdown(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        tokio::time::timeout(Duration::from_secs(10), self.task)
            .await
            .expect("graceful shutdown")
            .expect("join");
    }
}

fn config(num_envs: u32, seed: u64) -> v1::SessionConfig {
    v1::SessionConfig {
        num_envs,
        seed,
        ..Default::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn compliance_suite_passes() {
    let server = TestServer::start(Limits::default()).await;
    let client = server.client().await;
    let outcomes = compliance::run_all(&client).await;
    let failed: Vec<_> = outcomes.iter().filter(|o| !o.passed).collect();
    assert!(failed.is_empty(), "failed checks: {failed:?}");
    assert_eq!(outcomes.len(), 7);
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_sessions_match_sequential_runs() {
    let server = TestServer::start(Limits::default()).await;
    let run = |client: Client, seed: u64| async move {
        let mut c = client;
        let mut session = c.create_session(config(4, seed)).await.expect("create");
        let mut stream = session.stream().await.expect("stream");
        let mut rewards = Vec::new();
        for k in 0..20 {
            let actions: Vec<f32> = (0..48)
                .map(|i| (((i + k) % 5) as f32 - 2.0) / 2.0)
                .collect();
            let step = stream.step(&actions).await.expect("step");
            rewards.extend_from_slice(&step.reward().expect("reward"));
        }
        drop(stream);
        session.close().await.expect("close");
        rewards
    };
    let alone = run(server.client().await, 7).await;
    let together = tokio::join!(
        run(server.client().await, 7),
        run(server.client().await, 8),
        run(server.client().await, 7)
    );
    assert_eq!(alone, together.0, "a concurrent session changed results");
    assert_eq!(together.0, together.2);
    assert_ne!(together.0, together.1, "different seeds should differ");
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn session_limit_gives_resource_exhausted() {
    let server = TestServer::start(Limits {
        max_envs_per_session: 16,
        max_sessions: 2,
        idle_timeout_s: 600,
        ..Limits::default()
    })
    .await;
    let mut c = server.client().await;
    let a = c.create_session(config(1, 1)).await.expect("first");
    let b = c.create_session(config(1, 1)).await.expect("second");
    let third = c.create_session(config(1, 1)).await;
    assert_eq!(
        third.err().and_then(|e| e.code()),
        Some(Code::ResourceExhausted)
    );
    let big = c.create_session(config(17, 1)).await;
    assert_eq!(
        big.err().and_then(|e| e.code()),
        Some(Code::ResourceExhausted)
    );
    a.close().await.expect("close");
    let c3 = c
        .create_session(config(1, 1))
        .await
        .expect("room again after a close");
    c3.close().await.expect("close");
    b.close().await.expect("close");
    // An oversized request is refused by the transport, and the server keeps serving.
    let mut s = c.create_session(config(16, 1)).await.expect("create");
    let huge = vec![0.0f32; 4 << 20];
    let result = s.step(&huge).await;
    assert!(result.is_err());
    s.step(&[0.0; 16 * 12])
        .await
        .expect("the session still steps");
    s.close().await.expect("close");
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vanished_client_frees_its_session_and_harms_nobody() {
    // The session of a client whose stream broke stays for it to re-attach until the idle
    // timeout, then goes.
    let server = TestServer::start(Limits {
        idle_timeout_s: 1,
        ..Limits::default()
    })
    .await;
    let mut observer = server.client().await;
    let mut bystander = observer
        .create_session(config(2, 3))
        .await
        .expect("bystander");
    // A client on its own runtime (standing for another process) that dies in the middle of a
    // stream: its runtime is torn down with a request in flight, so the connection just breaks.
    let addr = server.addr.to_string();
    let victim_id = std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        let id = runtime.block_on(async {
            let mut c = Client::connect(&addr).await.expect("connect");
            let mut session = c.create_session(config(2, 4)).await.expect("victim");
            let mut stream = session.stream().await.expect("stream");
            stream.step(&[0.0; 24]).await.expect("step");
            stream.send(&[0.0; 24], false).await.expect("send");
            let id = session.id.clone();
            std::mem::forget(stream);
            std::mem::forget(session);
            std::mem::forget(c);
            id
        });
        runtime.shutdown_timeout(Duration::from_millis(0));
        id
    })
    .join()
    .expect("victim thread");
    // The server notices the broken stream and closes the session.
    let mut freed = false;
    for _ in 0..50 {
        tokio::time::sleep(Duration::from_millis(100)).await;
        // Stepping keeps the bystander from going idle meanwhile.
        bystander
            .step(&[0.0; 24])
            .await
            .expect("the bystander steps");
        let info = observer.server_info().await.expect("info");
        if info.active_sessions == 1 {
            freed = true;
            break;
        }
    }
    assert!(freed, "session {victim_id} was not freed");
    bystander
        .step(&[0.0; 24])
        .await
        .expect("the bystander still steps");
    bystander.close().await.expect("close");
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bearer_token_is_required_when_configured() {
    let server =
        TestServer::start_with_token(Limits::default(), Some("s3cret-s3cret-s3cret")).await;
    let addr = server.addr.to_string();
    let mut anonymous = Client::connect(&addr).await.expect("connect");
    let err = anonymous.server_info().await.expect_err("no token");
    assert_eq!(err.code(), Some(Code::Unauthenticated));
    let mut wrong = Client::connect_with_token(&addr, Some("guess"))
        .await
        .expect("connect");
    assert_eq!(
        wrong.server_info().await.expect_err("wrong token").code(),
        Some(Code::Unauthenticated)
    );
    let mut right = Client::connect_with_token(&addr, Some("s3cret-s3cret-s3cret"))
        .await
        .expect("connect");
    let mut session = right
        .create_session(config(1, 1))
        .await
        .expect("create with the token");
    let mut stream = session.stream().await.expect("stream with the token");
    stream.step(&[0.0; 12]).await.expect("step with the token");
    drop(stream);
    session.close().await.expect("close");
    server.shutdown().await;
}

/// A self-signed certificate for `localhost` made with the openssl command-line tool.
fn self_signed_localhost() -> (Vec<u8>, Vec<u8>) {
    let dir = std::env::temp_dir().join(format!("unigait-tls-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let (cert, key) = (dir.join("cert.pem"), dir.join("key.pem"));
    let status = std::process::Command::new("openssl")
        .args([
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-days",
            "1",
            "-subj",
            "/CN=localhost",
        ])
        .args(["-addext", "subjectAltName=DNS:localhost"])
        .args(["-addext", "basicConstraints=critical,CA:FALSE"])
        .args(["-addext", "extendedKeyUsage=serverAuth"])
        .arg("-keyout")
        .arg(&key)
        .arg("-out")
        .arg(&cert)
        .stderr(std::process::Stdio::null())
        .status()
        .expect("openssl runs");
    assert!(status.success(), "openssl could not make a certificate");
    (
        std::fs::read(cert).expect("cert"),
        std::fs::read(key).expect("key"),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_with_token_serves_and_plaintext_is_refused() {
    let (cert, key) = self_signed_localhost();
    let server = TestServer::start_secured(
        Limits::default(),
        Some("t0ken-t0ken-t0ken-t0ken"),
        Some((cert.clone(), key)),
    )
    .await;
    let addr = format!("localhost:{}", server.addr.port());
    let mut secure = Client::connect_with(
        &addr,
        Some("t0ken-t0ken-t0ken-t0ken"),
        Some((&cert, "localhost")),
    )
    .await
    .expect("TLS connect");
    let info = secure.server_info().await.expect("info over TLS");
    assert_eq!(info.protocol_version, "v1");
    let mut session = secure
        .create_session(config(1, 2))
        .await
        .expect("session over TLS");
    session.step(&[0.0; 12]).await.expect("step over TLS");
    session.close().await.expect("close");
    // A plaintext client gets no service from a TLS server.
    let plain = Client::connect_with_token(&addr, Some("t0ken-t0ken-t0ken-t0ken")).await;
    let refused = match plain {
        Err(_) => true,
        Ok(mut c) => c.server_info().await.is_err(),
    };
    assert!(refused, "a plaintext client was served by a TLS server");
    server.shutdown().await;
}
