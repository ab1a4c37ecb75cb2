//! unigait-record: rerun recordings of rollouts.
//!
//! A [`Recorder`] follows one env of a [`VecEnv`]: the robot drawn from the model's collision
//! primitives (boxes, capsules for the cylinders as the physics has them, spheres for the
//! feet) posed every step from [`VecEnv::body_poses`]; the terrain (a plane, or a mesh sampled
//! from the grid's heights around the env); the command and the measured velocity as arrows;
//! the feet coloured by contact; and time series of every reward term (`reward/<term>`), the
//! total reward, the command, the task mode, the base height and pitch, the foot contacts.
//! Two timelines: `step` (policy steps) and `sim_time` (seconds).
//!
//! Output: in memory (the `.rrd` bytes, e.g. for a gRPC reply), an `.rrd` file, a live stream
//! to a viewer's gRPC proxy ([`Recorder::connect`], `rerun+http://127.0.0.1:9876/proxy`), or
//! served from this process for a viewer to join later ([`Recorder::serve`]; [`Served::rrd`]
//! for a finished `.rrd`): rerun's gRPC server runs here (loopback by default) and buffers the
//! recording up to a memory limit, and `rerun --connect rerun+http://HOST:PORT/proxy` joins it.
//! Serving and sending finished recordings live in `unigait-rrd` (no simulator, so the client
//! replays through it alone) and are re-exported here.
//! rerun uses glam 0.30 and rapier glam 0.33: everything crosses as plain arrays.
//!
//! Entity layout: the followed env at `world/robot/<body>` (pose per step) with
//! `world/robot/<body>/geom<k>` (static shape and its pose in the body frame), `world/terrain`,
//! `world/feet`, `world/command`, `world/velocity`; the other recorded envs (up to
//! [`RecordOptions::max_envs`]) at `world/envs/<index>/{robot/<body>,feet,terrain}`; scalars
//! under `reward/` (every term, and `reward/active/` for the current mode's task terms),
//! `command/`, `state/` (heading-frame velocity, pitch, the upright threshold, base height),
//! `contact/`, `mode`; the gait diagram as state lanes `gait/FL` ... `gait/RR` and `gait/task_mode`;
//! text events under `events` (followed env) and `outcome/env<index>` (falls, head hits,
//! time-outs, mode switches, final outcome per recorded env).
//!
//! Every recording carries a viewer layout ([`blueprint`]): a 3D view following the robot, the
//! plots that tell the story and the gait diagram; rerun's viewer activates it on load.
#![warn(missing_docs)]

pub mod blueprint;
pub mod entity;
mod error;
mod outcome;
mod recorder;
mod scene;
mod terrain_mesh;

pub use error::RecordError;
pub use recorder::{APPLICATION_ID, FOOT_NAMES, RecordOptions, Recorder};
pub use scene::robot_drawing_rrd;
pub use terrain_mesh::{FLAT_TILE_M, TerrainMesh, terrain_mesh};
pub use unigait_rrd::{
    DEFAULT_MEMORY_LIMIT_BYTES, DEFAULT_SERVE_PORT, MemoryLimit, RrdError, ServeOptions, Served,
    proxy_url, send_rrd, send_rrd_until,
};
