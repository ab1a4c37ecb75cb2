//! A bounded fuzz of every RPC over a real loopback socket: well-formed messages with extreme
//! values, huge repeated fields, and random bytes. The server stays up and answers health,
//! never answers UNKNOWN or INTERNAL (bytes that do not decode are INVALID_ARGUMENT), and never
//! hangs (every call is bounded). Seeded, ~1300 calls, a few seconds.

mod common;

use std::time::{Duration, Instant};

use common::{RawBytes, RawCodec};
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tokio::sync::oneshot;
use tonic::transport::Channel;
use tonic::{Code, Request, Status};
use unigait_proto::v1::{self, simulator_client::SimulatorClient};
use unigait_server::{Limits, ServeOptions, serve};

const CALL_TIMEOUT: Duration = Duration::from_secs(20);

fn extreme_u32(rng: &mut ChaCha8Rng) -> u32 {
    match rng.random_range(0..6) {
        0 => 0,
        1 => 1,
        2 => u32::MAX,
        3 => rng.random_range(0..8),
        4 => rng.random_range(0..100_000),
        _ => rng.random(),
    }
}

fn extreme_f32(rng: &mut ChaCha8Rng) -> f32 {
    match rng.random_range(0..7) {
        0 => f32::NAN,
        1 => f32::INFINITY,
        2 => f32::MAX,
        3 => -f32::MAX,
        4 => f32::MIN_POSITIVE,
        5 => 0.0,
        _ => rng.random_range(-10.0..10.0),
    }
}

fn string(rng: &mut ChaCha8Rng, known: &[String]) -> String {
    match rng.random_range(0..5) {
        0 => String::new(),
        1 if !known.is_empty() => known[rng.random_range(0..known.len())].clone(),
        2 => "x".repeat(rng.random_range(0..200_000)),
        3 => (0..rng.random_range(0..64))
            .map(|_| char::from_u32(rng.random_range(0..0x11000)).unwrap_or('?'))
            .collect(),
        _ => "[env]\ndecimation = 2\n".into(),
    }
}

fn tensor(rng: &mut ChaCha8Rng) -> Option<v1::Tensor> {
    if rng.random_bool(0.1) {
        return None;
    }
    let max_rank = if rng.random_bool(0.05) { 100_000 } else { 4 };
    let rank = rng.random_range(0..max_rank);
    let shape: Vec<u32> = (0..rank).map(|_| extreme_u32(rng)).collect();
    let n = rng.random_range(0..2000);
    let data: Vec<u8> = (0..n)
        .flat_map(|_| extreme_f32(rng).to_le_bytes())
        .collect();
    Some(v1::Tensor {
        shape,
        dtype: rng.random_range(-1..5),
        data: data.into(),
    })
}

fn overrides(rng: &mut ChaCha8Rng) -> String {
    let key = [
        "env.decimation",
        "env.envs_per_world",
        "physics.dt",
        "physics.solver_iterations",
        "env.episode_length_s",
        "rewards.task_indicators",
        "nonsense.key",
    ][rng.random_range(0..7)];
    let value = match rng.random_range(0..5) {
        0 => format!("{}", extreme_f32(rng)),
        1 => format!("{}", extreme_u32(rng)),
        2 => "true".into(),
        3 => format!("[{}]", "1,".repeat(rng.random_range(0..1000))),
        _ => "\"str\"".into(),
    };
    format!("{key} = {value}\n")
}

/// Check one reply's status against the rules; returns it for the caller's bookkeeping.
fn check<T>(what: &str, r: Result<Result<T, Status>, tokio::time::error::Elapsed>) {
    let r = r.unwrap_or_else(|_| panic!("{what}: the call hung"));
    if let Err(s) = r {
        assert_ne!(s.code(), Code::Unknown, "{what}: {s:?}");
        assert_ne!(s.code(), Code::Internal, "{what}: {s:?}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_14_fuzz_every_rpc_bounded() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr");
    let (stop, stopped) = oneshot::channel::<()>();
    let options = ServeOptions {
        limits: Limits {
            max_envs_per_session: 64,
            max_sessions: 4,
            max_total_envs: 128,
            max_policy_bytes: 1 << 20,
            ..Limits::default()
        },
        threads: 2,
        policy_worker: Some(env!("CARGO_BIN_EXE_unigait-server").into()),
        ..ServeOptions::default()
    };
    let server = tokio::spawn(async move {
        serve(listener, options, async {
            let _ = stopped.await;
        })
        .await
    });
    let channel = Channel::from_shared(format!("http://{addr}"))
        .expect("uri")
        .connect()
        .await
        .expect("connect");
    let mut c = SimulatorClient::new(channel.clone())
        .max_decoding_message_size(64 << 20)
        .max_encoding_message_size(64 << 20);
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel.clone());
    let mut rng = ChaCha8Rng::seed_from_u64(14);
    let mut known: Vec<String> = Vec::new();
    let start = Instant::now();
    let t = CALL_TIMEOUT;
    let mut undecodable = 0usize;
    for i in 0..1000 {
        match rng.random_range(0..7) {
            0 => {
                let config = v1::SessionConfig {
                    num_envs: if rng.random_bool(0.7) {
                        rng.random_range(0..4)
                    } else {
                        extreme_u32(&mut rng)
                    },
                    seed: rng.random(),
                    task_overrides_toml: if rng.random_bool(0.5) {
                        overrides(&mut rng)
                    } else {
                        string(&mut rng, &[])
                    },
                    terrain: rng.random_bool(0.3).then(|| v1::TerrainConfig {
                        kind: ["flat", "stairs_up", "curriculum", "bogus"][rng.random_range(0..4)]
                            .into(),
                        level: extreme_u32(&mut rng),
                        initial_levels: (0..rng.random_range(0..3))
                            .map(|_| extreme_u32(&mut rng))
                            .collect(),
                        initial_mode_levels: (0..rng.random_range(0..5))
                            .map(|_| extreme_u32(&mut rng))
                            .collect(),
                        columns: (0..rng.random_range(0..3))
                            .map(|_| string(&mut rng, &["stairs_up".into(), "slope_down".into()]))
                            .collect(),
                    }),
                    autoreset: rng.random_range(-1..4),
                    reward_terms: rng.random(),
                    robot_drawing: rng.random_bool(0.1),
                };
                let r = tokio::time::timeout(
                    t,
                    c.create_session(v1::CreateSessionRequest {
                        config: rng.random_bool(0.9).then_some(config),
                    }),
                )
                .await;
                if let Ok(Ok(reply)) = &r {
                    known.push(reply.get_ref().session_id.clone());
                }
                check("create", r.map(|r| r.map(|_| ())));
            }
            1 | 2 => {
                let req = v1::StepRequest {
                    session_id: string(&mut rng, &known),
                    actions: tensor(&mut rng),
                    reward_terms: rng.random(),
                    draw_envs: (0..rng.random_range(0..3))
                        .map(|_| extreme_u32(&mut rng))
                        .collect(),
                };
                check("step", tokio::time::timeout(t, c.step(req)).await);
            }
            3 => {
                let req = v1::ResetRequest {
                    session_id: string(&mut rng, &known),
                    mask: tensor(&mut rng),
                };
                check("reset", tokio::time::timeout(t, c.reset(req)).await);
            }
            4 => {
                let session_id = string(&mut rng, &known);
                let req = v1::StepRequest {
                    session_id,
                    actions: tensor(&mut rng),
                    reward_terms: rng.random(),
                    draw_envs: (0..rng.random_range(0..3))
                        .map(|_| extreme_u32(&mut rng))
                        .collect(),
                };
                let r = tokio::time::timeout(t, async {
                    let mut s = c
                        .step_stream(tokio_stream::iter(vec![req.clone(), req]))
                        .await?
                        .into_inner();
                    while s.message().await?.is_some() {}
                    Ok::<(), Status>(())
                })
                .await;
                check("stream", r);
            }
            5 => {
                let close = rng.random_bool(0.5) && !known.is_empty();
                let session_id = if close {
                    known.swap_remove(rng.random_range(0..known.len()))
                } else {
                    string(&mut rng, &known)
                };
                let r = tokio::time::timeout(
                    t,
                    c.close_session(v1::CloseSessionRequest { session_id }),
                )
                .await;
                check("close", r);
            }
            _ => {
                let policy: Vec<u8> = (0..rng.random_range(0..4096))
                    .map(|_| rng.random())
                    .collect();
                let req = v1::EvaluateRequest {
                    policy_onnx: policy.into(),
                    biped_policy_onnx: Default::default(),
                    scenario: ["flat_quad", "bogus", ""][rng.random_range(0..3)].into(),
                    num_envs: extreme_u32(&mut rng),
                    seed: rng.random(),
                    record: rng.random(),
                    record_env: rng.random::<bool>().then(|| extreme_u32(&mut rng)),
                    task_overrides_toml: [
                        "",
                        "physics.engine = \"articulated\"",
                        "physics.engine = \"warp\"",
                        "env.decimation = 4000",
                        "[[[[",
                    ][rng.random_range(0..5)]
                    .into(),
                };
                check("evaluate", tokio::time::timeout(t, c.evaluate(req)).await);
            }
        }
        // Random bytes on a random method: the client's error, never UNKNOWN or INTERNAL.
        if i % 3 == 0 {
            let method = [
                "GetServerInfo",
                "CreateSession",
                "Reset",
                "Step",
                "CloseSession",
                "Evaluate",
            ][rng.random_range(0..6)];
            let mut bytes = vec![0u8; rng.random_range(0..512)];
            rng.fill_bytes(&mut bytes);
            let code = raw_unary(&channel, method, bytes).await;
            assert_ne!(code, Code::Unknown, "{method} on random bytes");
            assert_ne!(code, Code::Internal, "{method} on random bytes");
            undecodable += usize::from(code == Code::InvalidArgument);
        }
    }
    // Most random bytes are not a message at all (some decode by chance, to a request the
    // service then refuses with its own reason).
    assert!(
        undecodable > 100,
        "{undecodable} random payloads refused as undecodable"
    );
    let info = c
        .get_server_info(v1::GetServerInfoRequest {})
        .await
        .expect("the server lives")
        .into_inner();
    assert!(info.active_sessions <= 4);
    let served = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: String::new(),
        })
        .await
        .expect("health answers")
        .into_inner();
    assert_eq!(
        served.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    assert!(start.elapsed() < Duration::from_secs(60));
    let _ = stop.send(());
    tokio::time::timeout(Duration::from_secs(20), server)
        .await
        .expect("stops")
        .expect("join")
        .expect("serve ok");
}

/// A unary call of `method` with `payload` as the message bytes; its status code.
async fn raw_unary(channel: &Channel, method: &'static str, payload: Vec<u8>) -> Code {
    let mut grpc = tonic::client::Grpc::new(channel.clone());
    if grpc.ready().await.is_err() {
        return Code::Unavailable;
    }
    let path: tonic::codegen::http::uri::PathAndQuery = format!("/unigait.v1.Simulator/{method}")
        .parse()
        .expect("path");
    let r = tokio::time::timeout(
        CALL_TIMEOUT,
        grpc.unary(Request::new(RawBytes(payload)), path, RawCodec),
    )
    .await
    .expect("a raw call hung");
    match r {
        Ok(_) => Code::Ok,
        Err(s) => s.code(),
    }
}
