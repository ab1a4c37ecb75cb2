//! The recorder: static scene once, then one row of poses and series per policy step.

use std::path::Path;

use rerun::{
    Arrows3D, Boxes3D, Capsules3D, Color, Ellipsoids3D, FillMode, Mesh3D, Points3D, Quaternion,
    RecordingStream, RecordingStreamBuilder, Scalars, TextLog, Transform3D, ViewCoordinates,
};
use unigait_sim::env::VecEnv;
use unigait_sim::robot::{ColliderRole, NUM_FEET, Shape};
use unigait_sim::task::{RewardTerm, euler_pitch, heading_direction};

use crate::error::RecordError;
use crate::serve::{ServeOptions, Served, proxy_url, serve_stream};
use crate::terrain_mesh::terrain_mesh;

/// The rerun application id of unigait recordings.
pub const APPLICATION_ID: &str = "unigait";

/// Entity paths of a recording.
pub mod entity {
    /// Root of the 3D scene (Z up).
    pub const WORLD: &str = "world";
    /// Parent of the robot's bodies: `world/robot/<body>`.
    pub const ROBOT: &str = "world/robot";
    /// The terrain mesh.
    pub const TERRAIN: &str = "world/terrain";
    /// Feet, coloured by contact.
    pub const FEET: &str = "world/feet";
    /// Commanded velocity (world frame) as an arrow from the base.
    pub const COMMAND: &str = "world/command";
    /// Measured base velocity as an arrow from the base.
    pub const VELOCITY: &str = "world/velocity";
    /// Total reward.
    pub const REWARD_TOTAL: &str = "reward/total";
    /// Task mode (1 biped, 2 quad).
    pub const MODE: &str = "mode";
    /// Mode changes and episode ends.
    pub const EVENTS: &str = "events";

    /// Entity of body `name`.
    pub fn body(name: &str) -> String {
        format!("{ROBOT}/{name}")
    }

    /// Series of reward term `term`.
    pub fn reward(term: &str) -> String {
        format!("reward/{term}")
    }
}

/// Foot names in leg order.
const FOOT_NAMES: [&str; NUM_FEET] = ["FL", "FR", "RL", "RR"];

/// What to record.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordOptions {
    /// The env followed.
    pub env_index: usize,
    /// Half side of the terrain square drawn around the env's spawn point (m). Default 6.
    pub terrain_half_window_m: f32,
    /// Recording name shown in the viewer.
    pub name: String,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            env_index: 0,
            terrain_half_window_m: 6.0,
            name: "rollout".into(),
        }
    }
}

/// Records one env of a batch, step by step.
pub struct Recorder {
    rec: RecordingStream,
    memory: Option<rerun::sink::MemorySinkStorage>,
    /// Where the stream's own gRPC server listens, for a served recording.
    served: Option<std::net::SocketAddr>,
    options: RecordOptions,
    last_mode: Option<u8>,
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

fn open_err(e: impl std::fmt::Display) -> RecordError {
    RecordError::Open(e.to_string())
}

fn log_err(e: impl std::fmt::Display) -> RecordError {
    RecordError::Finish(e.to_string())
}

/// A rotation as rerun's quaternion (plain xyzw arrays in between: rapier and rerun use
/// different glam versions).
fn quat(q: impl Into<[f32; 4]>) -> Quaternion {
    Quaternion::from_xyzw(q.into())
}

fn role_color(role: ColliderRole) -> Color {
    match role {
        ColliderRole::Trunk | ColliderRole::Head => Color::from_rgb(70, 110, 170),
        ColliderRole::Penalised => Color::from_rgb(225, 140, 60),
        ColliderRole::Foot(_) => Color::from_rgb(40, 40, 40),
        ColliderRole::Other => Color::from_rgb(150, 150, 150),
    }
}

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

    /// Log the static scene (axes, robot shapes, terrain) and the state at step 0.
    pub fn begin(&mut self, env: &VecEnv) -> Result<(), RecordError> {
        let i = self.check_index(env)?;
        let rec = &self.rec;
        rec.log_static(entity::WORLD, &ViewCoordinates::RIGHT_HAND_Z_UP())
            .map_err(log_err)?;
        for body in &env.model().bodies {
            for (k, c) in body.colliders.iter().enumerate() {
                let path = format!("{}/geom{k}", entity::body(&body.name));
                let o = &c.geometry.origin;
                rec.log_static(
                    path.as_str(),
                    &Transform3D::from_translation_rotation(
                        [o.translation.x, o.translation.y, o.translation.z],
                        quat(o.rotation),
                    ),
                )
                .map_err(log_err)?;
                let color = role_color(c.role);
                match c.geometry.shape {
                    Shape::Box { size } => rec.log_static(
                        path.as_str(),
                        &Boxes3D::from_half_sizes([[size.x / 2.0, size.y / 2.0, size.z / 2.0]])
                            .with_colors([color])
                            .with_fill_mode(FillMode::Solid),
                    ),
                    // The physics makes cylinders capsules (legged_gym's choice): draw those.
                    // rerun's capsule runs from z = 0 to z = length; ours is centred.
                    Shape::Cylinder { radius, length } => rec.log_static(
                        path.as_str(),
                        &Capsules3D::from_lengths_and_radii([length], [radius])
                            .with_translations([[0.0, 0.0, -length / 2.0]])
                            .with_colors([color])
                            .with_fill_mode(FillMode::Solid),
                    ),
                    Shape::Sphere { radius } => rec.log_static(
                        path.as_str(),
                        &Ellipsoids3D::from_radii([radius])
                            .with_colors([color])
                            .with_fill_mode(FillMode::Solid),
                    ),
                }
                .map_err(log_err)?;
            }
        }
        let origin = env.env_state(i).origin;
        let mesh = terrain_mesh(env.terrain(), origin, self.options.terrain_half_window_m);
        rec.log_static(
            entity::TERRAIN,
            &Mesh3D::new(mesh.positions)
                .with_triangle_indices(mesh.triangles)
                .with_vertex_colors(mesh.colors),
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
        let dt = env.context().config.policy_dt();
        rec.set_time_sequence("step", step as i64);
        rec.set_duration_secs("sim_time", step as f64 * f64::from(dt));
        for (body, pose) in env.model().bodies.iter().zip(env.body_poses(i)) {
            let t = pose.translation;
            rec.log(
                entity::body(&body.name),
                &Transform3D::from_translation_rotation([t.x, t.y, t.z], quat(pose.rotation)),
            )
            .map_err(log_err)?;
        }
        let s = env.robot_state(i);
        let e = env.env_state(i);
        let out = env.output();
        let threshold = env.context().config.rewards.contact_threshold;
        let contact: Vec<bool> = s.foot_force.iter().map(|f| *f > threshold).collect();
        rec.log(
            entity::FEET,
            &Points3D::new(s.foot_pos.iter().map(|p| [p.x, p.y, p.z]))
                .with_radii(env.model().feet.iter().map(|f| f.radius * 1.2))
                .with_colors(contact.iter().map(|&c| {
                    if c {
                        Color::from_rgb(40, 200, 80)
                    } else {
                        Color::from_rgb(200, 200, 200)
                    }
                }))
                .with_labels(FOOT_NAMES),
        )
        .map_err(log_err)?;
        for (f, name) in FOOT_NAMES.iter().enumerate() {
            rec.log(
                format!("contact/{name}"),
                &Scalars::single(f64::from(u8::from(contact[f]))),
            )
            .map_err(log_err)?;
        }
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
        let scalars = [
            ("command/vx", c[0]),
            ("command/vy", c[1]),
            ("command/wz", c[2]),
            (
                "state/base_height",
                s.base_pos.z - env.terrain().height(s.base_pos.x, s.base_pos.y),
            ),
            ("state/pitch", euler_pitch(s.base_rot)),
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
            let name = match out.mode[i] {
                1 => "biped",
                2 => "quad",
                _ => "unknown",
            };
            rec.log(entity::EVENTS, &TextLog::new(format!("mode: {name}")))
                .map_err(log_err)?;
            self.last_mode = Some(out.mode[i]);
        }
        self.steps = self.steps.max(step);
        Ok(())
    }

    /// Flush and keep serving: the returned handle owns the server, which runs until
    /// [`Served::shutdown`] or drop. An error if the recorder was not made by
    /// [`Recorder::serve`].
    pub fn finish_serving(self) -> Result<Served, RecordError> {
        let Some(addr) = self.served else {
            return Err(RecordError::NotServed);
        };
        self.rec.flush_blocking().map_err(log_err)?;
        Ok(Served::from_stream(self.rec, addr))
    }

    /// Flush and close (a served recording stops its server: see [`Recorder::finish_serving`]);
    /// for an in-memory recording, the `.rrd` bytes.
    pub fn finish(self) -> Result<Option<Vec<u8>>, RecordError> {
        let bytes = match &self.memory {
            Some(storage) => Some(storage.drain_as_bytes().map_err(log_err)?),
            None => None,
        };
        self.rec.flush_blocking().map_err(log_err)?;
        self.rec.disconnect();
        Ok(bytes)
    }
}
