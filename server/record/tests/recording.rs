//! Headless check of a recording: write a short rollout to an `.rrd` file (and to memory),
//! decode it back with rerun's own decoder, and find the robot's entities, one pose per step on
//! the `step` timeline, and every reward series.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use rerun::TimelineName;
use rerun::log::{Chunk, LogMsg};
use unigait_record::{RecordOptions, Recorder, entity};
use unigait_sim::env::{VecEnv, VecEnvOptions};
use unigait_sim::robot::RobotModel;
use unigait_sim::task::{RewardTerm, TaskConfig};
use unigait_sim::terrain::{Terrain, TerrainKind, TerrainSpec, TerrainType};

const STEPS: u64 = 25;

/// Per entity: rows logged on the `step` timeline (with their distinct step values) and
/// whether it has static data.
#[derive(Debug, Default)]
struct EntityRows {
    steps: BTreeSet<i64>,
    rows: usize,
    is_static: bool,
}

fn decode(bytes: &[u8]) -> BTreeMap<String, EntityRows> {
    let mut entities: BTreeMap<String, EntityRows> = BTreeMap::new();
    let step = TimelineName::from_static_str("step");
    for msg in re_log_encoding::DecoderApp::decode_lazy(bytes) {
        let msg = msg.expect("a valid rrd message");
        let LogMsg::ArrowMsg(_, arrow) = msg else {
            continue;
        };
        let chunk = Chunk::from_arrow_msg(&arrow).expect("a valid chunk");
        let e = entities.entry(chunk.entity_path().to_string()).or_default();
        match chunk.timelines().get(&step) {
            Some(column) => {
                e.rows += chunk.num_rows();
                e.steps.extend(column.times_raw().iter().copied());
            }
            None => e.is_static = true,
        }
    }
    entities
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
    let entities = decode(&bytes);

    let model = RobotModel::go2();
    assert!(model.bodies.len() >= 13, "bodies: {}", model.bodies.len());
    for body in &model.bodies {
        let e = entities
            .get(&path(&entity::body(&body.name)))
            .unwrap_or_else(|| panic!("no entity for body {}: {:?}", body.name, entities.keys()));
        // Step 0 (the initial state) plus one pose per step.
        assert_eq!(e.steps.len() as u64, STEPS + 1, "{}", body.name);
        assert_eq!(e.steps.first(), Some(&0));
        assert_eq!(e.steps.last(), Some(&(STEPS as i64)));
        // Its shapes are static children.
        let geom = format!("{}/geom0", path(&entity::body(&body.name)));
        assert!(
            entities.get(&geom).is_some_and(|g| g.is_static),
            "{geom} static"
        );
    }
    let total = &entities[&path(entity::REWARD_TOTAL)];
    assert_eq!(total.rows as u64, STEPS);
    assert_eq!(total.steps.len() as u64, STEPS);
    for term in RewardTerm::ALL {
        let series = entities
            .get(&path(&entity::reward(term.name())))
            .unwrap_or_else(|| panic!("no series for {}", term.name()));
        assert_eq!(series.rows as u64, STEPS, "{}", term.name());
    }
    for p in [
        entity::FEET,
        entity::COMMAND,
        entity::MODE,
        "contact/FL",
        "command/vx",
    ] {
        assert_eq!(entities[&path(p)].steps.len() as u64, STEPS + 1, "{p}");
    }
    assert!(entities[&path(entity::TERRAIN)].is_static);
    assert!(entities[&path(entity::WORLD)].is_static);
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
