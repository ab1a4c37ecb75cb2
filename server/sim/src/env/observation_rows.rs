//! Writing one env's rows of the batch outputs: the observation o_t (scaled, noised, clipped)
//! and the estimator labels e_t, from the robot's state and the env's task state.

use std::ops::Range;

use rand::RngExt;

use crate::physics::RobotState;
use crate::robot::{NUM_FEET, NUM_JOINTS};
use crate::task::{
    OBS_DIM, OBSERVATION, TaskConfig, TaskContext, TaskMode, euler_pitch, projected_gravity,
};

use super::env_state::EnvState;
use super::group::Shared;

/// Where field `name` of o_t sits in a row. Evaluated at compile time for the constants below,
/// so a renamed or missing field fails the build instead of writing to the wrong place.
const fn obs_range(name: &str) -> Range<usize> {
    let mut offset = 0;
    let mut i = 0;
    while i < OBSERVATION.len() {
        let field = &OBSERVATION[i];
        if same_name(field.name, name) {
            return offset..offset + field.dim;
        }
        offset += field.dim;
        i += 1;
    }
    panic!("no such observation field");
}

/// `a == b` for const evaluation (`PartialEq` is not callable in a const fn).
const fn same_name(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

const OBS_CMD: Range<usize> = obs_range("cmd");
const OBS_MODE: Range<usize> = obs_range("mode");
const OBS_CLOCK: Range<usize> = obs_range("clock");
const OBS_RATIO: Range<usize> = obs_range("ratio");
/// The measured part of o_t: orientation through the last action, contiguous in the table.
const OBS_BODY: Range<usize> = obs_range("phi").start..obs_range("last_action").end;
/// The slices of o_t that follow the env's task rather than its body: all a mode switch
/// rewrites.
const OBS_TASK: [Range<usize>; 4] = [OBS_CMD, OBS_MODE, OBS_CLOCK, OBS_RATIO];

/// Write o_t of one env (scaled, noised, clipped) into `row` (53 values).
pub fn write_observation(sh: &Shared, env: &mut EnvState, s: &RobotState, row: &mut [f32]) {
    let ctx = sh.ctx;
    let inv = s.base_rot.inverse();
    let g = projected_gravity(s.base_rot);
    let w = inv * s.base_angvel;
    let mut i = OBS_BODY.start;
    let mut push = |v: f32| {
        row[i] = v;
        i += 1;
    };
    push(g.y);
    push(euler_pitch(s.base_rot));
    push(g.z);
    [w.x, w.y, w.z].iter().for_each(|&c| push(c));
    (0..NUM_JOINTS).for_each(|j| push(s.q[j] - ctx.default_q[j]));
    s.qd.iter().for_each(|&c| push(c));
    env.actions[0].iter().for_each(|&c| push(c));
    debug_assert_eq!(i, OBS_BODY.end);
    write_task_values(&ctx.config, env, row);
    finish_observation(ctx, env, row, 0..OBS_DIM);
}

/// Rewrite only the task slices of an already written o_t (after a mode switch): the body
/// slices keep the reading (and noise draw) the policy has already been given.
pub(super) fn rewrite_task_observation(sh: &Shared, env: &mut EnvState, row: &mut [f32]) {
    write_task_values(&sh.ctx.config, env, row);
    for range in OBS_TASK {
        // These slices carry no noise in the table, so this draws nothing from the env's
        // stream; the values come out bit-identical to a full write of the same state.
        finish_observation(sh.ctx, env, row, range);
    }
}

/// The unscaled task slices of o_t: command, one-hot mode, gait clock, swing/stance ratio.
fn write_task_values(cfg: &TaskConfig, env: &EnvState, row: &mut [f32]) {
    let biped = env.mode == TaskMode::Biped;
    let phase = env.gait_phase(cfg);
    let offsets = env.gait_offsets(cfg);
    row[OBS_CMD].copy_from_slice(&env.command);
    row[OBS_MODE].copy_from_slice(&[f32::from(u8::from(biped)), f32::from(u8::from(!biped))]);
    for (f, (value, theta)) in row[OBS_CLOCK].iter_mut().zip(offsets).enumerate() {
        let rear = f >= 2;
        *value = if biped && rear {
            0.0
        } else {
            (std::f32::consts::TAU * (phase + theta)).sin()
        };
    }
    row[OBS_RATIO].copy_from_slice(&[cfg.gait.swing_ratio, 1.0 - cfg.gait.swing_ratio]);
}

/// Scale, noise and clip `row[range]` in place (noise drawn in index order, where the table
/// has any).
fn finish_observation(ctx: &TaskContext, env: &mut EnvState, row: &mut [f32], range: Range<usize>) {
    let clip = ctx.config.env.clip_observations;
    for i in range {
        let mut v = row[i] * ctx.obs_scale[i];
        let noise = ctx.obs_noise[i];
        if noise > 0.0 {
            v += noise * (2.0 * env.rng.random::<f32>() - 1.0);
        }
        row[i] = v.clamp(-clip, clip);
    }
}

/// Write e_t of one env into `row` (14 values).
pub fn write_labels(sh: &Shared, s: &RobotState, row: &mut [f32]) {
    let inv = s.base_rot.inverse();
    let v = inv * s.base_linvel;
    let n = inv * sh.terrain.normal(s.base_pos.x, s.base_pos.y);
    let threshold = sh.ctx.config.rewards.contact_threshold;
    row[0..3].copy_from_slice(&[v.x, v.y, v.z]);
    for f in 0..NUM_FEET {
        row[3 + f] = f32::from(u8::from(s.foot_force[f] > threshold));
        let p = s.foot_pos[f];
        row[10 + f] = p.z - sh.model.feet[f].radius - sh.terrain.height(p.x, p.y);
    }
    row[7..10].copy_from_slice(&[n.x, n.y, n.z]);
}
