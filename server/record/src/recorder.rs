//! The recorder: static scene and viewer layout once, then one row of poses and series per
//! policy step.

use std::path::Path;

use rerun::{
    Arrows3D, Color, Mesh3D, Points3D, RecordingStream, RecordingStreamBuilder, Scalars,
    SeriesLines, StateChange, StateConfiguration, TextLog, TextLogLevel, Transform3D,
    ViewCoordinates,
};
use unigait_sim::env::VecEnv;
use unigait_sim::robot::{ColliderRole, NUM_FEET};
use unigait_sim::task::{RewardTerm, TermGroup, euler_pitch, heading_direction, to_heading_frame};

use crate::blueprint::{Layout, LayoutEnv, LayoutInput};
use crate::entity;
use crate::error::{RecordError, log_err, open_err};
use crate::outcome::{Tracked, log_outcome_events, mode_name};
use crate::scene::{ScenePaths, log_robot_shapes, quat};
use crate::terrain_mesh::terrain_mesh;
use unigait_rrd::{ServeOptions, Served, proxy_url, serve_stream};

/// The rerun application id of unigait recordings.
pub const APPLICATION_ID: &str = "unigait";

/// Foot names in leg order.
pub const FOOT_NAMES: [&str; NUM_FEET] = ["FL", "FR", "RL", "RR"];

/// What to record.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordOptions {
    /// The env followed: its robot, series, gait diagram and camera.
    pub env_index: usize,
    /// Envs drawn: the followed env and up to `max_envs - 1` others (the first indices of the
    /// batch), each a tab of the 3D view with its own camera, plus an overview of them all.
    /// Default 4; 1 draws the followed env only. The others cost a robot's poses and its
    /// feet per step (about a fifth of the followed env's data) and a terrain mesh.
    pub max_envs: usize,
    /// Half side of the terrain square drawn around each env's spawn point (m). Default 6.
    pub terrain_half_window_m: f32,
    /// Recording name shown in the viewer.
    pub name: String,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            env_index: 0,
            max_envs: 4,
            terrain_half_window_m: 6.0,
            name: "rollout".into(),
        }
    }
}

/// Records envs of a batch, step by step.
pub struct Recorder {
    rec: RecordingStream,
    memory: Option<rerun::sink::MemorySinkStorage>,
    /// Where the stream's own gRPC server listens, for a served recording.
    served: Option<std::net::SocketAddr>,
    options: RecordOptions,
    last_mode: Option<u8>,
    /// Stance per foot of the followed env at the last step (the gait lanes change there).
    last_stance: Option<[bool; NUM_FEET]>,
    /// The recorded envs, the followed one first (set by `begin`).
    tracked: Vec<Tracked>,
    steps: u64,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("options", &self.options)
            .field("in_memory", &self.memory.is_some())
            .field("served", &self.served)
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

/// Whether a task term belongs to mode `code` (1 biped, 2 quad).
fn term_of_mode(term: RewardTerm, code: u8) -> bool {
    match term.group() {
        TermGroup::Common => false,
        TermGroup::Quad => code == 2,
        TermGroup::Biped | TermGroup::BipedUpright => code == 1,
    }
}

/// Names and colours of the plotted series (commands thin and pale, measurements bold in the
/// same hue), so command and measurement pair up at a glance.
const SERIES_STYLE: [(&str, &str, [u8; 3], f32); 9] = [
    ("command/vx", "vx command", [150, 180, 255], 1.5),
    ("state/vx", "vx measured", [30, 80, 220], 2.5),
    ("command/vy", "vy command", [150, 220, 150], 1.5),
    ("state/vy", "vy measured", [20, 140, 40], 2.5),
    ("command/wz", "yaw rate command", [230, 160, 230], 1.5),
    ("state/yaw_rate", "yaw rate measured", [150, 40, 160], 2.5),
    ("state/pitch", "pitch", [200, 60, 40], 2.5),
    (
        "state/upright_pitch",
        "upright threshold",
        [120, 120, 120],
        1.5,
    ),
    ("state/base_height", "base height", [40, 120, 200], 2.5),
];

impl Recorder {
    fn builder(options: &RecordOptions) -> RecordingStreamBuilder {
        RecordingStreamBuilder::new(APPLICATION_ID)
            .recording_name(options.name.clone())
            .send_properties(true)
    }

    /// Record into memory; [`Recorder::finish`] returns the `.rrd` bytes.
    pub fn in_memory(options: RecordOptions) -> Result<Self, RecordError> {
        let (rec, storage) = Self::builder(&options).memory().map_err(open_err)?;
        Ok(Self::new(rec, Some(storage), options))
    }

    /// Record into an `.rrd` file.
    pub fn to_file(path: impl AsRef<Path>, options: RecordOptions) -> Result<Self, RecordError> {
        let rec = Self::builder(&options)
            .save(path.as_ref())
            .map_err(open_err)?;
        Ok(Self::new(rec, None, options))
    }

    /// Stream live to a viewer's gRPC proxy, e.g. `rerun+http://127.0.0.1:9876/proxy` (start
    /// the viewer with `rerun`, which listens there by default).
    pub fn connect(url: &str, options: RecordOptions) -> Result<Self, RecordError> {
        let rec = Self::builder(&options)
            .connect_grpc_opts(url)
            .map_err(open_err)?;
        Ok(Self::new(rec, None, options))
    }

    /// Serve from this process for a viewer to join, live or later: rerun's gRPC server runs
    /// here and buffers the recording (up to `serve.memory_limit`), and `rerun --connect
    /// <url>` (see [`Recorder::serve_url`]) joins it. Returns once the server listens. Keep
    /// serving after the rollout with [`Recorder::finish_serving`]; [`Recorder::finish`]
    /// stops the server.
    pub fn serve(serve: &ServeOptions, options: RecordOptions) -> Result<Self, RecordError> {
        let (rec, addr) = serve_stream(Self::builder(&options), serve)?;
        let mut recorder = Self::new(rec, None, options);
        recorder.served = Some(addr);
        Ok(recorder)
    }

    /// Record into a stream the caller built.
    pub fn with_stream(rec: RecordingStream, options: RecordOptions) -> Self {
        Self::new(rec, None, options)
    }

    fn new(
        rec: RecordingStream,
        memory: Option<rerun::sink::MemorySinkStorage>,
        options: RecordOptions,
    ) -> Self {
        Self {
            rec,
            memory,
            served: None,
            options,
            last_mode: None,
            last_stance: None,
            tracked: Vec::new(),
            steps: 0,
        }
    }

    /// The underlying stream (to log more).
    pub fn stream(&self) -> &RecordingStream {
        &self.rec
    }

    /// For a served recording, the URL a viewer joins (`rerun+http://HOST:PORT/proxy`).
    pub fn serve_url(&self) -> Option<String> {
        self.served.map(proxy_url)
    }

    /// Steps logged.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    fn check_index(&self, env: &VecEnv) -> Result<usize, RecordError> {
        let i = self.options.env_index;
        if i >= env.num_envs() {
            return Err(RecordError::EnvIndex {
                index: i,
                num_envs: env.num_envs(),
            });
        }
        Ok(i)
    }

    /// The indices recorded for a batch of `num_envs`: `followed` first, then the lowest
    /// others, `max_envs` in all.
    fn recorded_envs(&self, followed: usize, num_envs: usize) -> Vec<usize> {
        let others = (0..num_envs).filter(|&k| k != followed);
        std::iter::once(followed)
            .chain(others)
            .take(self.options.max_envs.max(1))
            .collect()
    }

    /// The viewer layout for `env` (the envs this recorder draws): what [`Recorder::begin`]
    /// sends with the recording.
    pub fn layout(&self, env: &VecEnv) -> Result<Layout, RecordError> {
        let i = self.check_index(env)?;
        let base = &env.model().bodies[0];
        // The camera follows a shape, not the body's frame: rerun's eye tracks an entity by
        // the bounding box of what it draws, and a body's own entity only holds its pose.
        let trunk = base
            .colliders
            .iter()
            .position(|c| c.role == ColliderRole::Trunk)
            .unwrap_or(0);
        let envs = self.recorded_envs(i, env.num_envs());
        let mut other_roots = Vec::new();
        let mut layout_envs = Vec::new();
        for &k in &envs {
            let p = env.robot_state(k).base_pos;
            let (paths, contents) = if k == i {
                (
                    ScenePaths::followed(),
                    vec![
                        format!("+ /{}/**", entity::WORLD),
                        format!("- /{}/**", entity::OTHER_ENVS),
                    ],
                )
            } else {
                let root = entity::other_env(k);
                other_roots.push(root.clone());
                (
                    ScenePaths::other(k),
                    vec![format!("+ /{}", entity::WORLD), format!("+ /{root}/**")],
                )
            };
            layout_envs.push(LayoutEnv {
                label: if k == i {
                    format!("env {k} (followed)")
                } else {
                    format!("env {k}")
                },
                contents,
                base: format!("{}/geom{trunk}", paths.body(&base.name)),
                base_start: [p.x, p.y, p.z],
            });
        }
        Ok(Layout::unigait(&LayoutInput {
            envs: layout_envs,
            other_roots,
            reward_series: vec![format!("{}/**", entity::REWARD_ACTIVE)],
        }))
    }

    /// Log the viewer layout, the static scene (axes, robot shapes, terrain, series styles) and
    /// the state at step 0.
    pub fn begin(&mut self, env: &VecEnv) -> Result<(), RecordError> {
        let i = self.check_index(env)?;
        self.layout(env)?.send(&self.rec, APPLICATION_ID)?;
        let out = env.output();
        self.tracked = self
            .recorded_envs(i, env.num_envs())
            .into_iter()
            .map(|k| Tracked {
                index: k,
                paths: if k == i {
                    ScenePaths::followed()
                } else {
                    ScenePaths::other(k)
                },
                mode: out.mode[k],
                head_contact: out.head_contact[k] != 0,
                falls: 0,
                head_hits: 0,
                time_outs: 0,
                mode_switches: 0,
            })
            .collect();
        let rec = &self.rec;
        rec.log_static(entity::WORLD, &ViewCoordinates::RIGHT_HAND_Z_UP())
            .map_err(log_err)?;
        for t in &self.tracked {
            log_robot_shapes(rec, env.model(), &t.paths)?;
            let origin = env.env_state(t.index).origin;
            let mesh = terrain_mesh(env.terrain(), origin, self.options.terrain_half_window_m);
            rec.log_static(
                t.paths.terrain.as_str(),
                &Mesh3D::new(mesh.positions)
                    .with_triangle_indices(mesh.triangles)
                    .with_vertex_colors(mesh.colors),
            )
            .map_err(log_err)?;
        }
        for (path, name, [r, g, b], width) in SERIES_STYLE {
            rec.log_static(
                path,
                &SeriesLines::new()
                    .with_names([name])
                    .with_colors([Color::from_rgb(r, g, b)])
                    .with_widths([width]),
            )
            .map_err(log_err)?;
        }
        // Gait lanes: stance as a dark bar, swing left blank, as in a classic gait diagram.
        for foot in FOOT_NAMES {
            rec.log_static(
                entity::gait(foot).as_str(),
                &StateConfiguration::new()
                    .with_values(["stance", "swing"])
                    .with_colors([Color::from_rgb(45, 45, 60), Color::from_rgb(235, 235, 235)])
                    .with_visible([true, false]),
            )
            .map_err(log_err)?;
        }
        rec.log_static(
            entity::GAIT_MODE,
            &StateConfiguration::new()
                .with_values(["quad", "biped", "unknown"])
                .with_colors([
                    Color::from_rgb(40, 155, 165),
                    Color::from_rgb(225, 135, 50),
                    Color::from_rgb(150, 150, 150),
                ]),
        )
        .map_err(log_err)?;
        self.log_state(env, 0)
    }

    /// Log the state after policy step `step` (1-based; 0 is the initial state).
    pub fn log_step(&mut self, env: &VecEnv, step: u64) -> Result<(), RecordError> {
        self.log_state(env, step)
    }

    fn log_state(&mut self, env: &VecEnv, step: u64) -> Result<(), RecordError> {
        let i = self.check_index(env)?;
        let rec = &self.rec;
        let cfg = &env.context().config;
        let dt = cfg.policy_dt();
        let t_s = step as f64 * f64::from(dt);
        rec.set_time_sequence("step", step as i64);
        rec.set_duration_secs("sim_time", t_s);
        let threshold = cfg.rewards.contact_threshold;
        let out = env.output();
        // Every recorded env: poses, feet, outcome events.
        for t in &mut self.tracked {
            let k = t.index;
            for (body, pose) in env.model().bodies.iter().zip(env.body_poses(k)) {
                let p = pose.translation;
                rec.log(
                    t.paths.body(&body.name),
                    &Transform3D::from_translation_rotation([p.x, p.y, p.z], quat(pose.rotation)),
                )
                .map_err(log_err)?;
            }
            let s = env.robot_state(k);
            rec.log(
                t.paths.feet.as_str(),
                &Points3D::new(s.foot_pos.iter().map(|p| [p.x, p.y, p.z]))
                    .with_radii(env.model().feet.iter().map(|f| f.radius * 1.2))
                    .with_colors(s.foot_force.iter().map(|&f| {
                        if f > threshold {
                            Color::from_rgb(40, 200, 80)
                        } else {
                            Color::from_rgb(200, 200, 200)
                        }
                    })),
            )
            .map_err(log_err)?;
            log_outcome_events(rec, t, env, step, t_s)?;
        }
        let s = env.robot_state(i);
        let e = env.env_state(i);
        let stance: [bool; NUM_FEET] = std::array::from_fn(|f| s.foot_force[f] > threshold);
        for (f, name) in FOOT_NAMES.iter().enumerate() {
            rec.log(
                format!("contact/{name}"),
                &Scalars::single(f64::from(u8::from(stance[f]))),
            )
            .map_err(log_err)?;
            if self.last_stance.is_none_or(|last| last[f] != stance[f]) {
                rec.log(
                    entity::gait(name),
                    &StateChange::single(if stance[f] { "stance" } else { "swing" }),
                )
                .map_err(log_err)?;
            }
        }
        self.last_stance = Some(stance);
        let base = [s.base_pos.x, s.base_pos.y, s.base_pos.z];
        let h = heading_direction(s.base_rot);
        let c = e.command;
        let cmd_world = [c[0] * h.x - c[1] * h.y, c[0] * h.y + c[1] * h.x, 0.0];
        rec.log(
            entity::COMMAND,
            &Arrows3D::from_vectors([cmd_world])
                .with_origins([base])
                .with_colors([Color::from_rgb(60, 120, 255)]),
        )
        .map_err(log_err)?;
        let v = s.base_linvel;
        rec.log(
            entity::VELOCITY,
            &Arrows3D::from_vectors([[v.x, v.y, v.z]])
                .with_origins([base])
                .with_colors([Color::from_rgb(255, 80, 80)]),
        )
        .map_err(log_err)?;
        let v_heading = to_heading_frame(h, v);
        let scalars = [
            ("command/vx", c[0]),
            ("command/vy", c[1]),
            ("command/wz", c[2]),
            ("state/vx", v_heading.x),
            ("state/vy", v_heading.y),
            (
                "state/base_height",
                s.base_pos.z - env.terrain().height(s.base_pos.x, s.base_pos.y),
            ),
            ("state/pitch", euler_pitch(s.base_rot)),
            ("state/upright_pitch", cfg.rewards.upright_pitch),
            ("state/yaw_rate", s.base_angvel.z),
            (entity::MODE, f32::from(out.mode[i])),
        ];
        for (path, value) in scalars {
            rec.log(path, &Scalars::single(f64::from(value)))
                .map_err(log_err)?;
        }
        if step > 0 {
            rec.log(
                entity::REWARD_TOTAL,
                &Scalars::single(f64::from(out.reward[i])),
            )
            .map_err(log_err)?;
            let terms = &out.reward_terms[i * RewardTerm::COUNT..(i + 1) * RewardTerm::COUNT];
            for (term, value) in RewardTerm::ALL.iter().zip(terms) {
                rec.log(
                    entity::reward(term.name()),
                    &Scalars::single(f64::from(*value)),
                )
                .map_err(log_err)?;
                // A scenario's switch (between steps) already counts in this step's reward; a
                // mode drawn at a reset is one step early here, harmless for a plot.
                if term_of_mode(*term, out.mode[i]) {
                    rec.log(
                        entity::reward_active(term.name()),
                        &Scalars::single(f64::from(*value)),
                    )
                    .map_err(log_err)?;
                }
            }
            if out.terminated[i] != 0 || out.truncated[i] != 0 {
                let what = if out.terminated[i] != 0 {
                    "terminated (base contact)"
                } else {
                    "time-out"
                };
                rec.log(
                    entity::EVENTS,
                    &TextLog::new(format!("episode ended: {what}; env reset")),
                )
                .map_err(log_err)?;
            }
        }
        if self.last_mode != Some(out.mode[i]) {
            let name = mode_name(out.mode[i]);
            rec.log(entity::EVENTS, &TextLog::new(format!("mode: {name}")))
                .map_err(log_err)?;
            rec.log(entity::GAIT_MODE, &StateChange::single(name))
                .map_err(log_err)?;
            self.last_mode = Some(out.mode[i]);
        }
        self.steps = self.steps.max(step);
        Ok(())
    }

    /// Log each recorded env's outcome (falls, head hits, time-outs, mode switches, final
    /// mode) as an event at the last step.
    fn log_outcomes(&self) -> Result<(), RecordError> {
        if self.tracked.is_empty() {
            return Ok(());
        }
        self.rec.set_time_sequence("step", self.steps as i64);
        for t in &self.tracked {
            let fell = if t.falls == 0 {
                "no fall".to_string()
            } else {
                format!("{} fall(s)", t.falls)
            };
            let text = format!(
                "env {} outcome: {}; {fell}, {} head hit(s), {} time-out(s), {} mode switch(es), \
                 ends in {} mode",
                t.index,
                if t.falls == 0 { "kept going" } else { "fell" },
                t.head_hits,
                t.time_outs,
                t.mode_switches,
                mode_name(t.mode),
            );
            let level = if t.falls == 0 && t.head_hits == 0 {
                TextLogLevel::INFO
            } else {
                TextLogLevel::WARN
            };
            self.rec
                .log(
                    entity::outcome(t.index),
                    &TextLog::new(text).with_level(level),
                )
                .map_err(log_err)?;
        }
        Ok(())
    }

    /// Flush and keep serving: the returned handle owns the server, which runs until
    /// [`Served::shutdown`] or drop. An error if the recorder was not made by
    /// [`Recorder::serve`].
    pub fn finish_serving(self) -> Result<Served, RecordError> {
        let Some(addr) = self.served else {
            return Err(RecordError::NotServed);
        };
        self.log_outcomes()?;
        self.rec.flush_blocking().map_err(log_err)?;
        Ok(Served::from_stream(self.rec, addr))
    }

    /// Log the outcome per env, flush and close (a served recording stops its server: see
    /// [`Recorder::finish_serving`]); for an in-memory recording, the `.rrd` bytes.
    pub fn finish(self) -> Result<Option<Vec<u8>>, RecordError> {
        self.log_outcomes()?;
        let bytes = match &self.memory {
            Some(storage) => Some(storage.drain_as_bytes().map_err(log_err)?),
            None => None,
        };
        self.rec.flush_blocking().map_err(log_err)?;
        self.rec.disconnect();
        Ok(bytes)
    }
}
