//! The server's defences against one client taking it down or filling it, over a real
//! loopback socket: override caps, cost caps, env reservation, closing a streaming session,
//! poisoned sessions, evaluation limits, hostile ONNX policies (in the policy worker: this
//! crate's `unigait-server` binary), stream semantics, drain, and the token.

mod common;

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use common::{RawBytes, RawCodec};
use prost::Message;
use tokio::sync::{mpsc, oneshot};
use tokio_stream::StreamExt;
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::Channel;
use tonic::{Code, Request, Status};
use tract_onnx::pb;
use unigait_proto::v1::{self, simulator_client::SimulatorClient};
use unigait_proto::{TensorView, f32_tensor, u8_tensor};
use unigait_server::{Limits, ServeError, ServeOptions, serve};

struct TestServer {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), ServeError>>,
}

impl TestServer {
    async fn start(options: ServeOptions) -> Self {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .expect("bind");
        let addr = listener.local_addr().expect("addr");
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(async move {
            serve(listener, options, async {
                let _ = stopped.await;
            })
            .await
        });
        TestServer {
            addr,
            stop: Some(stop),
            task,
        }
    }

    async fn with_limits(limits: Limits) -> Self {
        Self::start(options(limits)).await
    }

    async fn client(&self) -> SimulatorClient<Channel> {
        common::connect(self.addr).await
    }

    /// Ask the server to stop; returns how long it took to return.
    async fn shutdown(mut self) -> Duration {
        let start = Instant::now();
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        tokio::time::timeout(Duration::from_secs(20), self.task)
            .await
            .expect("the server stops within its drain deadline")
            .expect("join")
            .expect("serve returns Ok");
        start.elapsed()
    }
}

fn options(limits: Limits) -> ServeOptions {
    ServeOptions {
        limits,
        threads: 2,
        policy_worker: Some(env!("CARGO_BIN_EXE_unigait-server").into()),
        drain_timeout: Duration::from_secs(5),
        ..ServeOptions::default()
    }
}

fn config(num_envs: u32, seed: u64, overrides: &str) -> v1::CreateSessionRequest {
    v1::CreateSessionRequest {
        config: Some(v1::SessionConfig {
            num_envs,
            seed,
            task_overrides_toml: overrides.into(),
            ..Default::default()
        }),
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

async fn create(c: &mut SimulatorClient<Channel>, n: u32, seed: u64, overrides: &str) -> String {
    c.create_session(config(n, seed, overrides))
        .await
        .expect("create")
        .into_inner()
        .session_id
}

fn code<T: std::fmt::Debug>(r: Result<T, Status>) -> Code {
    r.expect_err("expected an error").code()
}

async fn active_sessions(c: &mut SimulatorClient<Channel>) -> (u32, u32) {
    let info = c
        .get_server_info(v1::GetServerInfoRequest {})
        .await
        .expect("info")
        .into_inner();
    (info.active_sessions, info.active_envs)
}

/// A step stream: a sender of requests and the reply stream.
struct Stream {
    tx: mpsc::Sender<v1::StepRequest>,
    rx: tonic::Streaming<v1::StepResult>,
}

async fn open_stream(c: &mut SimulatorClient<Channel>) -> Stream {
    let (tx, requests) = mpsc::channel(4);
    let rx = c
        .step_stream(ReceiverStream::new(requests))
        .await
        .expect("open stream")
        .into_inner();
    Stream { tx, rx }
}

impl Stream {
    async fn step(&mut self, r: v1::StepRequest) -> Result<Option<v1::StepResult>, Status> {
        self.tx.send(r).await.expect("send");
        self.next().await
    }

    async fn next(&mut self) -> Result<Option<v1::StepResult>, Status> {
        tokio::time::timeout(Duration::from_secs(20), self.rx.message())
            .await
            .expect("the stream answers")
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_overrides_too_long_or_too_deep_are_refused_before_parsing() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    // Deep enough to overflow a parser's stack if it recursed on it.
    let deep = format!("x = {}1{}", "[".repeat(30_000), "]".repeat(30_000));
    let r = c.create_session(config(1, 1, &deep)).await;
    let status = r.expect_err("too deep");
    assert_eq!(status.code(), Code::InvalidArgument);
    assert!(status.message().contains("nests"), "{}", status.message());
    let dotted = format!("{} = 1", vec!["a"; 1000].join("."));
    assert_eq!(
        code(c.create_session(config(1, 1, &dotted)).await),
        Code::InvalidArgument
    );
    let long = format!("# {}\n", "x".repeat(100_000));
    assert_eq!(
        code(c.create_session(config(1, 1, &long)).await),
        Code::InvalidArgument
    );
    // The paper's ablation still goes through.
    let id = create(&mut c, 1, 1, "[rewards]\ntask_indicators = false\n").await;
    c.close_session(v1::CloseSessionRequest { session_id: id })
        .await
        .expect("close");
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_cost_caps_refuse_expensive_physics() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    for overrides in [
        "[env]\ndecimation = 100\n",
        "[env]\nenvs_per_world = 4096\n",
        "[physics]\nsolver_iterations = 64\n",
        "[physics]\npgs_iterations = 64\n",
        "[physics]\nextra_iterations_on_leg_contact = 64\n",
        "[physics]\nextra_pgs_iterations_on_leg_contact = 64\n",
        "[physics]\ndt = 0.0001\n",
    ] {
        let status = c
            .create_session(config(1, 1, overrides))
            .await
            .expect_err(overrides);
        assert_eq!(status.code(), Code::ResourceExhausted, "{overrides}");
        assert!(status.message().contains("cap") || status.message().contains("floor"));
    }
    assert_eq!(active_sessions(&mut c).await, (0, 0));
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_envs_are_reserved_before_they_are_built() {
    let server = TestServer::with_limits(Limits {
        max_total_envs: 40,
        ..Limits::default()
    })
    .await;
    let c = server.client().await;
    // Three concurrent creates of 16 envs: two fit in 40, the third is refused up front.
    let tries = (0..3).map(|i| {
        let mut c = c.clone();
        async move { c.create_session(config(16, i, "")).await }
    });
    let results = futures_join(tries).await;
    let ok = results.iter().filter(|r| r.is_ok()).count();
    assert_eq!(ok, 2);
    for r in &results {
        if let Err(s) = r {
            assert_eq!(s.code(), Code::ResourceExhausted);
        }
    }
    let mut c = c.clone();
    assert_eq!(active_sessions(&mut c).await, (2, 32));
    server.shutdown().await;
}

async fn futures_join<F: std::future::Future + Send + 'static>(
    futures: impl Iterator<Item = F>,
) -> Vec<F::Output>
where
    F::Output: Send + 'static,
{
    let handles: Vec<_> = futures.map(tokio::spawn).collect();
    let mut out = Vec::new();
    for h in handles {
        out.push(h.await.expect("join"));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_closing_a_streaming_session_frees_it() {
    let server = TestServer::with_limits(Limits {
        max_sessions: 1,
        ..Limits::default()
    })
    .await;
    let mut c = server.client().await;
    for seed in 0..5 {
        let id = create(&mut c, 2, seed, "").await;
        let mut stream = open_stream(&mut c).await;
        stream.step(step_request(&id, 2)).await.expect("step");
        c.close_session(v1::CloseSessionRequest {
            session_id: id.clone(),
        })
        .await
        .expect("close");
        // The stream ends with NOT_FOUND and the slot is free again.
        let end = stream.next().await;
        assert_eq!(code(end), Code::NotFound);
        assert_eq!(active_sessions(&mut c).await, (0, 0));
    }
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_a_session_that_panics_is_removed() {
    let server = TestServer::start(ServeOptions {
        fault_injection_seed: Some(666),
        ..options(Limits::default())
    })
    .await;
    let mut c = server.client().await;
    let bystander = create(&mut c, 1, 1, "").await;
    let id = create(&mut c, 1, 666, "").await;
    let first = c.step(step_request(&id, 1)).await;
    assert_eq!(code(first), Code::Internal);
    let again = c.step(step_request(&id, 1)).await;
    assert_eq!(code(again), Code::NotFound, "the broken session is gone");
    assert_eq!(active_sessions(&mut c).await, (1, 1));
    c.step(step_request(&bystander, 1))
        .await
        .expect("others step on");
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_stream_semantics() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let id = create(&mut c, 2, 3, "").await;
    let mut stream = open_stream(&mut c).await;
    let first = stream
        .step(step_request(&id, 2))
        .await
        .expect("step")
        .expect("a result");
    let nonfinite = first.nonfinite.expect("nonfinite flags");
    assert_eq!(nonfinite.u8_values("nonfinite").expect("u8"), &[0, 0]);
    // A unary Step on a session with an open stream is refused.
    assert_eq!(
        code(c.step(step_request(&id, 2)).await),
        Code::FailedPrecondition
    );
    // A failed step ends the stream with its status ...
    let mut bad = step_request("", 2);
    bad.actions = Some(f32_tensor(&[0.0; 12], &[1, 12]));
    assert_eq!(code(stream.step(bad).await), Code::InvalidArgument);
    // ... and the session stays: a new stream re-attaches to it.
    let mut again = open_stream(&mut c).await;
    again
        .step(step_request(&id, 2))
        .await
        .expect("re-attached")
        .expect("a result");
    // A message that does not decode ends the stream as the client's error (tonic's own codec
    // says INTERNAL, the service's fault).
    drop(again);
    let raw = raw_stream(&server, b"\xff\xff\xff\xff not protobuf").await;
    assert_eq!(raw, Some(Code::InvalidArgument));
    server.shutdown().await;
}

/// Send one undecodable message on StepStream; the status the stream ended with.
async fn raw_stream(server: &TestServer, payload: &[u8]) -> Option<Code> {
    let channel = Channel::from_shared(format!("http://{}", server.addr))
        .expect("uri")
        .connect()
        .await
        .expect("connect");
    let mut grpc = tonic::client::Grpc::new(channel);
    grpc.ready().await.expect("ready");
    let (tx, rx) = mpsc::channel::<RawBytes>(1);
    tx.send(RawBytes(payload.to_vec())).await.expect("send");
    let path =
        tonic::codegen::http::uri::PathAndQuery::from_static("/unigait.v1.Simulator/StepStream");
    let reply = grpc
        .streaming(Request::new(ReceiverStream::new(rx)), path, RawCodec)
        .await;
    match reply {
        Err(s) => Some(s.code()),
        Ok(r) => {
            let mut s = r.into_inner();
            match tokio::time::timeout(Duration::from_secs(10), s.next()).await {
                Ok(Some(Err(st))) => Some(st.code()),
                Ok(Some(Ok(_))) => Some(Code::Ok),
                Ok(None) => Some(Code::Ok),
                Err(_) => None,
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_autoreset_off_reports_an_ended_env_once() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let overrides = "[env]\nepisode_length_s = 0.1\nrandom_initial_episode_step = false\n";
    let reply = c
        .create_session(v1::CreateSessionRequest {
            config: Some(v1::SessionConfig {
                num_envs: 2,
                seed: 5,
                task_overrides_toml: overrides.into(),
                autoreset: v1::AutoresetMode::Disabled as i32,
                ..Default::default()
            }),
        })
        .await
        .expect("create")
        .into_inner();
    let id = reply.session_id;
    let mut ends = [0u32; 2];
    for _ in 0..15 {
        let r = c
            .step(step_request(&id, 2))
            .await
            .expect("step")
            .into_inner();
        let term = r.terminated.expect("t");
        let trunc = r.truncated.expect("t");
        let (term, trunc) = (
            term.u8_values("terminated").expect("u8"),
            trunc.u8_values("truncated").expect("u8"),
        );
        for i in 0..2 {
            ends[i] += u32::from(term[i] != 0 || trunc[i] != 0);
        }
    }
    assert_eq!(ends, [1, 1], "each ended env is reported once");
    // After a reset, env 0 ends again (once); env 1 stays ended.
    c.reset(v1::ResetRequest {
        session_id: id.clone(),
        mask: Some(u8_tensor(&[1, 0], &[2])),
    })
    .await
    .expect("reset");
    let mut again = [0u32; 2];
    for _ in 0..15 {
        let r = c
            .step(step_request(&id, 2))
            .await
            .expect("step")
            .into_inner();
        let ids = r.final_env_ids.expect("ids");
        for &i in ids.u32_values("ids").expect("u32").iter() {
            again[i as usize] += 1;
        }
    }
    assert_eq!(again, [1, 0]);
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_an_idle_stream_ends_and_the_session_can_be_reattached() {
    let server = TestServer::with_limits(Limits {
        stream_idle_timeout_s: 1,
        ..Limits::default()
    })
    .await;
    let mut c = server.client().await;
    let id = create(&mut c, 1, 1, "").await;
    let mut stream = open_stream(&mut c).await;
    stream.step(step_request(&id, 1)).await.expect("step");
    // The client goes silent (as a half-open connection would).
    let end = stream.next().await;
    assert_eq!(code(end), Code::DeadlineExceeded);
    let mut again = open_stream(&mut c).await;
    again
        .step(step_request(&id, 1))
        .await
        .expect("re-attached")
        .expect("a result");
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_shutdown_ends_streams_unavailable_and_returns() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let id = create(&mut c, 1, 1, "").await;
    let mut stream = open_stream(&mut c).await;
    stream.step(step_request(&id, 1)).await.expect("step");
    let stop = server.stop.as_ref().map(|_| ());
    assert!(stop.is_some());
    let mut server = server;
    if let Some(s) = server.stop.take() {
        let _ = s.send(());
    }
    let end = stream.next().await;
    assert_eq!(code(end), Code::Unavailable);
    drop(stream);
    drop(c);
    let took = server.shutdown().await;
    assert!(took < Duration::from_secs(6), "drain took {took:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_short_tokens_are_refused_at_startup() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let r = serve(
        listener,
        ServeOptions {
            token: Some("short".into()),
            ..ServeOptions::default()
        },
        async {},
    )
    .await;
    assert!(matches!(r, Err(ServeError::Token(_))), "{r:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_error_messages_echoing_client_strings_are_cut() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let long_id = "x".repeat(100_000);
    let status = c
        .step(step_request(&long_id, 1))
        .await
        .expect_err("unknown");
    assert_eq!(status.code(), Code::NotFound);
    assert!(status.message().len() < 600, "{}", status.message().len());
    server.shutdown().await;
}

// ---- Evaluate -------------------------------------------------------------------------------

fn test_policy() -> Vec<u8> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/test_policy.onnx"
    );
    std::fs::read(path).expect("tests/data/test_policy.onnx")
}

fn evaluate_request(policy: Vec<u8>, scenario: &str, envs: u32) -> v1::EvaluateRequest {
    v1::EvaluateRequest {
        policy_onnx: policy.into(),
        biped_policy_onnx: Default::default(),
        scenario: scenario.into(),
        num_envs: envs,
        seed: 1,
        record: false,
        record_env: None,
        task_overrides_toml: String::new(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_evaluations_are_limited_stop_with_their_caller_and_cap_their_reply() {
    let server = TestServer::with_limits(Limits {
        max_concurrent_evaluations: 1,
        max_evaluation_reply_bytes: 2000,
        ..Limits::default()
    })
    .await;
    let c = server.client().await;
    // A long evaluation whose caller gives up after 1.5 s (its grpc-timeout).
    let long = {
        let mut c = c.clone();
        tokio::spawn(async move {
            let mut r = Request::new(evaluate_request(test_policy(), "flat_quad", 256));
            r.set_timeout(Duration::from_millis(1500));
            c.evaluate(r).await
        })
    };
    tokio::time::sleep(Duration::from_millis(500)).await;
    let mut c2 = c.clone();
    let busy = c2
        .evaluate(evaluate_request(test_policy(), "flat_quad", 1))
        .await;
    assert_eq!(code(busy), Code::ResourceExhausted);
    let long = long.await.expect("join");
    let long_code = code(long);
    assert!(
        matches!(long_code, Code::DeadlineExceeded | Code::Cancelled),
        "{long_code:?}"
    );
    // The slot comes back once the rollout has stopped (at its next step).
    let start = Instant::now();
    let small = loop {
        let r = c2
            .evaluate(evaluate_request(test_policy(), "flat_quad", 1))
            .await;
        match r {
            Err(s) if s.code() == Code::ResourceExhausted && s.message().contains("at once") => {
                assert!(start.elapsed() < Duration::from_secs(10), "slot not freed");
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            other => break other,
        }
    };
    // Its reply (the report JSON) is over the 2000-byte cap.
    let status = small.expect_err("reply too large");
    assert_eq!(status.code(), Code::ResourceExhausted, "{status:?}");
    assert!(status.message().contains("reply"), "{}", status.message());
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_evaluation_runs_on_the_engine_its_overrides_name_and_bad_ones_are_the_clients() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let mut metrics = Vec::new();
    for (overrides, engine) in [
        ("", "articulated"),
        ("physics.engine = \"rapier\"", "rapier"),
    ] {
        let mut request = evaluate_request(test_policy(), "flat_quad", 2);
        request.task_overrides_toml = overrides.into();
        let reply = c.evaluate(request).await.expect(overrides).into_inner();
        let report: serde_json::Value =
            serde_json::from_str(&reply.report_json).expect("report JSON");
        assert_eq!(report["physics_engine"], engine, "{overrides:?}");
        let mut m = reply.metrics;
        m.remove("wall_s");
        metrics.push(m);
    }
    // Same policy, seed and scenario: other dynamics, other figures.
    assert_ne!(metrics[0], metrics[1]);
    for (overrides, expected, names) in [
        ("physics.engine = \"warp\"", Code::InvalidArgument, "warp"),
        ("[[[[", Code::InvalidArgument, "config:"),
        (
            &*format!("x = {}1{}", "[".repeat(30_000), "]".repeat(30_000)),
            Code::InvalidArgument,
            "EvaluateRequest.task_overrides_toml",
        ),
        (
            "env.decimation = 100",
            Code::ResourceExhausted,
            "env.decimation",
        ),
    ] {
        let mut request = evaluate_request(test_policy(), "flat_quad", 1);
        request.task_overrides_toml = overrides.into();
        let status = c.evaluate(request).await.expect_err(names);
        assert_eq!(status.code(), expected, "{status:?}");
        assert!(status.message().contains(names), "{}", status.message());
    }
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_evaluation_runs_on_the_engine_its_policy_names_unless_the_overrides_choose() {
    use unigait_policy::{PHYSICS_ENGINE_KEY, with_metadata};
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let stamped = |engine: &str| with_metadata(&test_policy(), PHYSICS_ENGINE_KEY, engine);
    let rapier = "physics.engine = \"rapier\"";
    for (policy, biped, overrides, engine) in [
        (stamped("articulated"), vec![], "", "articulated"),
        (stamped("rapier"), vec![], "", "rapier"),
        (stamped("articulated"), vec![], rapier, "rapier"),
        // Two policies: the one that says is enough; when both say, the overrides decide.
        (test_policy(), stamped("articulated"), "", "articulated"),
        (stamped("rapier"), stamped("articulated"), rapier, "rapier"),
    ] {
        let mut request = evaluate_request(policy, "flat_quad", 2);
        request.biped_policy_onnx = biped.into();
        request.task_overrides_toml = overrides.into();
        let reply = c.evaluate(request).await.expect(engine).into_inner();
        let report: serde_json::Value =
            serde_json::from_str(&reply.report_json).expect("report JSON");
        assert_eq!(report["physics_engine"], engine, "{overrides:?}");
    }
    for (policy, biped, names) in [
        (
            stamped("warp"),
            vec![],
            "policy_onnx: its metadata says it trained on physics engine \"warp\"",
        ),
        (
            stamped("rapier"),
            stamped("articulated"),
            "biped_policy_onnx on the articulated",
        ),
    ] {
        let mut request = evaluate_request(policy, "flat_quad", 1);
        request.biped_policy_onnx = biped.into();
        let status = c.evaluate(request).await.expect_err(names);
        assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
        assert!(status.message().contains(names), "{}", status.message());
    }
    server.shutdown().await;
}

/// A graph `obs_history [batch, 3, 53] -> Flatten -> Gemm(W) (+ extra) -> actions [batch, 12]`
/// with `extra` nodes and initialisers spliced in; `bias` names the tensor added to the output.
fn policy_graph(
    mut nodes: Vec<pb::NodeProto>,
    mut initializers: Vec<pb::TensorProto>,
    bias: Option<&str>,
) -> Vec<u8> {
    fn node(
        op: &str,
        inputs: &[&str],
        output: &str,
        attrs: Vec<pb::AttributeProto>,
    ) -> pb::NodeProto {
        pb::NodeProto {
            op_type: op.into(),
            name: output.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.into()],
            attribute: attrs,
            ..Default::default()
        }
    }
    let value_info = |name: &str, dims: &[Option<i64>]| pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: 1,
                shape: Some(pb::TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|d| pb::tensor_shape_proto::Dimension {
                            value: Some(match d {
                                Some(v) => pb::tensor_shape_proto::dimension::Value::DimValue(*v),
                                None => pb::tensor_shape_proto::dimension::Value::DimParam(
                                    "batch".into(),
                                ),
                            }),
                            ..Default::default()
                        })
                        .collect(),
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    };
    initializers.push(f32_init("W", &[159, 12], 0.0));
    let mut all = vec![node(
        "Flatten",
        &["obs_history"],
        "flat",
        vec![attr_int("axis", 1)],
    )];
    let out = if bias.is_some() { "gemm" } else { "actions" };
    all.push(node("Gemm", &["flat", "W"], out, vec![]));
    all.append(&mut nodes);
    if let Some(b) = bias {
        all.push(node("Add", &["gemm", b], "actions", vec![]));
    }
    let model = pb::ModelProto {
        ir_version: 8,
        opset_import: vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: 17,
        }],
        graph: Some(pb::GraphProto {
            name: "hostile".into(),
            node: all,
            initializer: initializers,
            input: vec![value_info("obs_history", &[None, Some(3), Some(53)])],
            output: vec![value_info("actions", &[None, Some(12)])],
            ..Default::default()
        }),
        ..Default::default()
    };
    model.encode_to_vec()
}

fn attr_int(name: &str, v: i64) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Int as i32,
        i: v,
        ..Default::default()
    }
}

fn f32_init(name: &str, dims: &[i64], value: f32) -> pb::TensorProto {
    let n: i64 = dims.iter().product();
    pb::TensorProto {
        name: name.into(),
        dims: dims.to_vec(),
        data_type: 1,
        float_data: vec![value; n as usize],
        ..Default::default()
    }
}

fn op(op: &str, inputs: &[&str], output: &str, attrs: Vec<pb::AttributeProto>) -> pb::NodeProto {
    pb::NodeProto {
        op_type: op.into(),
        name: output.into(),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        attribute: attrs,
        ..Default::default()
    }
}

fn i64_init(name: &str, values: &[i64]) -> pb::TensorProto {
    pb::TensorProto {
        name: name.into(),
        dims: vec![values.len() as i64],
        data_type: 7,
        int64_data: values.to_vec(),
        ..Default::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_hostile_policies_get_client_errors_and_the_server_lives() {
    let server = TestServer::start(ServeOptions {
        sandbox: unigait_policy::SandboxLimits {
            memory_bytes: 512 << 20,
            ..Default::default()
        },
        ..options(Limits::default())
    })
    .await;
    let mut c = server.client().await;
    let mut cases: Vec<(&str, Vec<u8>, Code)> = Vec::new();
    // ConstantOfShape([2^20, 2^20]) folds to 4 TiB: not an op a policy may use.
    cases.push((
        "constant_of_shape",
        policy_graph(
            vec![op("ConstantOfShape", &["shape"], "big", vec![])],
            vec![i64_init("shape", &[1 << 20, 1 << 20])],
            None,
        ),
        Code::InvalidArgument,
    ));
    // Range(0, 1e12).
    cases.push((
        "range",
        policy_graph(
            vec![op("Range", &["s", "e", "d"], "r", vec![])],
            vec![
                f32_init("s", &[], 0.0),
                f32_init("e", &[], 1e12),
                f32_init("d", &[], 1.0),
            ],
            None,
        ),
        Code::InvalidArgument,
    ));
    // An initialiser whose dims say 2^40 elements.
    cases.push((
        "huge_initializer",
        policy_graph(
            vec![],
            vec![pb::TensorProto {
                name: "huge".into(),
                dims: vec![1 << 20, 1 << 20],
                data_type: 1,
                ..Default::default()
            }],
            None,
        ),
        Code::ResourceExhausted,
    ));
    // Allowed ops only, but a chain of Concat(x, x) doubles a 48-byte constant to terabytes as
    // tract folds it: the worker runs out of its memory, not the server.
    let mut nodes = Vec::new();
    let mut prev = "seed".to_string();
    for i in 0..36 {
        let next = format!("c{i}");
        nodes.push(op(
            "Concat",
            &[prev.as_str(), prev.as_str()],
            &next,
            vec![attr_int("axis", 0)],
        ));
        prev = next;
    }
    nodes.push(op(
        "Slice",
        &[prev.as_str(), "st", "en", "ax"],
        "bias",
        vec![],
    ));
    cases.push((
        "concat_doubling",
        policy_graph(
            nodes,
            vec![
                f32_init("seed", &[1, 12], 0.0),
                i64_init("st", &[0]),
                i64_init("en", &[1]),
                i64_init("ax", &[0]),
            ],
            Some("bias"),
        ),
        Code::ResourceExhausted,
    ));
    cases.push((
        "garbage",
        b"\x08\x01\x12\xff\xff\xff not onnx".to_vec(),
        Code::InvalidArgument,
    ));
    for (name, bytes, expected) in cases {
        let start = Instant::now();
        let status = c
            .evaluate(evaluate_request(bytes, "flat_quad", 1))
            .await
            .expect_err(name);
        assert_eq!(status.code(), expected, "{name}: {status:?}");
        eprintln!("{name}: {:?} {}", status.code(), status.message());
        if name == "concat_doubling" {
            assert!(status.message().contains("memory"), "{}", status.message());
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "{name} took {:?}",
            start.elapsed()
        );
        c.get_server_info(v1::GetServerInfoRequest {})
            .await
            .expect("the server lives");
    }
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_a_policy_over_its_time_limit_is_resource_exhausted() {
    let server = TestServer::start(ServeOptions {
        sandbox: unigait_policy::SandboxLimits {
            act_timeout: Duration::from_micros(1),
            ..Default::default()
        },
        ..options(Limits::default())
    })
    .await;
    let mut c = server.client().await;
    let status = c
        .evaluate(evaluate_request(test_policy(), "flat_quad", 1))
        .await
        .expect_err("too slow");
    assert_eq!(status.code(), Code::ResourceExhausted, "{status:?}");
    assert!(status.message().contains("longer"), "{}", status.message());
    server.shutdown().await;
}

/// A session config with `terrain.initial_levels`.
fn with_levels(n: u32, kind: &str, levels: Vec<u32>) -> v1::CreateSessionRequest {
    with_mode_levels(n, kind, levels, Vec::new(), "")
}

/// A session config with `terrain.initial_levels`, `terrain.initial_mode_levels` and task
/// overrides.
fn with_mode_levels(
    n: u32,
    kind: &str,
    levels: Vec<u32>,
    mode_levels: Vec<u32>,
    task: &str,
) -> v1::CreateSessionRequest {
    let mut request = config(n, 3, task);
    if let Some(c) = request.config.as_mut() {
        c.terrain = Some(v1::TerrainConfig {
            kind: kind.into(),
            level: 1,
            initial_levels: levels,
            initial_mode_levels: mode_levels,
            columns: Vec::new(),
        });
    }
    request
}

/// A curriculum session of `n` envs on the top level with `columns` as its grid.
fn with_columns(n: u32, kind: &str, columns: &[&str]) -> v1::CreateSessionRequest {
    let mut request = with_levels(n, kind, Vec::new());
    if let Some(t) = request.config.as_mut().and_then(|c| c.terrain.as_mut()) {
        if kind == "curriculum" {
            t.initial_levels = vec![9; n as usize];
        }
        t.columns = columns.iter().map(|c| c.to_string()).collect();
    }
    request
}

/// A session names its grid's columns; envs fill them in blocks, so the first two of four
/// spawn on the top stairs-down platform (raised eight risers) and the last two in the top
/// stairs-up pit (sunk eight). The spec lists the grid's columns. Bad columns are refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_curriculum_session_builds_the_columns_it_names() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let created = c
        .create_session(with_columns(4, "curriculum", &["stairs_down", "stairs_up"]))
        .await
        .expect("a session with two columns")
        .into_inner();
    let spec = created.spec.expect("spec");
    assert_eq!(spec.terrain_columns, ["stairs_down", "stairs_up"]);
    let mut step = step_request(&created.session_id, 4);
    step.draw_envs = vec![0, 1, 2, 3];
    let result = c.step(step).await.expect("step").into_inner();
    let poses = result.body_poses.expect("body_poses");
    let bodies = spec.body_names.len();
    let poses = poses.f32_values("body_poses").expect("f32");
    let base_z: Vec<f32> = (0..4).map(|k| poses[k * bodies * 7 + 2]).collect();
    for (down, up) in [(0, 2), (0, 3), (1, 2), (1, 3)] {
        assert!(
            base_z[down] - base_z[up] > 1.0,
            "env {down} on stairs down, env {up} on stairs up: base z {base_z:?}"
        );
    }
    // Without columns: legged_gym's 20; on flat ground: none.
    let default = c
        .create_session(with_columns(4, "curriculum", &[]))
        .await
        .expect("default columns")
        .into_inner()
        .spec
        .expect("spec");
    assert_eq!(default.terrain_columns.len(), 20);
    assert_eq!(default.terrain_columns[0], "slope_up");
    assert_eq!(
        default
            .terrain_columns
            .iter()
            .filter(|t| t.starts_with("stairs"))
            .count(),
        12
    );
    let flat = c
        .create_session(config(2, 3, ""))
        .await
        .expect("flat")
        .into_inner()
        .spec
        .expect("spec");
    assert!(flat.terrain_columns.is_empty());
    for (request, what) in [
        (
            with_columns(4, "curriculum", &["stairs_up", "lava"]),
            "unknown type",
        ),
        (
            with_columns(4, "stairs_up", &["stairs_up"]),
            "a pinned tile",
        ),
        (with_columns(4, "flat", &["stairs_up"]), "flat ground"),
    ] {
        assert_refused(&mut c, request, "terrain.columns", what).await;
    }
    // A grid costlier than the caps (decision record 0037) is refused before it is built; the
    // largest one they allow is built.
    let caps = Limits::default().cost;
    let mut most = vec!["obstacles"; caps.max_terrain_columns - caps.max_rough_slope_columns];
    most.extend(vec!["rough_slope"; caps.max_rough_slope_columns]);
    let over_columns = vec!["stairs_up"; caps.max_terrain_columns + 1];
    let over_rough = vec!["rough_slope"; caps.max_rough_slope_columns + 1];
    for (columns, what) in [(&over_columns, "columns"), (&over_rough, "rough_slope")] {
        let status = c
            .create_session(with_columns(4, "curriculum", columns))
            .await
            .expect_err("over the caps");
        assert_eq!(status.code(), Code::ResourceExhausted, "{what}: {status}");
        assert!(status.message().contains(what), "{status}");
    }
    let largest = c
        .create_session(with_columns(4, "curriculum", &most))
        .await
        .expect("the largest grid the caps allow")
        .into_inner();
    assert_eq!(
        largest.spec.expect("spec").terrain_columns.len(),
        most.len()
    );
    server.shutdown().await;
}

/// `request` is refused as INVALID_ARGUMENT, naming `field`.
async fn assert_refused(
    c: &mut SimulatorClient<Channel>,
    request: v1::CreateSessionRequest,
    field: &str,
    what: &str,
) {
    let status = c.create_session(request).await.expect_err("refused");
    assert_eq!(status.code(), Code::InvalidArgument, "{what}: {status}");
    assert!(status.message().contains(field), "{status}");
}

fn u32s(t: Option<v1::Tensor>, name: &str) -> Vec<u32> {
    t.expect(name).u32_values(name).expect("u32").into_owned()
}

/// Decision record 0036: a resumed run hands back each env's (quad, biped) levels; with a
/// level per mode the envs start on the level of the mode they start in, and every step
/// reports both. Without it both report the env's one level. Bad counts are refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_curriculum_session_starts_each_mode_on_the_level_it_asks_for() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    let levels: Vec<u32> = vec![5; 8];
    let pairs: Vec<u32> = (0..8).flat_map(|i| [i % 3, 9 - i % 4]).collect();
    let per_mode = "[terrain_curriculum]\nper_mode_levels = true\n";
    let created = c
        .create_session(with_mode_levels(
            8,
            "curriculum",
            levels.clone(),
            pairs.clone(),
            per_mode,
        ))
        .await
        .expect("a session with two levels per env")
        .into_inner();
    let initial = created.initial.expect("initial step");
    assert_eq!(u32s(initial.mode_levels, "mode_levels"), pairs);
    let modes = initial
        .mode
        .expect("mode")
        .u8_values("mode")
        .expect("u8")
        .to_vec();
    let tiles = u32s(initial.terrain_level, "terrain_level");
    for (i, (&mode, &tile)) in modes.iter().zip(&tiles).enumerate() {
        // Mode 1 is biped: the second of the pair.
        let own = pairs[2 * i + usize::from(mode == 1)];
        assert_eq!(tile, own, "env {i} in mode {mode}");
    }
    // Without a level per mode the pairs are kept aside and both modes report the one level.
    let created = c
        .create_session(with_mode_levels(
            8,
            "curriculum",
            levels.clone(),
            pairs.clone(),
            "",
        ))
        .await
        .expect("a session with one level per env")
        .into_inner();
    let initial = created.initial.expect("initial step");
    assert_eq!(u32s(initial.mode_levels, "mode_levels"), vec![5; 16]);
    assert_eq!(u32s(initial.terrain_level, "terrain_level"), levels);
    for (kind, bad) in [
        ("curriculum", vec![0; 15]),
        ("curriculum", [vec![0; 15], vec![10]].concat()),
        ("stairs_up", vec![0; 16]),
    ] {
        let request = with_mode_levels(8, kind, Vec::new(), bad.clone(), per_mode);
        let what = format!("{kind} {bad:?}");
        assert_refused(&mut c, request, "initial_mode_levels", &what).await;
    }
    assert_eq!(active_sessions(&mut c).await.0, 2);
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_curriculum_session_starts_its_envs_on_the_levels_it_asks_for() {
    let server = TestServer::with_limits(Limits::default()).await;
    let mut c = server.client().await;
    // Levels 4-9, all above the drawn range 0..=1: only the given levels put envs there.
    let levels: Vec<u32> = (0..8).map(|i| 9 - i % 6).collect();
    let created = c
        .create_session(with_levels(8, "curriculum", levels.clone()))
        .await
        .expect("a curriculum session with one level per env")
        .into_inner();
    let initial = created.initial.expect("initial step");
    let got = initial
        .terrain_level
        .expect("terrain levels")
        .u32_values("terrain_level")
        .expect("u32")
        .into_owned();
    assert_eq!(got, levels);
    // A level off the grid, a count that is not one per env, a pinned terrain: refused.
    for (kind, bad) in [
        ("curriculum", vec![0, 1, 2, 3, 4, 5, 6, 10]),
        ("curriculum", vec![0; 7]),
        ("stairs_up", vec![0; 8]),
        ("flat", vec![0; 8]),
    ] {
        let what = format!("{kind} {bad:?}");
        assert_refused(
            &mut c,
            with_levels(8, kind, bad.clone()),
            "initial_levels",
            &what,
        )
        .await;
    }
    assert_eq!(active_sessions(&mut c).await.0, 1);
    server.shutdown().await;
}
