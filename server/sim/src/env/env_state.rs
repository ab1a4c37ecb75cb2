//! The episode state of one env: RNG, mode, commands, clocks, action history, randomisation.

use std::f32::consts::PI;

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use rapier3d::math::Rotation;

use crate::robot::NUM_JOINTS;
use crate::task::{
    CommandRanges, FeetAirTime, Randomization, TaskConfig, TaskMode, heading_hold, heading_yaw,
    uniform,
};
use crate::terrain::EpisodeDistance;

use super::EnvId;

/// Per-env episode state (everything that is not physics).
#[derive(Clone, Debug)]
pub struct EnvState {
    /// Which env this is.
    pub id: EnvId,
    /// The env's own random stream (seeded from the batch seed and the env index).
    pub rng: ChaCha8Rng,
    /// Current task mode.
    pub mode: TaskMode,
    /// Velocity command (vx, vy in the heading frame, wz).
    pub command: [f32; 3],
    /// The heading (rad, world) this command holds, if its draw holds one
    /// (`commands.heading_share`): its wz then steers to it every step ([`Self::hold_heading`]).
    pub held_heading: Option<f32>,
    /// Policy steps since the episode began.
    pub episode_step: u32,
    /// Actions a_t, a_{t-1}, a_{t-2} (clipped).
    pub actions: [[f32; NUM_JOINTS]; 3],
    /// Joint speeds at the previous policy step.
    pub last_qd: [f32; NUM_JOINTS],
    /// Each foot's time in the air, for the feet-air-time term.
    pub feet_air: FeetAirTime,
    /// Randomised physical values of this episode.
    pub randomization: Randomization,
    /// Spawn point (world x, y) of this episode.
    pub origin: [f32; 2],
    /// Terrain difficulty level (row of the terrain grid) of the tile this episode is on.
    pub terrain_level: u32,
    /// Each mode's own level (quad, biped) when the curriculum keeps one per mode
    /// (`terrain_curriculum.per_mode_levels`, decision record 0036); unused otherwise.
    pub mode_levels: [u32; 2],
    /// The mode this episode started in.
    pub episode_mode: TaskMode,
    /// Terrain type (column of the terrain grid).
    pub terrain_type: u32,
    /// This episode's walked and commanded distances, for the terrain curriculum.
    pub distance: EpisodeDistance,
}

/// Draw a command from `ranges`; components below `zero_below` in magnitude become 0.
pub fn sample_command(ranges: &CommandRanges, zero_below: f32, rng: &mut ChaCha8Rng) -> [f32; 3] {
    let mut c = [
        uniform(rng, ranges.vx),
        uniform(rng, ranges.vy),
        uniform(rng, ranges.wz),
    ];
    for v in &mut c {
        if v.abs() < zero_below {
            *v = 0.0;
        }
    }
    c
}

impl EnvState {
    /// Draw a task mode from the env's stream without entering it.
    pub fn draw_mode(&mut self, cfg: &TaskConfig) -> TaskMode {
        let biped = self.rng.random::<f32>() < cfg.modes.biped_probability;
        if biped {
            TaskMode::Biped
        } else {
            TaskMode::Quad
        }
    }

    /// Enter `mode` and settle the command that goes with it: the one place a mode change
    /// happens, for the episode's own draws and for a caller's switch alike.
    ///
    /// `command` Some: that command from now on. None: a fresh draw from the new mode's ranges
    /// when the mode changed (an old command may be out of the new mode's reach, e.g. 1.5 m/s in
    /// biped mode) or when `redraw` asks for one (the command schedule is due), else the current
    /// command stays. At most one command is drawn, so the env's random stream advances exactly
    /// as it always has. The gait clock runs on the episode step and is left alone: a mode change
    /// swaps the phase offsets it is read with, not the clock. Returns whether the mode changed.
    pub fn enter_mode(
        &mut self,
        cfg: &TaskConfig,
        mode: TaskMode,
        command: Option<[f32; 3]>,
        redraw: bool,
    ) -> bool {
        let changed = self.mode != mode;
        self.mode = mode;
        match command {
            Some(c) => {
                self.command = c;
                self.held_heading = None;
            }
            None if changed || redraw => self.sample_command(cfg),
            None => {}
        }
        changed
    }

    /// Draw commands for the current mode, and whether they hold a heading. At
    /// `heading_share` 0 no heading is drawn, so the random stream is the paper task's.
    pub fn sample_command(&mut self, cfg: &TaskConfig) {
        let c = &cfg.commands;
        self.command = sample_command(self.command_ranges(cfg), c.zero_below, &mut self.rng);
        self.held_heading = None;
        if c.heading_share > 0.0 && self.rng.random::<f32>() < c.heading_share {
            self.held_heading = Some(uniform(&mut self.rng, [-PI, PI]));
        }
    }

    /// Steer the yaw-rate command to the held heading from the body's orientation `rot`, if
    /// this command holds one (decision record 0042); otherwise leave it (and skip the yaw).
    pub fn hold_heading(&mut self, cfg: &TaskConfig, rot: Rotation) {
        if let Some(target) = self.held_heading {
            let range = self.command_ranges(cfg).wz;
            let yaw = heading_yaw(rot);
            self.command[2] = heading_hold(target, yaw, cfg.commands.heading_gain, range);
        }
    }

    fn command_ranges<'a>(&self, cfg: &'a TaskConfig) -> &'a CommandRanges {
        match self.mode {
            TaskMode::Biped => &cfg.commands.biped,
            TaskMode::Quad => &cfg.commands.quad,
        }
    }

    /// Gait clock Phi in [0, 1) at the current step.
    pub fn gait_phase(&self, cfg: &TaskConfig) -> f32 {
        let t = self.episode_step as f32 * cfg.policy_dt();
        (t / cfg.gait.period_s).rem_euclid(1.0)
    }

    /// Phase offsets per foot for the current mode.
    pub fn gait_offsets(&self, cfg: &TaskConfig) -> [f32; 4] {
        match self.mode {
            TaskMode::Biped => cfg.gait.offsets_biped,
            TaskMode::Quad => cfg.gait.offsets_quad,
        }
    }
}
