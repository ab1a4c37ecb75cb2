//! Our side of the MuJoCo cross-checks (issue 13): the physics scenarios run on `RobotWorld`
//! and a dump of observations `VecEnv` built, printed as one JSON document on stdout.
//!
//! ```sh
//! cargo build --release -p unigait-crosscheck
//! ./target/release/unigait-crosscheck                      # every scenario
//! ./target/release/unigait-crosscheck stand drop           # only these
//! ./target/release/unigait-crosscheck --armature 0 stand   # physics overrides, to find causes
//! ./target/release/unigait-crosscheck --engine articulated  # the articulated engine (issue 34)
//! ```
//!
//! The Python side (`unigait.mujoco`) runs the same scenarios in MuJoCo on the same URDF and
//! compares the figures (`tests/test_mujoco_crosscheck.py`, `python -m unigait crosscheck`). It
//! finds this binary by `--binary`, `$UNIGAIT_CROSSCHECK_BIN` or `unigait-crosscheck` on PATH.
//! Every scenario echoes its parameters under `params`, so the two sides cannot drift apart
//! unnoticed. Scenarios:
//!
//! - `robot`: the model and config the physics runs (mass, gains, efforts, default pose, foot
//!   positions at the default pose, whole-body inertia as simulated);
//! - `task`: the task values the observation depends on (table of o_t, gait, action scale);
//! - `step_{hip,thigh,calf}`: one FL joint's response to a 0.3 rad target step, trunk held;
//! - `stand`: 4 s at the default pose on flat ground;
//! - `drop`: released at rest with the base at 0.5 m;
//! - `trot_forward`, `trot_backward`: 1 s standing, then 4 s of open-loop sinusoidal trot
//!   targets;
//! - `free_float_{roll,pitch}`: no gravity, free trunk, legs swung: the trunk turns;
//! - `observations`: states of a calm `VecEnv` (no randomisation, no noise) with the o_t it
//!   wrote for them.

use std::f32::consts::PI;
use std::fmt::Write as _;
use std::sync::Arc;

use rapier3d::math::{Pose, Rotation, Vec3};
use rapier3d::prelude::LockedAxes;
use unigait_sim::physics::{
    EngineKind, PhysicsParams, PhysicsWorld, RobotPhysicalParams, RobotState,
};
use unigait_sim::prelude::*;
use unigait_sim::task::{OBSERVATION, euler_pitch};

/// Minimal JSON values (written when this was an example of the sim crate, which has no
/// serde_json).
enum J {
    Num(f64),
    Str(String),
    Arr(Vec<J>),
    Obj(Vec<(String, J)>),
}

impl J {
    fn obj(fields: Vec<(&str, J)>) -> J {
        J::Obj(
            fields
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
        )
    }

    fn nums<T: Copy + Into<f64>>(values: &[T]) -> J {
        J::Arr(values.iter().map(|&v| J::Num(v.into())).collect())
    }

    fn vec3(v: Vec3) -> J {
        J::nums(&[v.x, v.y, v.z])
    }

    fn write(&self, out: &mut String) {
        match self {
            J::Num(v) if v.is_finite() => {
                let _ = write!(out, "{v}");
            }
            J::Num(_) => out.push_str("null"),
            J::Str(s) => {
                let _ = write!(out, "{s:?}");
            }
            J::Arr(items) => {
                out.push('[');
                for (i, item) in items.iter().enumerate() {
                    if i > 0 {
                        out.push(',');
                    }
                    item.write(out);
                }
                out.push(']');
            }
            J::Obj(fields) => {
                out.push('{');
                for (i, (k, v)) in fields.iter().enumerate() {
                    if i > 0 {
                        out.push(',');
                    }
                    let _ = write!(out, "{k:?}:");
                    v.write(out);
                }
                out.push('}');
            }
        }
    }
}

fn num(v: impl Into<f64>) -> J {
    J::Num(v.into())
}

/// Physics step (s), as the task runs it.
const DT: f32 = 0.005;
/// Physics steps per policy step.
const DECIMATION: usize = 4;
/// Threshold (N) above which a foot counts as touching (the task's contact threshold).
const CONTACT_N: f32 = 1.0;

/// Euler roll (XYZ convention, as legged_gym's `get_euler_xyz`).
fn euler_roll(r: Rotation) -> f32 {
    (2.0 * (r.w * r.x + r.y * r.z)).atan2(1.0 - 2.0 * (r.x * r.x + r.y * r.y))
}

/// Euler yaw (XYZ convention).
fn euler_yaw(r: Rotation) -> f32 {
    (2.0 * (r.w * r.z + r.x * r.y)).atan2(1.0 - 2.0 * (r.y * r.y + r.z * r.z))
}

fn default_q(model: &RobotModel) -> [f32; NUM_JOINTS] {
    std::array::from_fn(|j| model.config.default_joint_pos[j])
}

/// Base height that puts the lowest foot sole `gap` above z = 0 with the trunk level and the
/// joints at `q` (the feet are the lowest points at the default pose).
fn standing_base_z(model: &RobotModel, q: &[f32; NUM_JOINTS], gap: f32) -> f32 {
    let local = model.forward_kinematics(q);
    let lowest = model
        .feet
        .iter()
        .map(|f| local[f.body].transform_point(f.offset).z - f.radius)
        .fold(f32::INFINITY, f32::min);
    gap - lowest
}

/// Physics overrides from the command line (`--armature`, `--min-link-inertia`,
/// `--substeps`, `--pgs`, `--engine`), for finding the cause of a disagreement; none by default.
#[derive(Clone, Copy, Debug, Default)]
struct Overrides {
    engine: Option<EngineKind>,
    armature: Option<f32>,
    min_link_inertia: Option<f32>,
    substeps: Option<usize>,
    pgs: Option<usize>,
}

static OVERRIDES: std::sync::OnceLock<Overrides> = std::sync::OnceLock::new();

fn overrides() -> Overrides {
    OVERRIDES.get().copied().unwrap_or_default()
}

fn physics_params(gravity: f32) -> PhysicsParams {
    let o = overrides();
    let d = PhysicsParams::default();
    PhysicsParams {
        engine: o.engine.unwrap_or(d.engine),
        gravity,
        min_link_inertia: o.min_link_inertia.unwrap_or(d.min_link_inertia),
        solver_iterations: o.substeps.unwrap_or(d.solver_iterations),
        pgs_iterations: o.pgs.unwrap_or(d.pgs_iterations),
        ..d
    }
}

/// One robot in its own world, with a state buffer.
struct Rig {
    model: RobotModel,
    world: PhysicsWorld,
    params: RobotPhysicalParams,
    torques: [f32; NUM_JOINTS],
    states: [RobotState; 1],
}

impl Rig {
    fn new(gravity: f32) -> Self {
        let model = RobotModel::go2();
        let world = PhysicsWorld::new(&model, 1, &Terrain::Flat, &physics_params(gravity));
        let mut params = RobotPhysicalParams::nominal(&model);
        if let Some(a) = overrides().armature {
            params.armature = a;
        }
        Self {
            model,
            world,
            params,
            torques: [0.0; NUM_JOINTS],
            states: [RobotState::default()],
        }
    }

    fn place(&mut self, base: Pose, q: &[f32; NUM_JOINTS]) {
        self.world
            .set_robot_state(&self.model, 0, base, Vec3::ZERO, Vec3::ZERO, q);
        self.world.set_physical_params(&self.model, 0, &self.params);
        self.world.read_states(&self.model, &mut self.states);
    }

    /// One physics step towards `targets`; returns the state after it.
    fn step(&mut self, targets: &[f32; NUM_JOINTS]) -> RobotState {
        self.world.step(
            &self.model,
            targets,
            &[self.params.actuator],
            &mut self.torques,
        );
        self.world.read_states(&self.model, &mut self.states);
        self.states[0]
    }
}

fn robot_section() -> J {
    let model = RobotModel::go2();
    let c = &model.config;
    let q0 = default_q(&model);
    let local = model.forward_kinematics(&q0);
    let feet: Vec<J> = model
        .feet
        .iter()
        .map(|f| J::vec3(local[f.body].transform_point(f.offset)))
        .collect();
    let mut rig = Rig::new(0.0);
    rig.place(Pose::from_translation(Vec3::new(0.0, 0.0, 1.0)), &q0);
    // Rapier computes the bodies' mass properties in the first step.
    rig.step(&q0);
    let mass: f32 = (0..model.bodies.len())
        .map(|b| rig.world.body_mass(0, b).0)
        .sum();
    let physics = physics_params(9.81);
    J::obj(vec![
        (
            "joint_names",
            J::Arr(
                model
                    .joints
                    .iter()
                    .map(|j| J::Str(j.name.clone()))
                    .collect(),
            ),
        ),
        ("default_q", J::nums(&q0)),
        (
            "effort",
            J::nums(&model.joints.each_ref().map(|j| j.effort)),
        ),
        ("kp", num(c.kp)),
        ("kd", num(c.kd)),
        ("armature", num(rig.params.armature)),
        ("joint_damping", num(c.joint_damping)),
        ("joint_friction", num(c.joint_friction)),
        (
            "min_link_inertia",
            // The articulated engine runs the URDF's inertias, without the rapier world's floor.
            num(match physics.engine {
                EngineKind::Rapier => physics.min_link_inertia,
                EngineKind::Articulated => 0.0,
            }),
        ),
        ("dt", num(physics.dt)),
        ("mass_kg", num(mass)),
        ("foot_pos_default", J::Arr(feet)),
        (
            "foot_radius",
            J::nums(&model.feet.each_ref().map(|f| f.radius)),
        ),
        (
            "whole_body_inertia",
            J::nums(&[
                rig.world.whole_body_inertia(0, Vec3::X),
                rig.world.whole_body_inertia(0, Vec3::Y),
                rig.world.whole_body_inertia(0, Vec3::Z),
            ]),
        ),
        ("standing_base_z", num(standing_base_z(&model, &q0, 0.002))),
    ])
}

fn task_section() -> J {
    let cfg = TaskConfig::embedded_default();
    let table: Vec<J> = OBSERVATION
        .iter()
        .map(|f| {
            J::obj(vec![
                ("name", J::Str(f.name.to_string())),
                ("dim", num(f.dim as f64)),
                ("scale", J::nums(f.scale)),
            ])
        })
        .collect();
    J::obj(vec![
        ("observation", J::Arr(table)),
        ("policy_dt", num(cfg.policy_dt())),
        ("decimation", num(cfg.env.decimation as f64)),
        ("action_scale", num(cfg.env.action_scale)),
        ("clip_actions", num(cfg.env.clip_actions)),
        ("clip_observations", num(cfg.env.clip_observations)),
        ("gait_period_s", num(cfg.gait.period_s)),
        ("swing_ratio", num(cfg.gait.swing_ratio)),
        ("offsets_quad", J::nums(&cfg.gait.offsets_quad)),
        ("offsets_biped", J::nums(&cfg.gait.offsets_biped)),
        ("upright_pitch", num(cfg.rewards.upright_pitch)),
        ("episode_length_s", num(cfg.env.episode_length_s)),
    ])
}

/// Time (s) at which `trace` (sampled every `dt`, starting at t = dt) first reaches `level`
/// going up, linearly interpolated.
fn crossing_time(trace: &[f32], level: f32, start: f32, dt: f32) -> Option<f32> {
    let mut prev = start;
    for (i, &v) in trace.iter().enumerate() {
        if v >= level {
            let frac = if v > prev {
                (level - prev) / (v - prev)
            } else {
                1.0
            };
            return Some(dt * (i as f32 + frac));
        }
        prev = v;
    }
    None
}

/// Step response of joint `joint` (FL leg), trunk held level at 1 m, gravity on.
fn step_response(joint: usize) -> J {
    const STEP: f32 = 0.3;
    const STEPS: usize = 200;
    let mut rig = Rig::new(9.81);
    let q0 = default_q(&rig.model);
    rig.place(Pose::from_translation(Vec3::new(0.0, 0.0, 1.0)), &q0);
    rig.world.lock_trunk(0, LockedAxes::all());
    let mut targets = q0;
    targets[joint] += STEP;
    let trace: Vec<f32> = (0..STEPS).map(|_| rig.step(&targets).q[joint]).collect();
    let rel: Vec<f32> = trace.iter().map(|q| (q - q0[joint]) / STEP).collect();
    let tail = &trace[STEPS - 40..];
    let settled = tail.iter().sum::<f32>() / tail.len() as f32;
    let peak = rel.iter().copied().fold(f32::MIN, f32::max);
    let peak_i = rel.iter().position(|&v| v == peak).unwrap_or(0);
    let t10 = crossing_time(&rel, 0.1, 0.0, DT);
    let t90 = crossing_time(&rel, 0.9, 0.0, DT);
    J::obj(vec![
        (
            "params",
            J::obj(vec![
                ("joint", num(joint as f64)),
                ("step_rad", num(STEP)),
                ("steps", num(STEPS as f64)),
                ("trunk_height_m", num(1.0)),
            ]),
        ),
        (
            "rise_time_s",
            match (t10, t90) {
                (Some(a), Some(b)) => num(b - a),
                _ => J::Num(f64::NAN),
            },
        ),
        ("overshoot", num(peak - 1.0)),
        ("peak_time_s", num(DT * (peak_i + 1) as f32)),
        ("settled_error_rad", num(targets[joint] - settled)),
        ("q", J::nums(&trace)),
    ])
}

/// 4 s at the default pose on flat ground, feet released 2 mm above it.
fn stand() -> J {
    const STEPS: usize = 800;
    const TAIL: usize = 200;
    let mut rig = Rig::new(9.81);
    let q0 = default_q(&rig.model);
    let z0 = standing_base_z(&rig.model, &q0, 0.002);
    rig.place(Pose::from_translation(Vec3::new(0.0, 0.0, z0)), &q0);
    let (mut z, mut pitch, mut roll, mut x) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut forces = [0.0f64; NUM_FEET];
    let mut heights = Vec::new();
    let mut last = RobotState::default();
    for i in 0..STEPS {
        let s = rig.step(&q0);
        last = s;
        if i % DECIMATION == DECIMATION - 1 {
            heights.push(s.base_pos.z);
        }
        if i >= STEPS - TAIL {
            z += f64::from(s.base_pos.z);
            x += f64::from(s.base_pos.x);
            pitch += f64::from(euler_pitch(s.base_rot));
            roll += f64::from(euler_roll(s.base_rot));
            for (f, acc) in forces.iter_mut().enumerate() {
                *acc += f64::from(s.foot_force[f]);
            }
        }
    }
    let n = TAIL as f64;
    let forces = forces.map(|f| f / n);
    J::obj(vec![
        (
            "params",
            J::obj(vec![
                ("steps", num(STEPS as f64)),
                ("tail_steps", num(TAIL as f64)),
                ("initial_base_z", num(z0)),
            ]),
        ),
        ("base_height_m", num(z / n)),
        ("base_x_m", num(x / n)),
        ("pitch_rad", num(pitch / n)),
        ("roll_rad", num(roll / n)),
        ("foot_force_n", J::nums(&forces)),
        ("total_foot_force_n", num(forces.iter().sum::<f64>())),
        ("final_q", J::nums(&last.q)),
        (
            "final_foot_pos",
            J::Arr(last.foot_pos.iter().map(|p| J::vec3(*p)).collect()),
        ),
        (
            "leg_contacts",
            num(last.penalised_contacts + last.other_contacts),
        ),
        ("head_force_n", num(last.head_force)),
        ("max_joint_gap_m", num(last.max_joint_gap)),
        ("base_height_trace", J::nums(&heights)),
    ])
}

/// Released at rest, base level at 0.5 m, default joints held.
fn drop() -> J {
    const STEPS: usize = 600;
    const HEIGHT: f32 = 0.5;
    const TAIL: usize = 100;
    const BAND: f32 = 0.005;
    let mut rig = Rig::new(9.81);
    let q0 = default_q(&rig.model);
    rig.place(Pose::from_translation(Vec3::new(0.0, 0.0, HEIGHT)), &q0);
    let mut z = Vec::with_capacity(STEPS);
    let mut total = Vec::with_capacity(STEPS);
    let mut trunk_peak = 0.0f32;
    for _ in 0..STEPS {
        let s = rig.step(&q0);
        z.push(s.base_pos.z);
        total.push(s.foot_force.iter().sum::<f32>());
        trunk_peak = trunk_peak.max(s.trunk_force);
    }
    let first_contact = total.iter().position(|&f| f > CONTACT_N);
    // Impact: the total foot force averaged over each policy step (4 physics steps), which
    // smooths the solver's step-to-step split of one impulse.
    let peak_force = total
        .chunks(DECIMATION)
        .map(|c| c.iter().sum::<f32>() / c.len() as f32)
        .fold(0.0f32, f32::max);
    let final_z = z[STEPS - TAIL..].iter().sum::<f32>() / TAIL as f32;
    let settle = z
        .iter()
        .rposition(|&h| (h - final_z).abs() > BAND)
        .map_or(0.0, |i| (i + 1) as f32 * DT);
    let after = first_contact.unwrap_or(0);
    let min_z = z[after..].iter().copied().fold(f32::INFINITY, f32::min);
    let policy_z: Vec<f32> = z
        .iter()
        .skip(DECIMATION - 1)
        .step_by(DECIMATION)
        .copied()
        .collect();
    J::obj(vec![
        (
            "params",
            J::obj(vec![
                ("steps", num(STEPS as f64)),
                ("base_height_m", num(HEIGHT)),
                ("tail_steps", num(TAIL as f64)),
                ("settle_band_m", num(BAND)),
            ]),
        ),
        (
            "first_contact_s",
            first_contact.map_or(J::Num(f64::NAN), |i| num((i + 1) as f32 * DT)),
        ),
        ("peak_foot_force_n", num(peak_force)),
        ("peak_trunk_force_n", num(trunk_peak)),
        ("min_base_height_m", num(min_z)),
        ("settled_height_m", num(final_z)),
        ("settle_time_s", num(settle)),
        ("base_height_trace", J::nums(&policy_z)),
    ])
}

/// Open-loop trot targets at time `t` (s) since the gait started: per leg phase
/// theta = 2 pi t / T + (0 for FL, RR; pi for FR, RL); thigh q0 + A sin theta, calf
/// q0 + B cos(theta + `calf_phase`). The calf phase picks the direction: 5 pi / 4 walks forward,
/// pi / 2 backward (both found by a scan in MuJoCo; the backward gait is the less sensitive one).
fn trot_targets(q0: &[f32; NUM_JOINTS], t: f32, calf_phase: f32) -> [f32; NUM_JOINTS] {
    let mut q = *q0;
    for leg in 0..NUM_FEET {
        let offset = if leg == 1 || leg == 2 { PI } else { 0.0 };
        let theta = 2.0 * PI * t / TROT_PERIOD_S + offset;
        q[3 * leg + 1] += TROT_THIGH_AMPLITUDE * theta.sin();
        q[3 * leg + 2] += TROT_CALF_AMPLITUDE * (theta + calf_phase).cos();
    }
    q
}

const TROT_PERIOD_S: f32 = 0.3;
const TROT_THIGH_AMPLITUDE: f32 = 0.25;
const TROT_CALF_AMPLITUDE: f32 = 0.5;

/// 1 s standing, then 4 s of the open-loop trot; measured over the last 3 s.
fn trot(calf_phase: f32) -> J {
    const STAND: usize = 200;
    const GAIT: usize = 800;
    const MEASURE: usize = 600;
    let mut rig = Rig::new(9.81);
    let q0 = default_q(&rig.model);
    let z0 = standing_base_z(&rig.model, &q0, 0.002);
    rig.place(Pose::from_translation(Vec3::new(0.0, 0.0, z0)), &q0);
    for _ in 0..STAND {
        rig.step(&q0);
    }
    let mut trace: Vec<[f32; 6]> = Vec::new();
    let mut start = RobotState::default();
    let mut last = RobotState::default();
    for i in 0..GAIT {
        // Targets change at the policy rate (50 Hz), as a policy's would.
        let t_policy = (i / DECIMATION * DECIMATION) as f32 * DT;
        let s = rig.step(&trot_targets(&q0, t_policy, calf_phase));
        if i + 1 == GAIT - MEASURE {
            start = s;
        }
        if i % DECIMATION == DECIMATION - 1 {
            trace.push([
                s.base_pos.x,
                s.base_pos.y,
                s.base_pos.z,
                euler_roll(s.base_rot),
                euler_pitch(s.base_rot),
                euler_yaw(s.base_rot),
            ]);
        }
        last = s;
    }
    let span = MEASURE as f32 * DT;
    let tail = &trace[trace.len() - MEASURE / DECIMATION..];
    let column = |k: usize| tail.iter().map(move |r| r[k]);
    let range = |k: usize| {
        let (lo, hi) = column(k).fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        hi - lo
    };
    let mean = |k: usize| column(k).sum::<f32>() / tail.len() as f32;
    J::obj(vec![
        (
            "params",
            J::obj(vec![
                ("stand_steps", num(STAND as f64)),
                ("gait_steps", num(GAIT as f64)),
                ("measure_steps", num(MEASURE as f64)),
                ("period_s", num(TROT_PERIOD_S)),
                ("thigh_amplitude_rad", num(TROT_THIGH_AMPLITUDE)),
                ("calf_amplitude_rad", num(TROT_CALF_AMPLITUDE)),
                ("calf_phase_rad", num(calf_phase)),
            ]),
        ),
        (
            "forward_speed_mps",
            num((last.base_pos.x - start.base_pos.x) / span),
        ),
        (
            "lateral_speed_mps",
            num((last.base_pos.y - start.base_pos.y) / span),
        ),
        (
            "yaw_rate_radps",
            num((euler_yaw(last.base_rot) - euler_yaw(start.base_rot)) / span),
        ),
        ("base_height_m", num(mean(2))),
        ("roll_range_rad", num(range(3))),
        ("pitch_range_rad", num(range(4))),
        ("pitch_mean_rad", num(mean(4))),
        ("trace", J::Arr(trace.iter().map(|r| J::nums(r)).collect())),
    ])
}

/// No gravity, free trunk at rest 1 m up: the `joints` step by `delta` rad and the trunk turns
/// the other way (angular momentum stays zero). Measured after 0.5 s.
fn free_float(joints: &[usize], delta: f32) -> J {
    const STEPS: usize = 100;
    const EARLY: usize = 10;
    let mut rig = Rig::new(0.0);
    let q0 = default_q(&rig.model);
    rig.place(Pose::from_translation(Vec3::new(0.0, 0.0, 1.0)), &q0);
    let mut targets = q0;
    for &j in joints {
        targets[j] += delta;
    }
    let mut early = 0.0;
    let mut trace = Vec::new();
    let mut last = RobotState::default();
    for i in 0..STEPS {
        last = rig.step(&targets);
        let j = joints[0];
        if i + 1 == EARLY {
            early = last.q[j] - q0[j];
        }
        trace.push([
            last.q[j] - q0[j],
            euler_roll(last.base_rot),
            euler_pitch(last.base_rot),
            euler_yaw(last.base_rot),
        ]);
    }
    let moved = last.q[joints[0]] - q0[joints[0]];
    J::obj(vec![
        (
            "params",
            J::obj(vec![
                (
                    "joints",
                    J::nums(&joints.iter().map(|&j| j as f64).collect::<Vec<_>>()),
                ),
                ("delta_rad", num(delta)),
                ("steps", num(STEPS as f64)),
                ("early_steps", num(EARLY as f64)),
            ]),
        ),
        ("joint_moved_rad", num(moved)),
        ("joint_moved_early_rad", num(early)),
        ("roll_rad", num(euler_roll(last.base_rot))),
        ("pitch_rad", num(euler_pitch(last.base_rot))),
        ("yaw_rad", num(euler_yaw(last.base_rot))),
        ("trace", J::Arr(trace.iter().map(|r| J::nums(r)).collect())),
    ])
}

/// States of a calm batch (Table IV initial states, no randomisation, no noise, random initial
/// episode steps so the clocks differ) under deterministic pseudo-random actions, with the o_t
/// the env wrote for each.
fn observations() -> J {
    const ENVS: usize = 8;
    const STEPS: usize = 12;
    let overrides = "
[randomization]
enabled = false
[noise]
enabled = false
";
    let engine = format!(
        "physics.engine = \"{}\"",
        physics_params(9.81).engine.name()
    );
    let config = TaskConfig::embedded_default()
        .with_overrides(overrides)
        .and_then(|c| c.with_overrides(&engine))
        .expect("valid override");
    let options = VecEnvOptions {
        num_envs: ENVS,
        seed: 7,
        threads: 1,
        physics_only: false,
        autoreset: true,
    };
    let mut env = VecEnv::new(
        Arc::new(RobotModel::go2()),
        config,
        Arc::new(Terrain::Flat),
        options,
    )
    .expect("batch builds");
    let mut rng: u64 = 12345;
    let mut samples = Vec::new();
    let mut dump = |env: &VecEnv, step: usize| {
        for i in 0..ENVS {
            let s = env.robot_state(i);
            let e = env.env_state(i);
            let obs = &env.output().obs[i * OBS_DIM..(i + 1) * OBS_DIM];
            let r = s.base_rot;
            samples.push(J::obj(vec![
                ("env", num(i as f64)),
                ("step", num(step as f64)),
                ("base_pos", J::vec3(s.base_pos)),
                ("base_quat_xyzw", J::nums(&[r.x, r.y, r.z, r.w])),
                ("base_linvel", J::vec3(s.base_linvel)),
                ("base_angvel", J::vec3(s.base_angvel)),
                ("q", J::nums(&s.q)),
                ("qd", J::nums(&s.qd)),
                ("last_action", J::nums(&e.actions[0])),
                ("command", J::nums(&e.command)),
                ("mode", num(e.mode as u8)),
                ("episode_step", num(e.episode_step)),
                ("obs", J::nums(obs)),
            ]));
        }
    };
    dump(&env, 0);
    for step in 1..=STEPS {
        let actions: Vec<f32> = (0..ENVS * NUM_JOINTS)
            .map(|_| {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((rng >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect();
        env.step(&actions).expect("step");
        if step % 4 == 0 {
            dump(&env, step);
        }
    }
    J::obj(vec![("samples", J::Arr(samples))])
}

/// Every scenario, in output order.
const SCENARIOS: [&str; 12] = [
    "robot",
    "task",
    "step_hip",
    "step_thigh",
    "step_calf",
    "stand",
    "drop",
    "trot_forward",
    "trot_backward",
    "free_float_roll",
    "free_float_pitch",
    "observations",
];

fn usage() -> String {
    format!(
        "usage: unigait-crosscheck [--engine rapier|articulated] [--armature KG_M2] \
         [--min-link-inertia KG_M2] [--substeps N] [--pgs N] [SCENARIO ...]\nscenarios \
         (default: all): {}",
        SCENARIOS.join(" ")
    )
}

/// What the command line asks for: the scenarios (empty: all) and the physics overrides.
/// `Ok(None)` for `--help`.
fn parse_args(
    args: impl IntoIterator<Item = String>,
) -> Result<Option<(Vec<String>, Overrides)>, String> {
    let mut only = Vec::new();
    let mut o = Overrides::default();
    let mut args = args.into_iter();
    while let Some(a) = args.next() {
        let mut value = |name: &str| -> Result<f64, String> {
            let v = args.next().ok_or(format!("{name} needs a value"))?;
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x >= 0.0)
                .ok_or(format!("{name}: expected a number >= 0, got `{v}`"))
        };
        match a.as_str() {
            "-h" | "--help" => return Ok(None),
            "--engine" => {
                let v = args.next().ok_or("--engine needs a value")?;
                o.engine = Some(match v.as_str() {
                    "rapier" => EngineKind::Rapier,
                    "articulated" => EngineKind::Articulated,
                    _ => return Err(format!("--engine: rapier or articulated, got `{v}`")),
                });
            }
            "--armature" => o.armature = Some(value("--armature")? as f32),
            "--min-link-inertia" => o.min_link_inertia = Some(value("--min-link-inertia")? as f32),
            "--substeps" => o.substeps = Some(value("--substeps")? as usize),
            "--pgs" => o.pgs = Some(value("--pgs")? as usize),
            name if SCENARIOS.contains(&name) => only.push(a),
            other => return Err(format!("unknown scenario or option `{other}`")),
        }
    }
    Ok(Some((only, o)))
}

fn main() {
    let (only, o) = match parse_args(std::env::args().skip(1)) {
        Ok(Some(parsed)) => parsed,
        Ok(None) => {
            println!("{}", usage());
            return;
        }
        Err(e) => {
            eprintln!("unigait-crosscheck: {e}\n{}", usage());
            std::process::exit(2);
        }
    };
    OVERRIDES.set(o).expect("set once");
    let want = |name: &str| only.is_empty() || only.iter().any(|o| o == name);
    let mut sections: Vec<(&str, J)> = Vec::new();
    let mut add = |name: &'static str, run: &dyn Fn() -> J| {
        if want(name) {
            sections.push((name, run()));
        }
    };
    add("robot", &robot_section);
    add("task", &task_section);
    add("step_hip", &|| step_response(0));
    add("step_thigh", &|| step_response(1));
    add("step_calf", &|| step_response(2));
    add("stand", &stand);
    add("drop", &drop);
    add("trot_forward", &|| trot(1.25 * PI));
    add("trot_backward", &|| trot(0.5 * PI));
    add("free_float_roll", &|| free_float(&[0, 6], 0.5));
    add("free_float_pitch", &|| free_float(&[1, 4, 7, 10], 0.5));
    add("observations", &observations);
    // Every name the command line accepts ran (SCENARIOS and the list above agree).
    let wanted = SCENARIOS.iter().filter(|name| want(name)).count();
    assert_eq!(
        sections.len(),
        wanted,
        "SCENARIOS and the scenarios run differ"
    );
    let mut out = String::new();
    J::obj(sections).write(&mut out);
    println!("{out}");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(args: &[&str]) -> Result<Option<(Vec<String>, Overrides)>, String> {
        parse_args(args.iter().map(|a| a.to_string()))
    }

    #[test]
    fn scenarios_and_overrides_are_read() {
        let (only, o) = parse(&["--armature", "0.0005", "stand", "--substeps", "8", "drop"])
            .expect("valid")
            .expect("not help");
        assert_eq!(only, ["stand", "drop"]);
        assert_eq!(o.armature, Some(0.0005));
        assert_eq!(o.substeps, Some(8));
        assert_eq!((o.min_link_inertia, o.pgs, o.engine), (None, None, None));
        let (_, o) = parse(&["--engine", "articulated"])
            .expect("valid")
            .expect("not help");
        assert_eq!(o.engine, Some(EngineKind::Articulated));
        assert!(parse(&["--engine", "mujoco"]).is_err());
        let (all, _) = parse(&[]).expect("valid").expect("not help");
        assert!(all.is_empty());
    }

    #[test]
    fn a_misspelt_scenario_or_a_bad_value_is_an_error_not_a_missing_section() {
        let err = parse(&["stnad"]).expect_err("unknown");
        assert!(err.contains("`stnad`"), "{err}");
        assert!(
            parse(&["--armature"])
                .expect_err("no value")
                .contains("needs a value")
        );
        assert!(parse(&["--pgs", "-1"]).is_err());
        assert!(parse(&["--substeps", "x"]).is_err());
        assert!(parse(&["--help", "stnad"]).expect("help").is_none());
    }
}
