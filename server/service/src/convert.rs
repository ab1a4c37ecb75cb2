//! Conversions between the wire format and the simulation core, in one place.

use unigait_proto::v1::{self, Dtype, FieldSpec, TensorSpec};
use unigait_proto::{f32_tensor, u8_tensor, u32_tensor};
use unigait_sim::env::{ElementType, StepOutput, VecEnv, tensor_layouts};
use unigait_sim::prelude::*;

use crate::error::ServiceError;

/// The server's version string.
pub const SERVER_VERSION: &str = env!("CARGO_PKG_VERSION");

fn dtype(e: ElementType) -> Dtype {
    match e {
        ElementType::F32 => Dtype::F32,
        ElementType::U8 => Dtype::U8,
        ElementType::U32 => Dtype::U32,
    }
}

/// The spec of a session's batch.
pub fn spec(
    env: &VecEnv,
    autoreset: v1::AutoresetMode,
    terrain: &str,
) -> Result<v1::Spec, ServiceError> {
    let cfg = &env.context().config;
    let model = env.model();
    let tensors = tensor_layouts()
        .into_iter()
        .map(|t| TensorSpec {
            name: t.name.into(),
            shape: t.row_shape.iter().map(|&d| d as u32).collect(),
            dtype: dtype(t.element) as i32,
            fields: t
                .slices
                .into_iter()
                .map(|s| FieldSpec {
                    name: s.name,
                    offset: s.offset as u32,
                    size: s.size as u32,
                    doc: s.doc,
                })
                .collect(),
            doc: t.doc.into(),
        })
        .collect();
    Ok(v1::Spec {
        protocol_version: unigait_proto::PROTOCOL_VERSION.into(),
        server_version: SERVER_VERSION.into(),
        num_envs: env.num_envs() as u32,
        physics_dt: cfg.physics.dt,
        decimation: cfg.env.decimation as u32,
        policy_dt: cfg.policy_dt(),
        max_episode_steps: env.context().max_episode_steps,
        action_scale: cfg.env.action_scale,
        joint_names: model.joints.iter().map(|j| j.name.clone()).collect(),
        default_joint_pos: model.config.default_joint_pos.clone(),
        reward_terms: RewardTerm::ALL
            .iter()
            .map(|t| t.name().to_string())
            .collect(),
        tensors,
        task_config_toml: toml_of(cfg)?,
        autoreset: autoreset as i32,
        terrain: terrain.into(),
        body_names: model.bodies.iter().map(|b| b.name.clone()).collect(),
        robot_drawing_rrd: Default::default(),
        physics_engine: cfg.physics.engine.name().into(),
        terrain_columns: crate::terrain::column_names(env.terrain()),
    })
}

/// Most envs one step may ask poses of (`StepRequest.draw_envs`): a live view draws a few.
pub const MAX_DRAWN_ENVS: usize = 64;

/// Check `draw_envs` against a batch of `num_envs` before stepping (a refused request leaves
/// the envs where they were).
pub fn check_draw_envs(draw_envs: &[u32], num_envs: usize) -> Result<(), ServiceError> {
    if draw_envs.len() > MAX_DRAWN_ENVS {
        return Err(ServiceError::InvalidArgument(format!(
            "StepRequest.draw_envs names {} envs; at most {MAX_DRAWN_ENVS}",
            draw_envs.len()
        )));
    }
    if let Some(&bad) = draw_envs.iter().find(|&&i| i as usize >= num_envs) {
        return Err(ServiceError::InvalidArgument(format!(
            "StepRequest.draw_envs: env {bad} is out of range (the session has envs 0..{num_envs})"
        )));
    }
    Ok(())
}

/// f32 [K, B, 7]: each body's pose (x, y, z, qx, qy, qz, qw) of each env of `draw_envs`.
pub fn body_poses(env: &VecEnv, draw_envs: &[u32]) -> v1::Tensor {
    let bodies = env.model().bodies.len();
    let mut values = Vec::with_capacity(draw_envs.len() * bodies * 7);
    for &i in draw_envs {
        for pose in env.body_poses(i as usize) {
            let p = pose.translation;
            let q: [f32; 4] = pose.rotation.into();
            values.extend_from_slice(&[p.x, p.y, p.z, q[0], q[1], q[2], q[3]]);
        }
    }
    f32_tensor(&values, &[draw_envs.len(), bodies, 7])
}

fn toml_of(cfg: &TaskConfig) -> Result<String, ServiceError> {
    // Serialising plain data cannot fail unless the types change shape: that would be a bug.
    cfg.to_toml()
        .map_err(|e| ServiceError::Internal(format!("config to TOML: {e}")))
}

/// Rows `ids` of a `dim`-wide array.
fn gather(values: &[f32], dim: usize, ids: &[u32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(ids.len() * dim);
    for &i in ids {
        let i = i as usize;
        out.extend_from_slice(&values[i * dim..(i + 1) * dim]);
    }
    out
}

/// A step reply from the batch's outputs. Envs flagged in `already_ended` (autoreset
/// disabled: their episode ended at an earlier step and they were not reset) report no end
/// and no reward.
pub fn step_result(
    out: &StepOutput,
    reward_terms: bool,
    step_count: u64,
    nonfinite_resets: u32,
    already_ended: Option<&[u8]>,
) -> v1::StepResult {
    let n = out.len();
    let stale = |i: usize| already_ended.is_some_and(|e| e.get(i).is_some_and(|&v| v != 0));
    let masked = |flags: &[u8]| -> Vec<u8> {
        (0..n)
            .map(|i| if stale(i) { 0 } else { flags[i] })
            .collect()
    };
    let terminated = masked(&out.terminated);
    let truncated = masked(&out.truncated);
    let mut reward = out.reward.clone();
    let mut terms = reward_terms.then(|| out.reward_terms.clone());
    for i in (0..n).filter(|&i| stale(i)) {
        reward[i] = 0.0;
        if let Some(t) = terms.as_mut() {
            t[i * RewardTerm::COUNT..(i + 1) * RewardTerm::COUNT].fill(0.0);
        }
    }
    let ended: Vec<u32> = (0..n)
        .filter(|&i| terminated[i] != 0 || truncated[i] != 0)
        .map(|i| i as u32)
        .collect();
    let k = ended.len();
    let lengths: Vec<u32> = ended
        .iter()
        .map(|&i| out.episode_length[i as usize])
        .collect();
    v1::StepResult {
        obs: Some(f32_tensor(&out.obs, &[n, OBS_DIM])),
        labels: Some(f32_tensor(&out.labels, &[n, LABEL_DIM])),
        privileged: Some(f32_tensor(&out.privileged, &[n, PRIVILEGED_DIM])),
        reward: Some(f32_tensor(&reward, &[n])),
        reward_terms: terms.map(|t| f32_tensor(&t, &[n, RewardTerm::COUNT])),
        terminated: Some(u8_tensor(&terminated, &[n])),
        truncated: Some(u8_tensor(&truncated, &[n])),
        final_obs: Some(f32_tensor(
            &gather(&out.final_obs, OBS_DIM, &ended),
            &[k, OBS_DIM],
        )),
        final_labels: Some(f32_tensor(
            &gather(&out.final_labels, LABEL_DIM, &ended),
            &[k, LABEL_DIM],
        )),
        final_privileged: Some(f32_tensor(
            &gather(&out.final_privileged, PRIVILEGED_DIM, &ended),
            &[k, PRIVILEGED_DIM],
        )),
        final_episode_length: Some(u32_tensor(&lengths, &[k])),
        final_env_ids: Some(u32_tensor(&ended, &[k])),
        mode: Some(u8_tensor(&out.mode, &[n])),
        terrain_level: Some(u32_tensor(&out.terrain_level, &[n])),
        mode_levels: Some(u32_tensor(&out.mode_levels, &[n, 2])),
        head_contact: Some(u8_tensor(&out.head_contact, &[n])),
        nonfinite: Some(u8_tensor(&out.nonfinite, &[n])),
        step_count,
        nonfinite_resets,
        upright_pitch: Some(out.upright_pitch),
        body_poses: None,
    }
}
