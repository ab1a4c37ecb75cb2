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
    })
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

/// A step reply from the batch's outputs.
pub fn step_result(
    out: &StepOutput,
    reward_terms: bool,
    step_count: u64,
    nonfinite_resets: u32,
) -> v1::StepResult {
    let n = out.len();
    let ended: Vec<u32> = (0..n)
        .filter(|&i| out.terminated[i] != 0 || out.truncated[i] != 0)
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
        reward: Some(f32_tensor(&out.reward, &[n])),
        reward_terms: reward_terms.then(|| f32_tensor(&out.reward_terms, &[n, RewardTerm::COUNT])),
        terminated: Some(u8_tensor(&out.terminated, &[n])),
        truncated: Some(u8_tensor(&out.truncated, &[n])),
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
        head_contact: Some(u8_tensor(&out.head_contact, &[n])),
        step_count,
        nonfinite_resets,
    }
}
