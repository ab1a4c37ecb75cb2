//! Per-rollout statistics the Python learner also logs, with its columns and rules: the mean
//! terrain level per terrain type and per mode (client-py's `unigait.env.terrain_stats`), and
//! what the robot does in biped mode (`unigait.env.biped_pose`).

use std::ops::Range;

use unigait_client::Spec;

use crate::env::StepData;
use crate::{Error, Result};

/// Task modes as the columns count them.
pub const MODES: [&str; 2] = ["quad", "biped"];

/// Biped mode in a step's `mode` (1 biped, 2 quad: the paper's x).
const BIPED_MODE: u8 = 1;

/// Grid column of env `env` of `n` (the server's rule: in blocks, never moved).
pub fn initial_column(env: usize, n: usize, columns: usize) -> usize {
    let n = n.max(1);
    (env.min(n - 1) * columns.max(1)) / n
}

/// The terrain type of each of `n` envs, from the spec's terrain description (`flat`,
/// `curriculum` or `<type> level <l>`) and its grid's column types (`Spec.terrain_columns`); a
/// curriculum without them (an older server) counts every env as `curriculum`.
pub fn env_terrain_types(terrain: &str, columns: &[String], n: usize) -> Vec<String> {
    if terrain == "curriculum" && !columns.is_empty() {
        return (0..n)
            .map(|e| columns[initial_column(e, n, columns.len())].clone())
            .collect();
    }
    let name = terrain.split(' ').next().filter(|s| !s.is_empty());
    vec![name.unwrap_or("flat").to_string(); n]
}

fn mean(sum: f64, count: f64) -> f64 {
    if count > 0.0 { sum / count } else { f64::NAN }
}

/// Sums of the terrain level over env-steps, by terrain type and by mode; `terrain_level/<type>`
/// for every type of the batch and `terrain_level/quad`, `terrain_level/biped` always (NaN
/// where a rollout had no such env-step), then `terrain_level/<type>/<mode>`, the mean level of
/// the type's tiles over the env-steps taken in that mode (decision record 0036). Then
/// `promoted/<type>` and `demoted/<type>`: the share
/// of the type's ended episodes after which the env came back a level higher or lower (NaN
/// without an ended episode), as the Python learner logs them.
#[derive(Debug, Clone)]
pub struct TerrainLevelStats {
    types: Vec<String>,
    type_of_env: Vec<usize>,
    type_sum: Vec<f64>,
    type_steps: Vec<f64>,
    mode_sum: [f64; 2],
    mode_steps: [f64; 2],
    /// Per type and mode ([type][mode]).
    cell_sum: Vec<[f64; 2]>,
    cell_steps: Vec<[f64; 2]>,
    ends: Vec<f64>,
    ups: Vec<f64>,
    downs: Vec<f64>,
}

impl TerrainLevelStats {
    /// For envs of these terrain types (in first-seen order of the types).
    pub fn new(env_types: &[String]) -> Self {
        let mut types: Vec<String> = Vec::new();
        let type_of_env = env_types
            .iter()
            .map(|t| match types.iter().position(|k| k == t) {
                Some(k) => k,
                None => {
                    types.push(t.clone());
                    types.len() - 1
                }
            })
            .collect();
        let k = types.len();
        Self {
            types,
            type_of_env,
            type_sum: vec![0.0; k],
            type_steps: vec![0.0; k],
            mode_sum: [0.0; 2],
            mode_steps: [0.0; 2],
            cell_sum: vec![[0.0; 2]; k],
            cell_steps: vec![[0.0; 2]; k],
            ends: vec![0.0; k],
            ups: vec![0.0; k],
            downs: vec![0.0; k],
        }
    }

    /// One step's ended episodes: every env's level before and after the step. An ended env's
    /// level after it is its next episode's (the server resets it within the step), so the
    /// difference is the curriculum's verdict on the episode.
    pub fn add_episode_ends(&mut self, before: &[u32], after: &[u32], dones: &[bool]) {
        for (((&b, &a), &done), &t) in before.iter().zip(after).zip(dones).zip(&self.type_of_env) {
            if done {
                self.ends[t] += 1.0;
                if a > b {
                    self.ups[t] += 1.0;
                } else if a < b {
                    self.downs[t] += 1.0;
                }
            }
        }
    }

    /// One step: every env's level and mode.
    pub fn add(&mut self, level: &[u32], mode: &[u8]) {
        for ((&l, &m), &t) in level.iter().zip(mode).zip(&self.type_of_env) {
            let l = f64::from(l);
            self.type_sum[t] += l;
            self.type_steps[t] += 1.0;
            let k = usize::from(m == BIPED_MODE);
            self.mode_sum[k] += l;
            self.mode_steps[k] += 1.0;
            self.cell_sum[t][k] += l;
            self.cell_steps[t][k] += 1.0;
        }
    }

    /// The means since the last summary; then cleared.
    pub fn summary(&mut self) -> Vec<(String, f64)> {
        let mut out: Vec<(String, f64)> = self
            .types
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let m = mean(self.type_sum[k], self.type_steps[k]);
                (format!("terrain_level/{name}"), m)
            })
            .collect();
        for (k, name) in MODES.iter().enumerate() {
            let m = mean(self.mode_sum[k], self.mode_steps[k]);
            out.push((format!("terrain_level/{name}"), m));
        }
        for (t, kind) in self.types.iter().enumerate() {
            for (k, name) in MODES.iter().enumerate() {
                let m = mean(self.cell_sum[t][k], self.cell_steps[t][k]);
                out.push((format!("terrain_level/{kind}/{name}"), m));
            }
        }
        for (k, name) in self.types.iter().enumerate() {
            out.push((format!("promoted/{name}"), mean(self.ups[k], self.ends[k])));
            out.push((format!("demoted/{name}"), mean(self.downs[k], self.ends[k])));
        }
        self.type_sum.fill(0.0);
        self.type_steps.fill(0.0);
        self.mode_sum = [0.0; 2];
        self.mode_steps = [0.0; 2];
        self.cell_sum.fill([0.0; 2]);
        self.cell_steps.fill([0.0; 2]);
        self.ends.fill(0.0);
        self.ups.fill(0.0);
        self.downs.fill(0.0);
        out
    }
}

/// Sums over the env-steps taken in biped mode: the observed pitch, the share upright (pitch
/// above the task's `rewards.upright_pitch`), the share with both rear feet off the ground and
/// the share with the head on it. Envs whose episode ended in the step are left out: their
/// state is already the next episode's first one.
#[derive(Debug, Clone)]
pub struct BipedPoseStats {
    pitch_index: usize,
    rear_feet: Range<usize>,
    upright_pitch: f64,
    sums: PoseSums,
}

/// One rollout's sums over biped env-steps.
#[derive(Debug, Clone, Default)]
struct PoseSums {
    steps: f64,
    pitch: f64,
    upright: f64,
    rear_up: f64,
    head_steps: f64,
    head: f64,
}

impl BipedPoseStats {
    /// Where pitch (the second entry of o_t's `phi`) and the rear feet's contact labels sit,
    /// from the spec; the upright line from its task config.
    pub fn from_spec(spec: &Spec) -> Result<Self> {
        let phi = spec
            .slice("obs", "phi")
            .ok_or_else(|| Error::Spec("the spec's obs has no `phi` field".into()))?;
        let contact = spec
            .slice("labels", "foot_contact")
            .filter(|r| r.len() == 4)
            .ok_or_else(|| Error::Spec("the spec's labels have no 4 `foot_contact`".into()))?;
        let task: toml::Table = toml::from_str(&spec.0.task_config_toml)
            .map_err(|e| Error::Spec(format!("the spec's task config: {e}")))?;
        let upright_pitch = task
            .get("rewards")
            .and_then(|r| r.get("upright_pitch"))
            .and_then(|v| v.as_float())
            .ok_or_else(|| Error::Spec("the spec's task config has no upright_pitch".into()))?;
        Ok(Self {
            pitch_index: phi.start + 1,
            // Feet in FL, FR, RL, RR order: the last two are the rear feet.
            rear_feet: contact.start + 2..contact.start + 4,
            upright_pitch,
            sums: PoseSums::default(),
        })
    }

    /// Add the envs that acted in biped mode (`mode`) and the state `after` left them in.
    pub fn add(&mut self, mode: &[u8], after: &StepData, obs: usize, labels: usize) {
        let dones = after.dones();
        for (e, &m) in mode.iter().enumerate() {
            if m != BIPED_MODE || dones[e] {
                continue;
            }
            let pitch = f64::from(after.obs[e * obs + self.pitch_index]);
            let rear = &after.labels[e * labels..(e + 1) * labels][self.rear_feet.clone()];
            let sums = &mut self.sums;
            sums.steps += 1.0;
            sums.pitch += pitch;
            sums.upright += f64::from(u8::from(pitch > self.upright_pitch));
            sums.rear_up += f64::from(u8::from(rear.iter().all(|&c| c < 0.5)));
            if let Some(head) = &after.head_contact {
                sums.head_steps += 1.0;
                sums.head += f64::from(u8::from(head[e]));
            }
        }
    }

    /// The means over this rollout's biped env-steps (NaN where there were none); then cleared.
    pub fn summary(&mut self) -> Vec<(String, f64)> {
        let s = std::mem::take(&mut self.sums);
        vec![
            ("biped_pose/pitch".into(), mean(s.pitch, s.steps)),
            ("biped_pose/upright_share".into(), mean(s.upright, s.steps)),
            (
                "biped_pose/head_contact_share".into(),
                mean(s.head, s.head_steps),
            ),
            (
                "biped_pose/rear_feet_up_share".into(),
                mean(s.rear_up, s.steps),
            ),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_in_blocks_as_the_server() {
        // The default grid: 40 envs over 20 columns, two envs a column, in order.
        let grid: Vec<String> = [
            ("slope_up", 1),
            ("slope_down", 1),
            ("rough_slope", 2),
            ("stairs_up", 7),
            ("stairs_down", 5),
            ("obstacles", 4),
        ]
        .iter()
        .flat_map(|&(name, k)| std::iter::repeat_n(name.to_string(), k))
        .collect();
        let types = env_terrain_types("curriculum", &grid, 40);
        assert_eq!(
            &types[..4],
            ["slope_up", "slope_up", "slope_down", "slope_down"]
        );
        assert_eq!(types.iter().filter(|t| *t == "stairs_up").count(), 14);
        assert_eq!(types[39], "obstacles");
        // A grid of its own: 6 envs on 3 columns.
        let own: Vec<String> = ["slope_up", "slope_up", "stairs_down"]
            .map(String::from)
            .to_vec();
        assert_eq!(
            env_terrain_types("curriculum", &own, 6),
            [
                "slope_up",
                "slope_up",
                "slope_up",
                "slope_up",
                "stairs_down",
                "stairs_down"
            ]
        );
        // An older server names no columns.
        assert_eq!(
            env_terrain_types("curriculum", &[], 2),
            ["curriculum", "curriculum"]
        );
        assert_eq!(
            env_terrain_types("stairs_up level 3", &[], 2),
            ["stairs_up", "stairs_up"]
        );
        assert_eq!(env_terrain_types("flat", &[], 1), ["flat"]);
    }

    /// Obs of width 3 with pitch at 1, labels of width 4 with the rear feet at 2..4.
    fn pose_stats() -> BipedPoseStats {
        BipedPoseStats {
            pitch_index: 1,
            rear_feet: 2..4,
            upright_pitch: 1.4,
            sums: PoseSums::default(),
        }
    }

    fn step(pitch: [f32; 3], rear: [[f32; 2]; 3], ended: [bool; 3], head: [bool; 3]) -> StepData {
        StepData {
            obs: pitch.iter().flat_map(|&p| [0.0, p, 0.0]).collect(),
            labels: rear.iter().flat_map(|r| [1.0, 1.0, r[0], r[1]]).collect(),
            privileged: Vec::new(),
            reward: vec![0.0; 3],
            reward_terms: None,
            terminated: ended.to_vec(),
            truncated: vec![false; 3],
            final_env_ids: Vec::new(),
            final_obs: Vec::new(),
            final_labels: Vec::new(),
            final_privileged: Vec::new(),
            mode: vec![1; 3],
            terrain_level: vec![0; 3],
            upright_pitch: None,
            head_contact: Some(head.to_vec()),
            nonfinite_resets: 0,
            mode_levels: Vec::new(),
        }
    }

    #[test]
    fn biped_pose_by_hand() {
        let mut stats = pose_stats();
        // Env 0 biped, upright, rear feet up; env 1 biped, head down, one rear foot down, head on
        // the ground; env 2 acted on four legs (not counted).
        let s = step(
            [1.5, 0.3, 1.6],
            [[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]],
            [false; 3],
            [false, true, true],
        );
        stats.add(&[1, 1, 2], &s, 3, 4);
        // Env 1 ended in this step: its state is the next episode's, left out.
        let s = step(
            [1.45, 0.0, 1.6],
            [[0.0, 0.0]; 3],
            [false, true, false],
            [false; 3],
        );
        stats.add(&[1, 1, 2], &s, 3, 4);
        let out = stats.summary();
        let get = |k: &str| out.iter().find(|(n, _)| n == k).expect(k).1;
        assert!((get("biped_pose/pitch") - (1.5 + 0.3 + 1.45) / 3.0).abs() < 1e-6);
        assert!((get("biped_pose/upright_share") - 2.0 / 3.0).abs() < 1e-12);
        assert!((get("biped_pose/rear_feet_up_share") - 2.0 / 3.0).abs() < 1e-12);
        assert!((get("biped_pose/head_contact_share") - 1.0 / 3.0).abs() < 1e-12);
        assert!(stats.summary().iter().all(|(_, v)| v.is_nan()), "cleared");
    }

    #[test]
    fn means_per_type_and_mode_by_hand() {
        let types: Vec<String> = ["a", "b", "a"].iter().map(|s| s.to_string()).collect();
        let mut stats = TerrainLevelStats::new(&types);
        stats.add(&[1, 4, 3], &[2, 1, 2]);
        stats.add(&[2, 6, 5], &[1, 1, 2]);
        let out = stats.summary();
        let get = |k: &str| out.iter().find(|(n, _)| n == k).expect(k).1;
        assert_eq!(get("terrain_level/a"), (1.0 + 3.0 + 2.0 + 5.0) / 4.0);
        assert_eq!(get("terrain_level/b"), 5.0);
        assert_eq!(get("terrain_level/quad"), (1.0 + 3.0 + 5.0) / 3.0);
        assert_eq!(get("terrain_level/biped"), (4.0 + 2.0 + 6.0) / 3.0);
        // Per type and mode, in the Python learner's order: "a" on four legs (1 + 3 + 5) / 3,
        // on two 2; "b" never on four legs, on two (4 + 6) / 2.
        assert_eq!(get("terrain_level/a/quad"), 3.0);
        assert_eq!(get("terrain_level/a/biped"), 2.0);
        assert!(get("terrain_level/b/quad").is_nan());
        assert_eq!(get("terrain_level/b/biped"), 5.0);
        let names: Vec<&str> = out.iter().map(|(n, _)| n.as_str()).take(8).collect();
        assert_eq!(
            names,
            [
                "terrain_level/a",
                "terrain_level/b",
                "terrain_level/quad",
                "terrain_level/biped",
                "terrain_level/a/quad",
                "terrain_level/a/biped",
                "terrain_level/b/quad",
                "terrain_level/b/biped",
            ]
        );
        // Cleared: no env-steps since, so every mean is NaN.
        assert!(stats.summary().iter().all(|(_, v)| v.is_nan()));
    }

    /// Three "a" envs and one "b": env 0 ends and comes back up, env 3 ends and stays; then env
    /// 1 ends and goes down, env 2 ends at the top and lands lower. Env 1's level in the first
    /// step does not count: it did not end.
    #[test]
    fn level_moves_per_type_by_hand() {
        let types: Vec<String> = ["a", "a", "a", "b"].iter().map(|s| s.to_string()).collect();
        let mut stats = TerrainLevelStats::new(&types);
        stats.add_episode_ends(&[2, 4, 6, 1], &[3, 5, 6, 1], &[true, false, false, true]);
        stats.add_episode_ends(&[3, 5, 9, 1], &[3, 4, 0, 1], &[false, true, true, false]);
        let out = stats.summary();
        let get = |k: &str| out.iter().find(|(n, _)| n == k).expect(k).1;
        assert!((get("promoted/a") - 1.0 / 3.0).abs() < 1e-12);
        assert!((get("demoted/a") - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!((get("promoted/b"), get("demoted/b")), (0.0, 0.0));
        let again = stats.summary();
        assert!(again.iter().all(|(_, v)| v.is_nan()), "cleared");
    }
}
