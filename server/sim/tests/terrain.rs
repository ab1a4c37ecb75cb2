//! The curriculum terrain: its shapes against the generator's analytic geometry, robots resting
//! on every tile in rapier, the curriculum rule, and (ignored) a speed benchmark.

mod common;

use std::sync::Arc;
use std::time::Instant;

use common::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::math::{Pose, Rotation, Vec3};
use unigait_sim::physics::{
    EngineKind, PhysicsParams, PhysicsWorld, RobotPhysicalParams, RobotState, RobotWorld,
};
use unigait_sim::prelude::*;
use unigait_sim::terrain::{
    EpisodeDistance, LevelRule, TerrainCollider, TerrainKind, TerrainSpec, TerrainType,
};

/// A curriculum spec whose deterministic spawn tiles cover levels `0..=max_init_level`.
fn curriculum(max_init_level: u32) -> TerrainSpec {
    TerrainSpec {
        kind: TerrainKind::Curriculum { max_init_level },
        ..TerrainSpec::default()
    }
}

fn batch_on(terrain: Terrain, config: TaskConfig, n: usize, seed: u64) -> VecEnv {
    let options = VecEnvOptions {
        num_envs: n,
        seed,
        threads: 1,
        physics_only: false,
        autoreset: true,
    };
    VecEnv::new(
        Arc::new(RobotModel::go2()),
        config,
        Arc::new(terrain),
        options,
    )
    .expect("batch builds")
}

/// Step `env` with zero actions for `steps` policy steps; panic on any termination.
fn stand(env: &mut VecEnv, steps: usize) {
    let zeros = vec![0.0; env.num_envs() * NUM_JOINTS];
    for step in 0..steps {
        let out = env.step(&zeros).expect("step");
        if let Some(i) = out.terminated.iter().position(|t| *t != 0) {
            let o = env.env_state(i).origin;
            panic!("env {i} (spawned at {o:?}) terminated at step {step}");
        }
    }
}

/// The base height above the terrain under it, for every env.
fn base_heights(env: &VecEnv) -> Vec<f32> {
    (0..env.num_envs())
        .map(|i| {
            let p = env.robot_state(i).base_pos;
            p.z - env.terrain().height(p.x, p.y)
        })
        .collect()
}

/// A robot standing (zero actions, 2 s) on the spawn platform of every tile of every level rests
/// there: no termination, base 0.2-0.35 m above the terrain under it (so above the terrain).
#[test]
fn robots_rest_on_every_tile() {
    for terrain_type in TerrainType::ALL {
        for level in 0..10 {
            // A one-column grid with every env on tile (level, 0).
            let spec = TerrainSpec {
                kind: TerrainKind::Pinned {
                    terrain_type,
                    level,
                },
                types: vec![terrain_type],
                ..TerrainSpec::default()
            };
            let terrain = Terrain::from_spec(&spec, 3).expect("terrain");
            let origin = terrain.grid().expect("grid").tile_origin(level, 0);
            let mut env = batch_on(terrain, calm_config(""), 2, 0);
            stand(&mut env, 100);
            for (i, h) in base_heights(&env).into_iter().enumerate() {
                let p = env.robot_state(i).base_pos;
                assert!(
                    (0.2..=0.35).contains(&h),
                    "{terrain_type} level {level}: base {h} m above the terrain"
                );
                assert!(
                    (p.truncate() - origin.truncate()).length() < 0.1,
                    "{terrain_type} level {level}: spawned at {p:?}, tile origin {origin:?}"
                );
            }
            assert!(env.max_joint_gap() < 5e-3);
        }
    }
}

/// World positions of the feet' centres with the trunk at `base` and joints at `q`.
fn feet_at(model: &RobotModel, q: &[f32; NUM_JOINTS], base: Pose) -> [Vec3; 4] {
    let local = model.forward_kinematics(q);
    model
        .feet
        .each_ref()
        .map(|f| (base * local[f.body]).transform_point(f.offset))
}

/// The trunk pose at (`x`, `y`) heading `yaw`, nose up by `pitch`, lowered until the lowest foot
/// (joints at `q`) is 5 mm above the terrain under it.
fn placed_on(
    terrain: &Terrain,
    model: &RobotModel,
    q: &[f32; NUM_JOINTS],
    x: f32,
    y: f32,
    yaw: f32,
    pitch: f32,
) -> Pose {
    let rot = Rotation::from_rotation_z(yaw) * Rotation::from_rotation_y(-pitch);
    let clearance = |base: Pose| {
        feet_at(model, q, base)
            .iter()
            .zip(&model.feet)
            .map(|(p, f)| p.z - f.radius - terrain.height(p.x, p.y))
            .fold(f32::INFINITY, f32::min)
    };
    let probe = Pose::from_parts(Vec3::new(x, y, 5.0), rot);
    let z = 5.0 - clearance(probe) + 0.005;
    Pose::from_parts(Vec3::new(x, y, z), rot)
}

/// A robot placed on tile (`terrain_type`, `level`) at `base_x_in_tile` along the tile's centre
/// line, heading `yaw` and pitched nose-up by `pitch`, held at the default pose for 2.5 s directly in
/// a physics world: it comes to rest with every foot loaded on the tread (or face) it was put on
/// and the trunk clear of the terrain, no foot more than `max_drop` (m) lower than it started.
fn rest_on_tile(
    terrain_type: TerrainType,
    level: u32,
    base_x_in_tile: f32,
    yaw: f32,
    pitch: f32,
    max_drop: f32,
) {
    let spec = curriculum(9);
    let terrain = Terrain::from_spec(&spec, 3).expect("terrain");
    let model = RobotModel::go2();
    let mut world = RobotWorld::new(&model, 1, terrain.collider(), &PhysicsParams::default());
    let q0: [f32; NUM_JOINTS] = std::array::from_fn(|j| model.config.default_joint_pos[j]);
    let column = spec.column_of(terrain_type).expect("on the grid") as f32;
    let (x, y) = (level as f32 * 8.0 + base_x_in_tile, (column + 0.5) * 8.0);
    let base = placed_on(&terrain, &model, &q0, x, y, yaw, pitch);
    world.set_robot_state(&model, 0, base, Vec3::ZERO, Vec3::ZERO, &q0);
    let start = feet_at(&model, &q0, base);
    let actuators = [RobotPhysicalParams::nominal(&model).actuator];
    let mut torques = [0.0; NUM_JOINTS];
    let mut states = [RobotState::default()];
    for _ in 0..500 {
        world.step(&model, &q0, &actuators, &mut torques);
        world.read_states(&model, &mut states);
        assert_eq!(
            states[0].trunk_force, 0.0,
            "{terrain_type}: the trunk touched"
        );
    }
    let s = &states[0];
    assert!(
        s.base_linvel.length() < 0.02,
        "{terrain_type}: moving at {:?}",
        s.base_linvel
    );
    for (f, (p, p0)) in s.foot_pos.iter().zip(&start).enumerate() {
        let gap = p.z - model.feet[f].radius - terrain.height(p.x, p.y);
        assert!(
            gap.abs() < 5e-3,
            "{terrain_type}: foot {f} {gap} m off its ground"
        );
        // The robot settles into its soft (kp 20) stance, which draws the feet in a little, but
        // no foot slips down a step (or far down a face).
        let drop = terrain.height(p.x, p.y) - terrain.height(p0.x, p0.y);
        assert!(
            drop.abs() < max_drop,
            "{terrain_type}: foot {f} moved {drop} m down"
        );
        assert!(
            s.foot_force[f] > 1.0,
            "{terrain_type}: foot {f} carries nothing"
        );
    }
    assert!(s.max_joint_gap < 5e-3);
}

/// Climbing across a 0.15 m stair edge (level 6) of both staircases, the front feet 0.2 m onto
/// the upper tread and the rear feet on the tread below, and climbing an 18.5 deg slope face
/// (level 4).
#[test]
fn robots_rest_across_stair_edges_and_on_slopes() {
    use std::f32::consts::PI;
    let step = TerrainSpec::default().step_height_at(6);
    // Feet 0.448 m apart front to rear, the front ones 0.176 m ahead of the base.
    let lean = (step / 0.448).atan();
    // Stairs down (a hill): from the tile's -x edge inwards is up; the riser at 0.9 m.
    rest_on_tile(
        TerrainType::StairsDown,
        6,
        0.9 + 0.2 - 0.176,
        0.0,
        lean,
        0.02,
    );
    // Stairs up (a pit): outwards is up; facing -x, the riser at 0.9 m.
    rest_on_tile(TerrainType::StairsUp, 6, 0.9 - 0.2 + 0.176, PI, lean, 0.02);
    // The hill's -x face at level 4: settling draws the front feet back down the face.
    let slope = TerrainSpec::default().slope(4).atan();
    rest_on_tile(TerrainType::SlopeDown, 4, 1.5, 0.0, slope, 0.08);
}

/// Table V's low end (0.2) on the 18.5 deg face (level 4), facing up it at the default pose: once
/// settled (1 s), over the next second in each engine the robot stays put when the coefficient
/// is averaged with the ground's 1.0 (0.6 > tan 18.5 deg = 0.33) and slides down the face when
/// it is the contact's own (0.2). Measured: 3-16 mm against 0.72-0.73 m.
#[test]
fn table_v_low_friction_holds_a_slope_only_averaged_with_the_ground() {
    use unigait_sim::task::{FrictionCombine, Randomization, RandomizationParams};
    const LEVEL: u32 = 4;
    let spec = curriculum(9);
    let terrain = Terrain::from_spec(&spec, 3).expect("terrain");
    let model = RobotModel::go2();
    let slope = spec.slope(LEVEL).atan();
    let column = spec.column_of(TerrainType::SlopeDown).expect("on the grid") as f32;
    // The hill's -x face, facing +x (uphill), 1.5 m in from the tile's edge, as below.
    let (x, y) = (LEVEL as f32 * 8.0 + 1.5, (column + 0.5) * 8.0);
    let q0: [f32; NUM_JOINTS] = std::array::from_fn(|j| model.config.default_joint_pos[j]);
    let base = placed_on(&terrain, &model, &q0, x, y, 0.0, slope);
    let drawn = Randomization {
        friction: 0.2,
        ..Randomization::nominal(&model.config)
    };
    for engine in [EngineKind::Articulated, EngineKind::Rapier] {
        let mut slid = [0.0; 2];
        for (rule, out) in [FrictionCombine::Average, FrictionCombine::Multiply]
            .into_iter()
            .zip(&mut slid)
        {
            let ranges = RandomizationParams {
                friction_combine: rule,
                ..RandomizationParams::default()
            };
            let params = PhysicsParams {
                engine,
                ..PhysicsParams::default()
            };
            let mut world = PhysicsWorld::new(&model, 1, &terrain, &params);
            let physical = drawn.physical_params(&model.config, &ranges);
            world.set_physical_params(&model, 0, &physical);
            world.set_robot_state(&model, 0, base, Vec3::ZERO, Vec3::ZERO, &q0);
            let actuators = [physical.actuator];
            let mut torques = [0.0; NUM_JOINTS];
            let mut states = [RobotState::default()];
            let mut at = [Vec3::ZERO; 2];
            for (steps, p) in [200, 200].into_iter().zip(&mut at) {
                for _ in 0..steps {
                    world.step(&model, &q0, &actuators, &mut torques);
                }
                world.read_states(&model, &mut states);
                *p = states[0].base_pos;
            }
            *out = (at[1] - at[0]).length();
        }
        let [averaged, own] = slid;
        assert!(
            averaged < 0.03,
            "{engine:?}: slid {averaged} m in 1 s at 0.6"
        );
        assert!(own > 0.3, "{engine:?}: slid only {own} m in 1 s at 0.2");
    }
}

/// The public queries on a generated grid: a 30 degree face (level 7), a 0.15 m stair edge
/// (level 6), the highest point within a radius, determinism.
#[test]
fn grid_queries_through_the_terrain() {
    let spec = curriculum(5);
    let terrain = Terrain::from_spec(&spec, 3).expect("terrain");
    let grid = terrain.grid().expect("a grid");
    let column = |t| spec.column_of(t).expect("on the grid") as f32;
    // Level 7 hill, 2 m from the centre along +x: atan(7/9 tan 37 deg) = 30.37 degrees.
    let (x, y) = (
        7.0 * 8.0 + 6.0,
        (column(TerrainType::SlopeDown) + 0.5) * 8.0,
    );
    let tilt = terrain.normal(x, y).z.acos().to_degrees();
    assert!((tilt - 30.37).abs() < 0.01, "tilt {tilt}");
    // Level 6 stairs: 0.15 m steps, the third riser 0.9 m in from the tile edge.
    let (x, y) = (
        6.0 * 8.0 + 0.9,
        (column(TerrainType::StairsDown) + 0.5) * 8.0,
    );
    let rise = terrain.height(x + 1e-3, y) - terrain.height(x - 1e-3, y);
    assert!((rise - 0.15).abs() < 1e-5, "rise {rise}");
    assert_eq!(terrain.height(x - 0.15, y), terrain.height(x - 0.05, y));
    // 2 cm before the riser: a 3 cm radius sees the upper tread, a 1 cm one does not.
    let lower = terrain.height(x - 0.02, y);
    assert!((terrain.max_height_within(x - 0.02, y, 0.03) - (lower + 0.15)).abs() < 1e-5);
    assert_eq!(terrain.max_height_within(x - 0.02, y, 0.01), lower);
    // Same seed, same terrain; the flat kind is the half-space.
    assert_eq!(Terrain::from_spec(&spec, 3).expect("terrain"), terrain);
    assert!(grid.tile_origin(0, 0).z.abs() < 1e-6);
    assert_eq!(
        Terrain::from_spec(&TerrainSpec::default(), 3).expect("flat"),
        Terrain::Flat
    );
}

/// The curriculum through the public API: up after more than 70 % of the commanded distance
/// (and 2 m), down after less than half of it, unchanged on pinned tiles.
#[test]
fn curriculum_levels_move_by_the_rule() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let ep = |walked, commanded| EpisodeDistance {
        walked,
        commanded,
        commanded_biped: 0.0,
        walked_biped: 0.0,
        ..EpisodeDistance::default()
    };
    let rule = LevelRule::default();
    let terrain = Terrain::from_spec(&curriculum(5), 0).expect("terrain");
    let grid = terrain.grid().expect("a grid");
    assert_eq!(grid.next_level(4, ep(7.5, 10.0), &rule, &mut rng), 5);
    assert_eq!(grid.next_level(4, ep(4.5, 10.0), &rule, &mut rng), 3);
    assert_eq!(grid.next_level(4, ep(3.0, 5.0), &rule, &mut rng), 4);
    assert_eq!(grid.next_level(0, ep(0.0, 10.0), &rule, &mut rng), 0);
    assert!(grid.next_level(9, ep(5.0, 5.0), &rule, &mut rng) < 10);
    assert!(Terrain::Flat.grid().is_none(), "flat ground has no levels");
    let pinned = TerrainSpec {
        kind: TerrainKind::Pinned {
            terrain_type: TerrainType::StairsUp,
            level: 5,
        },
        ..TerrainSpec::default()
    };
    let pinned = Terrain::from_spec(&pinned, 0).expect("terrain");
    let tile = pinned.grid().expect("a grid");
    assert_eq!(tile.next_level(5, ep(7.5, 10.0), &rule, &mut rng), 5);
    assert_eq!(pinned.initial_tile(0, 10, &mut rng), (5, 4));
}

/// One full episode (18 s) of a standing policy (zero actions) under the training config's
/// commands, pushes and randomisation, on the curriculum (levels 0-5): no env is promoted.
/// Envs that end up lying down or standing under a non-zero command are demoted (those above
/// level 0). `UNIGAIT_CURRICULUM_ENVS` sets the batch (default 32; 1024 for the report).
#[test]
fn a_standing_policy_is_never_promoted() {
    let n: usize = std::env::var("UNIGAIT_CURRICULUM_ENVS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(32);
    let config = TaskConfig::embedded_default()
        .with_overrides("[env]\nrandom_initial_episode_step = false")
        .expect("config");
    let grid = Terrain::from_spec(&curriculum(5), 1).expect("terrain");
    let mut env = batch_on(grid, config, n, 1);
    let start: Vec<u32> = (0..n).map(|i| env.env_state(i).terrain_level).collect();
    let mut after: Vec<Option<u32>> = vec![None; n];
    let zeros = vec![0.0; n * NUM_JOINTS];
    for _ in 0..900 {
        let dones: Vec<bool> = {
            let out = env.step(&zeros).expect("step");
            (0..n)
                .map(|i| out.terminated[i] != 0 || out.truncated[i] != 0)
                .collect()
        };
        for i in 0..n {
            if dones[i] && after[i].is_none() {
                after[i] = Some(env.env_state(i).terrain_level);
            }
        }
    }
    let ended: Vec<(u32, u32)> = start
        .iter()
        .zip(&after)
        .filter_map(|(&s, a)| a.map(|a| (s, a)))
        .collect();
    let up = ended.iter().filter(|(s, a)| a > s).count();
    let down = ended.iter().filter(|(s, a)| a < s).count();
    let floor = ended.iter().filter(|(s, _)| *s == 0).count();
    println!(
        "{n} envs, {} episodes ended: {up} promoted, {down} demoted, {} kept ({floor} at level 0)",
        ended.len(),
        ended.len() - up - down
    );
    assert_eq!(
        ended.len(),
        n,
        "every env ends its first episode within 18 s"
    );
    assert_eq!(up, 0);
    assert!(down > 0);
}

/// The task config's `[terrain_curriculum]` is the rule the envs move by: with both demotion
/// lines at 0 only an env that drifted against its command (walked < 0) goes down, where the
/// default lines send most standing envs down. Bad values are refused, named by their field.
#[test]
fn the_task_configs_curriculum_rule_moves_the_envs() {
    let n = 16;
    let demoted = |rule: &str| {
        let config = TaskConfig::embedded_default()
            .with_overrides(&format!(
                "[env]\nrandom_initial_episode_step = false\n{rule}"
            ))
            .expect("config");
        let grid = Terrain::from_spec(&curriculum(5), 1).expect("terrain");
        let mut env = batch_on(grid, config, n, 1);
        let start: Vec<u32> = (0..n).map(|i| env.env_state(i).terrain_level).collect();
        let zeros = vec![0.0; n * NUM_JOINTS];
        let mut after: Vec<Option<u32>> = vec![None; n];
        for _ in 0..900 {
            let out = env.step(&zeros).expect("step");
            let ended: Vec<bool> = (0..n)
                .map(|i| out.terminated[i] != 0 || out.truncated[i] != 0)
                .collect();
            for i in 0..n {
                if ended[i] && after[i].is_none() {
                    after[i] = Some(env.env_state(i).terrain_level);
                }
            }
        }
        assert!(after.iter().all(Option::is_some), "every env ends in 18 s");
        (0..n).filter(|&i| after[i] < Some(start[i])).count()
    };
    let by_default = demoted("");
    let lenient = demoted("[terrain_curriculum]\ndemote_share = 0.0\ndemote_share_biped = 0.0");
    println!("standing, demoted of {n}: {by_default} by default, {lenient} with the lines at 0");
    assert!(lenient < by_default, "{lenient} !< {by_default}");
    for (text, field) in [
        (
            "[terrain_curriculum]\npromote_share_biped = 1.5",
            "promote_share_biped",
        ),
        (
            "[terrain_curriculum]\ndemote_share_biped = 0.9",
            "demote_share_biped",
        ),
        ("[terrain_curriculum]\npromote_line = 0.5", "promote_line"),
    ] {
        let err = TaskConfig::embedded_default()
            .with_overrides(text)
            .expect_err(text)
            .to_string();
        assert!(err.contains(field), "{text}: {err}");
    }
}

/// The terrain called `name`: `flat`, `trimesh` or `heightfield:<subdivisions>`, on a
/// curriculum grid spawning on levels `0..=max_init_level`, or on the one tile of `pinned`
/// (`<type>:<level>`) if given.
fn bench_terrain(name: &str, max_init_level: u32, pinned: Option<&str>) -> Terrain {
    if name == "flat" {
        return Terrain::Flat;
    }
    let mut spec = curriculum(max_init_level);
    if let Some((terrain_type, level)) = pinned.and_then(|p| p.split_once(':')) {
        spec.kind = TerrainKind::Pinned {
            terrain_type: TerrainType::from_name(terrain_type).expect("terrain type"),
            level: level.parse().expect("level"),
        };
    }
    if let Some(("heightfield", k)) = name.split_once(':') {
        spec.collider = TerrainCollider::Heightfield {
            subdivisions: k.parse().expect("subdivisions"),
        };
    }
    Terrain::from_spec(&spec, 1).expect("terrain")
}

/// Env steps per second of 512 envs on one thread under random actions (as `unigait-server
/// bench`: 20 warm-up steps, then 200 timed), and the worst joint gap, for each terrain of
/// `UNIGAIT_TERRAINS` (comma-separated names of [`bench_terrain`], default `flat,trimesh`).
/// The batches are stepped in turns of 10 steps, so load from other processes hits them alike.
/// `UNIGAIT_MAX_INIT_LEVEL` sets the highest spawn level (default 9: every level);
/// `UNIGAIT_PINNED=<type>:<level>` puts every env on one tile.
/// Run: `cargo test --release -p unigait-sim --test terrain -- --ignored --nocapture bench`.
#[test]
#[ignore]
fn bench_terrain_speed() {
    let names = std::env::var("UNIGAIT_TERRAINS").unwrap_or_else(|_| "flat,trimesh".into());
    let max_init_level = std::env::var("UNIGAIT_MAX_INIT_LEVEL")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(9);
    let pinned = std::env::var("UNIGAIT_PINNED").ok();
    let (n, steps, turn) = (512, 200, 10);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let pool: Vec<Vec<f32>> = (0..16)
        .map(|_| {
            (0..n * NUM_JOINTS)
                .map(|_| rng.random_range(-1.0..=1.0))
                .collect()
        })
        .collect();
    struct Run {
        name: String,
        env: VecEnv,
        gap: f32,
        wall: f64,
        cpu: f64,
    }
    let mut runs: Vec<Run> = names
        .split(',')
        .map(|name| {
            let built = Instant::now();
            let terrain = bench_terrain(name, max_init_level, pinned.as_deref());
            println!(
                "{name}: terrain built in {:.2} s",
                built.elapsed().as_secs_f64()
            );
            let mut env = batch_on(terrain, TaskConfig::embedded_default(), n, 1);
            let mut gap: f32 = 0.0;
            for i in 0..20 {
                env.step(&pool[i % pool.len()]).expect("step");
                gap = gap.max(env.max_joint_gap());
            }
            Run {
                name: name.to_owned(),
                env,
                gap,
                wall: 0.0,
                cpu: 0.0,
            }
        })
        .collect();
    for first in (0..steps).step_by(turn) {
        for run in &mut runs {
            let (start, cpu_start) = (Instant::now(), process_cpu_seconds());
            for i in first..first + turn {
                run.env.step(&pool[i % pool.len()]).expect("step");
                run.gap = run.gap.max(run.env.max_joint_gap());
            }
            run.wall += start.elapsed().as_secs_f64();
            run.cpu += process_cpu_seconds() - cpu_start;
        }
    }
    for run in &runs {
        println!(
            "{{\"terrain\":\"{}\",\"pinned\":\"{}\",\"max_init_level\":{max_init_level},\"env_steps_per_sec_per_thread\":{:.0},\"env_steps_per_cpu_sec\":{:.0},\"max_joint_gap_m\":{:.5},\"nonfinite_resets\":{}}}",
            run.name,
            pinned.as_deref().unwrap_or(""),
            (n * steps) as f64 / run.wall,
            (n * steps) as f64 / run.cpu,
            run.gap,
            run.env.nonfinite_resets()
        );
    }
}

/// CPU time of this process so far (s), from /proc (0 where unavailable): steadier than wall
/// time on a shared machine.
fn process_cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the command name (which may hold spaces) start after the last ')'.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    // utime and stime are fields 14 and 15 of the line: 11 and 12 counted from the state.
    let ticks: f64 = [11, 12]
        .iter()
        .filter_map(|&k| fields.get(k).and_then(|v| v.parse::<f64>().ok()))
        .sum();
    ticks / 100.0
}

/// Decision record 0036: with a level per mode, each episode starts on the tile of its first
/// mode's level, and only what the robot walked in that mode moves that level. Robots stand
/// still (zero actions) from level 8 through 1 s episodes whose mode is redrawn every 0.1 s:
/// four legs are commanded nothing, two legs 0.5 m/s. An episode started on two legs walked
/// under half of what its biped part asked and demotes the biped's level; one started on four
/// legs was asked nothing on four legs and keeps the quad's level, though judged as a whole it
/// would be demoted for its biped part.
#[test]
fn each_mode_keeps_its_own_level() {
    let cfg = TaskConfig::embedded_default()
        .with_overrides(
            "[terrain_curriculum]\nper_mode_levels = true\n\
             [env]\nepisode_length_s = 1.0\nrandom_initial_episode_step = false\n\
             [modes]\nresampling_time_s = 0.1\n\
             [commands]\nresampling_time_s = 600.0\nzero_below = 0.0\n\
             quad = { vx = [0.0, 0.0], vy = [0.0, 0.0], wz = [0.0, 0.0] }\n\
             biped = { vx = [0.5, 0.5], vy = [0.0, 0.0], wz = [0.0, 0.0] }\n\
             [init]\nlinvel = [0.0, 0.0]\nangvel = [0.0, 0.0]\npitch = [0.0, 0.0]\n\
             thigh = [0.0, 0.0]\ncalf = [0.0, 0.0]\nhip = [0.0, 0.0]\n",
        )
        .expect("config");
    let n = 16;
    let terrain = Terrain::from_spec(&curriculum(9), 0)
        .expect("terrain")
        .with_initial_levels(vec![8; n])
        .expect("levels");
    let mut env = batch_on(terrain, cfg, n, 4);
    let zeros = vec![0.0; n * NUM_JOINTS];
    let slot = |m: TaskMode| usize::from(m == TaskMode::Biped);
    // Biped-started episodes per env.
    let mut biped_started: Vec<u32> = (0..n)
        .map(|i| {
            let e = env.env_state(i);
            assert_eq!(e.mode_levels, [8, 8]);
            u32::from(e.episode_mode == TaskMode::Biped)
        })
        .collect();
    let (mut episodes, mut switches) = (0, 0);
    for _ in 0..6 * 50 {
        let before: Vec<_> = (0..n).map(|i| env.env_state(i).clone()).collect();
        let out = env.step(&zeros).expect("step").clone();
        for (i, b) in before.iter().enumerate() {
            let e = env.env_state(i);
            assert_eq!(
                e.terrain_level,
                e.mode_levels[slot(e.episode_mode)],
                "env {i}"
            );
            assert_eq!(out.terminated[i], 0, "env {i} fell");
            if out.truncated[i] == 0 {
                assert_eq!(e.mode_levels, b.mode_levels, "env {i} moved mid-episode");
                switches += usize::from(e.mode != b.mode);
                continue;
            }
            episodes += 1;
            let expected = match b.episode_mode {
                TaskMode::Biped => [b.mode_levels[0], b.mode_levels[1] - 1],
                TaskMode::Quad => b.mode_levels,
            };
            assert_eq!(e.mode_levels, expected, "env {i}");
            biped_started[i] += u32::from(e.episode_mode == TaskMode::Biped);
        }
    }
    assert!(
        episodes >= 5 * n && switches > 10 * n,
        "{episodes} episodes, {switches} switches"
    );
    // The quad's level never moved; the biped's went down once per episode it started.
    for (i, &started) in biped_started.iter().enumerate() {
        let e = env.env_state(i);
        let ended = started - u32::from(e.episode_mode == TaskMode::Biped);
        assert_eq!(e.mode_levels, [8, 8 - ended], "env {i}");
    }
    assert!(
        biped_started.iter().any(|&s| s > 1),
        "no env's biped level moved"
    );
}

/// Decision record 0038: each step adds the base's distance from its spawn point and the
/// commanded path's. Robots stand (zero actions) on four legs under 0.5 m/s forward and
/// 0.5 rad/s: after 0.8 s the commanded path is on a 1 m arc, 0.4 rad round it (a chord of
/// 2 sin 0.2 = 0.397 m from the spawn point), and the base's reach is the farthest its own
/// position got from the tile's origin, a few centimetres.
#[test]
fn each_step_adds_the_reach_of_the_base_and_of_its_commands() {
    let cfg = TaskConfig::embedded_default()
        .with_overrides(
            "[terrain_curriculum]\njudge_reach = true\n\
             [env]\nrandom_initial_episode_step = false\n\
             [modes]\nbiped_probability = 0.0\nresampling_time_s = 600.0\n\
             [commands]\nresampling_time_s = 600.0\nzero_below = 0.0\n\
             quad = { vx = [0.5, 0.5], vy = [0.0, 0.0], wz = [0.5, 0.5] }\n\
             [init]\nlinvel = [0.0, 0.0]\nangvel = [0.0, 0.0]\npitch = [0.0, 0.0]\n",
        )
        .expect("config");
    let n = 8;
    let terrain = Terrain::from_spec(&curriculum(0), 0).expect("terrain");
    let mut env = batch_on(terrain, cfg, n, 2);
    let zeros = vec![0.0; n * NUM_JOINTS];
    let mut farthest = vec![0.0f32; n];
    for _ in 0..40 {
        env.step(&zeros).expect("step");
        for (i, far) in farthest.iter_mut().enumerate() {
            let (e, s) = (env.env_state(i), env.robot_state(i));
            let offset = (s.base_pos.x - e.origin[0]).hypot(s.base_pos.y - e.origin[1]);
            *far = far.max(offset);
        }
    }
    let chord = 2.0 * 0.2f32.sin();
    for (i, &far) in farthest.iter().enumerate() {
        let reach = env.env_state(i).distance.reach;
        assert!(
            (reach.commanded[0] - chord).abs() < 0.01,
            "env {i}: {reach:?}"
        );
        assert_eq!(reach.commanded[1], 0.0, "env {i}: no biped steps");
        assert!(
            (reach.walked[0] - far).abs() < 1e-5 && far < 0.1,
            "env {i}: {reach:?}, {far}"
        );
        assert!(
            (reach.share() - far / reach.commanded[0]).abs() < 1e-4,
            "env {i}"
        );
    }
}
