//! Issue 37, the server side, over a real loopback socket: a step asks for chosen envs' body
//! poses (`StepRequest.draw_envs`) and a session for the robot's drawing
//! (`SessionConfig.robot_drawing`), so a learner draws its training envs in a live view.

mod common;

use tokio_stream::StreamExt;
use tonic::Code;
use tonic::transport::Channel;
use unigait_proto::v1::{self, simulator_client::SimulatorClient};
use unigait_proto::{TensorView, f32_tensor};
use unigait_server::{Limits, ServeOptions, serve};

async fn start() -> SimulatorClient<Channel> {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr");
    let options = ServeOptions {
        limits: Limits::default(),
        threads: 2,
        ..ServeOptions::default()
    };
    tokio::spawn(async move { serve(listener, options, std::future::pending()).await });
    common::connect(addr).await
}

async fn create(c: &mut SimulatorClient<Channel>, drawing: bool) -> v1::CreateSessionResponse {
    c.create_session(v1::CreateSessionRequest {
        config: Some(v1::SessionConfig {
            num_envs: 4,
            seed: 7,
            robot_drawing: drawing,
            ..Default::default()
        }),
    })
    .await
    .expect("create")
    .into_inner()
}

fn step(id: &str, draw_envs: Vec<u32>) -> v1::StepRequest {
    v1::StepRequest {
        session_id: id.into(),
        actions: Some(f32_tensor(&[0.0; 4 * 12], &[4, 12])),
        reward_terms: false,
        draw_envs,
    }
}

/// The poses of a reply as [env][body] = [x, y, z, qx, qy, qz, qw].
fn poses(r: &v1::StepResult, bodies: usize) -> Vec<Vec<[f32; 7]>> {
    let t = r.body_poses.as_ref().expect("body_poses");
    let k = t.shape[0] as usize;
    assert_eq!(t.shape, vec![k as u32, bodies as u32, 7]);
    let v = t.f32_values("body_poses").expect("f32");
    (0..k)
        .map(|e| {
            (0..bodies)
                .map(|b| {
                    let at = (e * bodies + b) * 7;
                    v[at..at + 7].try_into().expect("7 values")
                })
                .collect()
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_step_returns_the_poses_of_the_envs_it_names_in_their_order() {
    let mut c = start().await;
    let a = create(&mut c, true).await;
    let b = create(&mut c, false).await;
    let spec = a.spec.expect("spec");
    // The bodies, base first; the drawing only for the session that asked.
    assert_eq!(spec.body_names[0], "base");
    assert!(spec.body_names.contains(&"FL_foot".to_string()) || spec.body_names.len() >= 13);
    let bodies = spec.body_names.len();
    assert!(spec.robot_drawing_rrd.starts_with(b"RRF"), "an .rrd stream");
    assert!(b.spec.expect("spec").robot_drawing_rrd.is_empty());

    // The same seed and actions: session b's rows are a's, in the order each asked.
    let ra = c
        .step(step(&a.session_id, vec![3, 1]))
        .await
        .expect("step a");
    let rb = c
        .step(step(&b.session_id, vec![1, 3]))
        .await
        .expect("step b");
    let (pa, pb) = (poses(ra.get_ref(), bodies), poses(rb.get_ref(), bodies));
    assert_eq!(pa[0], pb[1]);
    assert_eq!(pa[1], pb[0]);
    assert_ne!(pa[0][0][..3], pa[1][0][..3], "two envs, two places");
    for env in &pa {
        let base = env[0];
        assert!((0.15..0.5).contains(&base[2]), "base height {}", base[2]);
        for pose in env {
            let norm = pose[3..].iter().map(|q| q * q).sum::<f32>().sqrt();
            assert!(
                (norm - 1.0).abs() < 1e-4,
                "unit quaternion, got norm {norm}"
            );
        }
    }
    // An old client's step (no envs named) carries no poses.
    let plain = c.step(step(&a.session_id, vec![])).await.expect("step");
    assert!(plain.get_ref().body_poses.is_none());
    assert_eq!(plain.get_ref().step_count, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_draw_envs_are_invalid_arguments_and_leave_the_envs_unstepped() {
    let mut c = start().await;
    let id = create(&mut c, false).await.session_id;
    for (draw, says) in [
        (
            vec![0, 4],
            "env 4 is out of range (the session has envs 0..4)",
        ),
        (vec![u32::MAX], "out of range"),
        (vec![0; 65], "at most 64"),
    ] {
        let err = c.step(step(&id, draw)).await.expect_err("refused");
        assert_eq!(err.code(), Code::InvalidArgument, "{err:?}");
        assert!(err.message().contains(says), "{}", err.message());
    }
    // None of them stepped: the next step is the session's first.
    let r = c.step(step(&id, vec![2])).await.expect("step");
    assert_eq!(r.get_ref().step_count, 1);

    // On a stream: poses when asked, none otherwise; a bad request ends it with the same code.
    let requests = vec![step(&id, vec![0]), step(&id, vec![]), step(&id, vec![9])];
    let mut s = c
        .step_stream(tokio_stream::iter(requests))
        .await
        .expect("stream")
        .into_inner();
    let first = s.next().await.expect("a reply").expect("ok");
    assert_eq!(first.body_poses.expect("poses").shape[0], 1);
    let second = s.next().await.expect("a reply").expect("ok");
    assert!(second.body_poses.is_none());
    let err = s.next().await.expect("the end").expect_err("refused");
    assert_eq!(err.code(), Code::InvalidArgument);
}
