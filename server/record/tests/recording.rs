//! Headless check of a recording: write a short rollout to an `.rrd` file (and to memory),
//! decode it back with rerun's own decoder, and find the robot's entities, one pose per step on
//! the `step` timeline, and every reward series. Served recordings are read back the way a
//! viewer joining late reads them: rerun's viewer-side gRPC client (`re_grpc_client::stream`)
//! on the served proxy URL, after the whole rollout was logged.

use std::collections::{BTreeMap, BTreeSet};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::time::{Duration, Instant};

use re_log_channel::{DataSourceMessage, RecvTimeoutError, SmartMessagePayload};
use rerun::external::re_grpc_client;
use rerun::log::{Chunk, LogMsg};
use rerun::{StoreKind, TimelineName};
use unigait_record::{
    FOOT_NAMES, RecordError, RecordOptions, Recorder, RrdError, ServeOptions, Served, entity,
};
use unigait_sim::env::{VecEnv, VecEnvOptions};
use unigait_sim::robot::RobotModel;
use unigait_sim::task::{RewardTerm, TaskConfig};
use unigait_sim::terrain::{Terrain, TerrainKind, TerrainSpec, TerrainType};

const STEPS: u64 = 25;
/// End marker of a served test recording.
const END: &str = "test/end";

/// Per entity: rows logged on the `step` timeline (with their distinct step values) and
/// whether it has static data.
#[derive(Debug, Default)]
struct EntityRows {
    steps: BTreeSet<i64>,
    rows: usize,
    is_static: bool,
    /// Components logged (`Archetype:field`).
    components: BTreeSet<String>,
}

/// Rows per entity of a stream of messages.
#[derive(Debug, Default)]
struct Tally {
    entities: BTreeMap<String, EntityRows>,
    /// Recording ids seen (a replay must not add a recording of its own).
    store_ids: BTreeSet<String>,
    /// Messages seen.
    msgs: usize,
    /// Entities of the blueprint store (the viewer layout), kept apart from the recording's.
    blueprint: BTreeMap<String, EntityRows>,
    /// Blueprint activation commands seen.
    activations: usize,
}

impl Tally {
    fn add(&mut self, msg: &LogMsg) {
        self.msgs += 1;
        self.store_ids.insert(format!("{:?}", msg.store_id()));
        if let LogMsg::BlueprintActivationCommand(_) = msg {
            self.activations += 1;
        }
        let LogMsg::ArrowMsg(store, arrow) = msg else {
            return;
        };
        let chunk = Chunk::from_arrow_msg(arrow).expect("a valid chunk");
        let map = if store.kind() == StoreKind::Blueprint {
            &mut self.blueprint
        } else {
            &mut self.entities
        };
        let e = map.entry(chunk.entity_path().to_string()).or_default();
        e.components.extend(
            chunk
                .component_descriptors()
                .map(|d| d.display_name().to_string()),
        );
        match chunk
            .timelines()
            .get(&TimelineName::from_static_str("step"))
        {
            Some(column) => {
                e.rows += chunk.num_rows();
                e.steps.extend(column.times_raw().iter().copied());
            }
            None => e.is_static = true,
        }
    }
}

fn decode_all(bytes: &[u8]) -> Tally {
    let mut tally = Tally::default();
    for msg in re_log_encoding::DecoderApp::decode_lazy(bytes) {
        tally.add(&msg.expect("a valid rrd message"));
    }
    tally
}

fn decode(bytes: &[u8]) -> BTreeMap<String, EntityRows> {
    decode_all(bytes).entities
}

/// Join `url` as a viewer does (rerun's viewer-side gRPC client on its own runtime) and read
/// until `done`. The stream is live and never ends by itself; the deadline only turns a hang
/// into a failure.
fn join_as_viewer(url: &str, done: impl Fn(&Tally) -> bool) -> Tally {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let handle = re_async::AsyncRuntimeHandle::new_native(rt.handle().clone());
    let rx = re_grpc_client::stream(&handle, url.parse().expect("a proxy URL"));
    let mut tally = Tally::default();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !done(&tally) {
        assert!(
            Instant::now() < deadline,
            "incomplete after {} messages: {:#?}",
            tally.msgs,
            rollout_gaps(&tally.entities)
        );
        match rx.recv_timeout(Duration::from_millis(500)) {
            Ok(msg) => match msg.payload {
                SmartMessagePayload::Msg(DataSourceMessage::LogMsg(msg)) => tally.add(&msg),
                SmartMessagePayload::Quit(err) => panic!("the server closed the stream: {err:?}"),
                _ => {}
            },
            Err(RecvTimeoutError::Timeout) => {}
            Err(e) => panic!("the stream broke: {e:?}"),
        }
    }
    // Close the viewer's connection before the server stops.
    drop(rx);
    rt.shutdown_background();
    tally
}

/// After a shutdown, the port stops accepting connections (the server thread winds down on
/// its own, so poll; the deadline only turns a hang into a failure).
fn assert_stops_listening(addr: SocketAddr) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_ok() {
        assert!(
            Instant::now() < deadline,
            "{addr} still accepts connections"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn loopback_any_port() -> ServeOptions {
    ServeOptions {
        addr: SocketAddr::from((Ipv4Addr::LOCALHOST, 0)),
        ..ServeOptions::default()
    }
}

fn env(terrain: Terrain) -> VecEnv {
    VecEnv::new(
        Arc::new(RobotModel::go2()),
        TaskConfig::embedded_default(),
        Arc::new(terrain),
        VecEnvOptions {
            num_envs: 2,
            seed: 3,
            threads: 1,
            ..VecEnvOptions::default()
        },
    )
    .expect("env")
}

fn record(recorder: &mut Recorder, env: &mut VecEnv) {
    recorder.begin(env).expect("begin");
    let actions = vec![0.0; env.num_envs() * 12];
    for step in 1..=STEPS {
        env.step(&actions).expect("step");
        recorder.log_step(env, step).expect("log");
    }
}

/// The entity path as rerun prints it (a leading slash).
fn path(p: &str) -> String {
    format!("/{p}")
}

#[test]
fn rrd_file_holds_robot_steps_and_reward_series() {
    let dir = std::env::temp_dir().join(format!("unigait-record-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("rollout.rrd");
    let mut env = env(Terrain::Flat);
    let mut recorder = Recorder::to_file(&file, RecordOptions::default()).expect("file");
    record(&mut recorder, &mut env);
    assert_eq!(recorder.finish().expect("finish"), None);
    let bytes = std::fs::read(&file).expect("rrd written");
    std::fs::remove_dir_all(&dir).ok();
    let tally = decode_all(&bytes);
    check_whole_rollout(&tally.entities);
    check_layout(&tally);
    // The outcome per recorded env, logged when the recording finishes.
    for k in [0, 1] {
        assert!(
            tally.entities.contains_key(&path(&entity::outcome(k))),
            "env {k}"
        );
    }
}

/// What is missing from a whole rollout: the robot's bodies with one pose per step (step 0,
/// the initial state, plus one per policy step) and static shapes, every reward series (one
/// row per step), the per-step series, the static scene. Empty when it is all there.
fn rollout_gaps(entities: &BTreeMap<String, EntityRows>) -> Vec<String> {
    let mut gaps = Vec::new();
    let mut expect = |what: String, ok: bool| {
        if !ok {
            gaps.push(what);
        }
    };
    let steps_0_to_n = |p: &str| {
        entities.get(p).is_some_and(|e| {
            e.steps.len() as u64 == STEPS + 1
                && e.steps.first() == Some(&0)
                && e.steps.last() == Some(&(STEPS as i64))
        })
    };
    let model = RobotModel::go2();
    expect(
        format!("13+ bodies, got {}", model.bodies.len()),
        model.bodies.len() >= 13,
    );
    for body in &model.bodies {
        let p = path(&entity::body(&body.name));
        expect(format!("{p}: a pose per step"), steps_0_to_n(&p));
        let geom = format!("{p}/geom0");
        expect(
            format!("{geom}: static"),
            entities.get(&geom).is_some_and(|g| g.is_static),
        );
    }
    let mut series = vec![path(entity::REWARD_TOTAL)];
    series.extend(
        RewardTerm::ALL
            .iter()
            .map(|t| path(&entity::reward(t.name()))),
    );
    for p in series {
        // Rewards start at step 1.
        let ok = entities
            .get(&p)
            .is_some_and(|e| e.rows as u64 == STEPS && e.steps.len() as u64 == STEPS);
        expect(format!("{p}: a row per step"), ok);
    }
    for p in [
        entity::FEET,
        entity::COMMAND,
        entity::MODE,
        "contact/FL",
        "command/vx",
        "state/vx",
        "state/upright_pitch",
        // Another recorded env: its robot moves too.
        "world/envs/1/robot/base",
        "world/envs/1/feet",
    ] {
        expect(format!("{p}: a row per step"), steps_0_to_n(&path(p)));
    }
    // The gait diagram and the mode lane start at step 0 and change only when a foot does.
    for p in FOOT_NAMES
        .iter()
        .map(|f| entity::gait(f))
        .chain([entity::GAIT_MODE.to_string()])
    {
        expect(
            format!("{p}: state changes from step 0"),
            entities.get(&path(&p)).is_some_and(|e| {
                e.steps.first() == Some(&0) && e.components.iter().any(|c| c.contains("state"))
            }),
        );
    }
    expect(
        "the active mode's terms".into(),
        entities
            .keys()
            .any(|k| k.starts_with(&path(entity::REWARD_ACTIVE))),
    );

    for p in [entity::TERRAIN, entity::WORLD, "world/envs/1/terrain"] {
        expect(
            format!("{p}: static"),
            entities.get(&path(p)).is_some_and(|e| e.is_static),
        );
    }
    gaps
}

fn check_whole_rollout(entities: &BTreeMap<String, EntityRows>) {
    let gaps = rollout_gaps(entities);
    assert!(gaps.is_empty(), "missing: {gaps:#?}");
}

#[test]
fn in_memory_recording_on_stairs_returns_rrd_bytes() {
    let spec = TerrainSpec {
        kind: TerrainKind::Pinned {
            terrain_type: TerrainType::StairsDown,
            level: 0,
        },
        num_levels: 1,
        types: vec![TerrainType::StairsDown],
        step_height: [0.15, 0.15],
        ..TerrainSpec::default()
    };
    let mut env = env(Terrain::from_spec(&spec, 1).expect("terrain"));
    let options = RecordOptions {
        env_index: 1,
        ..RecordOptions::default()
    };
    let mut recorder = Recorder::in_memory(options).expect("memory");
    record(&mut recorder, &mut env);
    let bytes = recorder.finish().expect("finish").expect("bytes");
    assert!(bytes.len() > 10_000, "rrd of {} bytes", bytes.len());
    let entities = decode(&bytes);
    assert!(entities[&path(entity::TERRAIN)].is_static);
    let trunk = &entities[&path(&entity::body(&RobotModel::go2().bodies[0].name))];
    assert_eq!(trunk.steps.len() as u64, STEPS + 1);
}

#[test]
fn an_env_outside_the_batch_is_an_error() {
    let env = env(Terrain::Flat);
    let options = RecordOptions {
        env_index: 5,
        ..RecordOptions::default()
    };
    let mut recorder = Recorder::in_memory(options).expect("memory");
    let err = recorder.begin(&env).expect_err("refused");
    assert!(
        err.to_string().contains("env 5 is not in the batch of 2"),
        "{err}"
    );
}

#[test]
fn a_served_recording_reaches_a_viewer_joining_after_the_rollout() {
    let mut env = env(Terrain::Flat);
    let mut recorder =
        Recorder::serve(&loopback_any_port(), RecordOptions::default()).expect("serve");
    let url = recorder.serve_url().expect("served");
    record(&mut recorder, &mut env);
    // An end marker after everything else (the flush orders it last): the stream has no end
    // of its own, and the rollout's last chunks may come in any order.
    recorder.stream().flush_blocking().expect("flush");
    recorder
        .stream()
        .log(END, &rerun::TextLog::new("end"))
        .expect("end marker");
    let served = recorder.finish_serving().expect("keep serving");
    let addr = served.addr();
    assert!(addr.ip().is_loopback() && addr.port() != 0, "{addr}");
    assert_eq!(url, format!("rerun+http://127.0.0.1:{}/proxy", addr.port()));
    assert_eq!(served.url(), url);

    // The viewer joins only now: everything was buffered for it.
    let tally = join_as_viewer(&url, |t| t.entities.contains_key(&path(END)));
    check_whole_rollout(&tally.entities);
    // The recording and its viewer layout, which the viewer activates.
    assert_eq!(tally.store_ids.len(), 2, "{:?}", tally.store_ids);
    check_layout(&tally);

    served.shutdown().expect("clean shutdown");
    assert_stops_listening(addr);
}

#[test]
fn a_served_rrd_is_the_same_recording_for_every_viewer() {
    let mut env = env(Terrain::Flat);
    let mut recorder = Recorder::in_memory(RecordOptions::default()).expect("memory");
    record(&mut recorder, &mut env);
    let bytes = recorder.finish().expect("finish").expect("bytes");
    let from_file = decode_all(&bytes);

    let served = Served::rrd(&bytes, &loopback_any_port()).expect("serve the rrd");
    let addr = served.addr();
    // Two viewers, one after the other: the second gets everything too.
    for _ in 0..2 {
        let tally = join_as_viewer(&served.url(), |t| t.msgs == from_file.msgs);
        check_whole_rollout(&tally.entities);
        // The replay is the recording itself, not a new one wrapping it.
        assert_eq!(tally.store_ids, from_file.store_ids);
        let rows = |t: &Tally| -> Vec<(String, usize)> {
            t.entities
                .iter()
                .map(|(k, v)| (k.clone(), v.rows))
                .collect()
        };
        assert_eq!(rows(&tally), rows(&from_file));
    }
    served.shutdown().expect("clean shutdown");
    assert_stops_listening(addr);
}

#[test]
fn serving_on_a_port_in_use_is_an_error() {
    let taken = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).expect("a port");
    let options = ServeOptions {
        addr: taken.local_addr().expect("addr"),
        ..ServeOptions::default()
    };
    let err = Recorder::serve(&options, RecordOptions::default()).expect_err("in use");
    assert!(matches!(err, RecordError::Serve { .. }), "{err}");
    let mut recorder = Recorder::in_memory(RecordOptions::default()).expect("memory");
    recorder.begin(&env(Terrain::Flat)).expect("begin");
    let bytes = recorder.finish().expect("finish").expect("bytes");
    let err = Served::rrd(&bytes, &options).expect_err("in use");
    assert!(err.to_string().contains("in use"), "{err}");
    let err = Served::rrd(b"not an rrd", &loopback_any_port()).expect_err("invalid");
    assert!(matches!(err, RrdError::InvalidRrd(_)), "{err}");
    let not_served = Recorder::in_memory(RecordOptions::default()).expect("memory");
    assert!(matches!(
        not_served.finish_serving(),
        Err(RecordError::NotServed)
    ));
}

/// The viewer layout came with the recording: a blueprint store with views and an activation.
fn check_layout(tally: &Tally) {
    assert_eq!(tally.activations, 1, "one blueprint activation");
    assert!(
        tally.blueprint.contains_key("/viewport"),
        "{:?}",
        tally.blueprint.keys()
    );
    let views = tally
        .blueprint
        .iter()
        .filter(|(_, e)| e.components.iter().any(|c| c.contains("class_identifier")))
        .count();
    // 2 recorded envs (2 tabs of 3D) + events + velocity + posture + gait + reward.
    assert_eq!(views, 7, "{:#?}", tally.blueprint.keys());
    assert!(
        tally
            .blueprint
            .keys()
            .any(|k| k.ends_with("/EyeControls3D")),
        "a camera that follows the robot"
    );
}

/// What the recording holds at `p` or under it.
fn exists_in(entities: &BTreeMap<String, EntityRows>, p: &str) -> bool {
    let p = path(p);
    entities.contains_key(&p) || entities.keys().any(|k| k.starts_with(&format!("{p}/")))
}

#[test]
fn the_layout_names_entities_the_recording_has() {
    let mut env = env(Terrain::Flat);
    let mut recorder = Recorder::in_memory(RecordOptions::default()).expect("memory");
    let layout = recorder.layout(&env).expect("layout");
    record(&mut recorder, &mut env);
    let tally = decode_all(&recorder.finish().expect("finish").expect("bytes"));
    check_layout(&tally);
    let named = layout.named_entities();
    for p in [
        "world/robot/base/geom0",
        "world/envs/1/robot/base/geom0",
        "gait",
        "reward/total",
        "reward/active",
        "state/pitch",
        "state/upright_pitch",
        "command/vx",
        "events",
    ] {
        assert!(named.contains(p), "the layout shows {p}: {named:#?}");
    }
    let missing: Vec<&String> = named
        .iter()
        .filter(|p| !exists_in(&tally.entities, p))
        .collect();
    assert!(missing.is_empty(), "named but not recorded: {missing:?}");
    // The per-term series stay in the store without a view of their own.
    assert!(exists_in(&tally.entities, &entity::reward("torques")));
    assert!(!named.contains(&entity::reward("torques")));
}

#[test]
fn robot_links_carry_no_labels_and_feet_have_none() {
    let mut env = env(Terrain::Flat);
    let mut recorder = Recorder::in_memory(RecordOptions::default()).expect("memory");
    record(&mut recorder, &mut env);
    let tally = decode_all(&recorder.finish().expect("finish").expect("bytes"));
    let world = path(entity::WORLD);
    let labelled: Vec<&String> = tally
        .entities
        .iter()
        .filter(|(k, e)| k.starts_with(&world) && e.components.iter().any(|c| c.contains("labels")))
        .map(|(k, _)| k)
        .collect();
    assert!(labelled.is_empty(), "labels on {labelled:?}");
    // Colours by link group: the shapes carry colours.
    let thigh = &tally.entities[&path(&format!("{}/geom0", entity::body("FL_thigh")))];
    assert!(
        thigh.components.iter().any(|c| c.contains("colors")),
        "{thigh:?}"
    );
}

#[test]
fn one_env_only_when_asked() {
    let mut env = env(Terrain::Flat);
    let options = RecordOptions {
        max_envs: 1,
        ..RecordOptions::default()
    };
    let mut recorder = Recorder::in_memory(options).expect("memory");
    let layout = recorder.layout(&env).expect("layout");
    assert_eq!(
        layout
            .views()
            .iter()
            .filter(|v| v.kind == unigait_record::blueprint::ViewKind::Spatial3D)
            .count(),
        1
    );
    record(&mut recorder, &mut env);
    let tally = decode_all(&recorder.finish().expect("finish").expect("bytes"));
    assert!(!exists_in(&tally.entities, entity::OTHER_ENVS));
}
