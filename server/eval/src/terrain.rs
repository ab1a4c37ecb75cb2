//! The terrain of a traversal scenario: one pinned tile of the obstacle.
//!
//! HOOK: this is the one place the traversal scenarios meet the terrain API. It builds
//! `unigait_sim::terrain::Terrain::from_spec` with `TerrainKind::Pinned` on a one-tile grid
//! (`num_levels = 1`, so the tile has the spec's top-level size: `step_height[1]`,
//! `max_slope_deg`); envs spawn on the tile's central platform and cross the obstacle walking out
//! of it. [`Obstacle::Flat`] is the plane.

use serde::Serialize;
use unigait_sim::terrain::{Terrain, TerrainKind, TerrainSpec, TerrainType};

use crate::error::EvalError;

/// The obstacle a traversal case crosses.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "type")]
pub enum Obstacle {
    /// Flat ground (nothing to cross: a sanity case).
    Flat,
    /// Pyramid stairs climbing up away from the spawn platform.
    StairsUp {
        /// Riser height (m).
        step_height: f32,
    },
    /// Pyramid stairs stepping down away from the spawn platform.
    StairsDown {
        /// Riser height (m).
        step_height: f32,
    },
    /// A planar slope rising away from the spawn platform.
    SlopeUp {
        /// Incline (deg).
        degrees: f32,
    },
    /// A planar slope falling away from the spawn platform.
    SlopeDown {
        /// Incline (deg).
        degrees: f32,
    },
}

impl Obstacle {
    /// The pinned one-tile terrain spec of this obstacle (None for flat ground).
    pub fn spec(&self) -> Option<TerrainSpec> {
        let (terrain_type, step, slope) = match *self {
            Obstacle::Flat => return None,
            Obstacle::StairsUp { step_height } => (TerrainType::StairsUp, step_height, 0.0),
            Obstacle::StairsDown { step_height } => (TerrainType::StairsDown, step_height, 0.0),
            Obstacle::SlopeUp { degrees } => (TerrainType::SlopeUp, 0.0, degrees),
            Obstacle::SlopeDown { degrees } => (TerrainType::SlopeDown, 0.0, degrees),
        };
        Some(TerrainSpec {
            kind: TerrainKind::Pinned {
                terrain_type,
                level: 0,
            },
            num_levels: 1,
            types: vec![terrain_type],
            step_height: [step, step],
            max_slope_deg: slope,
            ..TerrainSpec::default()
        })
    }

    /// Distance (m) from the tile centre (the spawn point) to the tile's outer edge, where the
    /// obstacle ends; flat ground uses the same distance so cases compare.
    pub fn half_extent(&self) -> f32 {
        0.5 * self.spec().unwrap_or_default().tile_size
    }
}

/// Build the terrain of `obstacle` (the hook; see the module doc).
pub fn obstacle_terrain(obstacle: &Obstacle, seed: u64) -> Result<Terrain, EvalError> {
    match obstacle.spec() {
        None => Ok(Terrain::Flat),
        Some(spec) => Ok(Terrain::from_spec(&spec, seed)?),
    }
}
