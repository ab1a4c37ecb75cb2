//! What terrain to build: the curriculum grid's parameters, the terrain types, and how envs are
//! placed on it. Plain data with documented defaults; [`TerrainSpec::validate`] checks ranges.

use serde::{Deserialize, Serialize};

use crate::error::SimError;

/// One column of the curriculum grid: the shape of its tiles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TerrainType {
    /// Flat ground.
    Flat,
    /// Pyramid pit with planar faces: the robot walks uphill leaving the centre.
    SlopeUp,
    /// Pyramid hill with planar faces: the robot walks downhill leaving the centre.
    SlopeDown,
    /// The hill of [`TerrainType::SlopeDown`] plus uniform noise (legged_gym's rough slope).
    RoughSlope,
    /// Pyramid stairs around a pit: the robot climbs up leaving the centre.
    StairsUp,
    /// Pyramid stairs around a raised platform: the robot steps down leaving the centre.
    StairsDown,
    /// Random rectangles raised or sunk by up to the level's obstacle height.
    Obstacles,
}

impl TerrainType {
    /// Every type (the order of names in configs and logs; not the grid's column order, which
    /// is [`TerrainSpec::types`]).
    pub const ALL: [TerrainType; 7] = [
        TerrainType::Flat,
        TerrainType::SlopeUp,
        TerrainType::SlopeDown,
        TerrainType::RoughSlope,
        TerrainType::StairsUp,
        TerrainType::StairsDown,
        TerrainType::Obstacles,
    ];

    /// The type's name (as in configs and logs).
    pub fn name(self) -> &'static str {
        match self {
            TerrainType::Flat => "flat",
            TerrainType::SlopeUp => "slope_up",
            TerrainType::SlopeDown => "slope_down",
            TerrainType::RoughSlope => "rough_slope",
            TerrainType::StairsUp => "stairs_up",
            TerrainType::StairsDown => "stairs_down",
            TerrainType::Obstacles => "obstacles",
        }
    }

    /// The type called `name`, if any.
    pub fn from_name(name: &str) -> Option<TerrainType> {
        TerrainType::ALL.into_iter().find(|t| t.name() == name)
    }
}

impl std::fmt::Display for TerrainType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Which terrain a batch runs on and how its envs move over it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum TerrainKind {
    /// The infinite plane z = 0 ([`crate::terrain::Terrain::Flat`]); the grid parameters are
    /// ignored.
    #[default]
    Flat,
    /// The whole grid with legged_gym's game-inspired curriculum: env i starts in column
    /// `i * columns / num_envs` at a level drawn uniformly from `0..=max_init_level`, and moves
    /// up or down a level at each reset.
    Curriculum {
        /// Highest initial level (legged_gym: 5).
        max_init_level: u32,
    },
    /// Every env on one tile, which never changes (evaluation on a given terrain).
    Pinned {
        /// The tile's type (must be one of the grid's `types`).
        terrain_type: TerrainType,
        /// The tile's level.
        level: u32,
    },
}

/// How the grid becomes a rapier collider.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum TerrainCollider {
    /// A triangle mesh with exactly vertical step faces and flat areas merged into large
    /// triangles (measured faster than the heightfield and correct at stair edges).
    #[default]
    Trimesh,
    /// A parry heightfield sampled `subdivisions` times per grid cell. A heightfield cannot hold
    /// a vertical face: every step becomes a ramp one sample wide. Kept for comparison only.
    Heightfield {
        /// Samples per grid cell along each axis (1 ..= 8).
        subdivisions: u32,
    },
}

/// The terrain of a batch: the curriculum grid's shape and how envs are placed on it.
///
/// The grid has `num_levels` rows of difficulty along +x and one column per entry of `types`
/// along +y; tile (level l, column c) covers x in [l, l+1) * tile_size, y in [c, c+1) * tile_size.
/// Difficulty `d = level / (num_levels - 1)` runs from 0 at level 0 to 1 at the top level (d = 1
/// with a single level); each shape parameter below interpolates linearly in d.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TerrainSpec {
    /// Flat, curriculum or pinned.
    pub kind: TerrainKind,
    /// Difficulty levels (grid rows).
    pub num_levels: u32,
    /// Terrain type of each grid column, in order. Repeat a type to give it more columns
    /// (legged_gym's `terrain_proportions`).
    pub types: Vec<TerrainType>,
    /// Side of a square tile (m).
    pub tile_size: f32,
    /// Flat ground around the grid (m).
    pub border: f32,
    /// Grid cell size (m); `tile_size` must be a whole number of cells. Step faces and obstacle
    /// sides lie on cell edges.
    pub horizontal_scale: f32,
    /// Side of the flat square at every tile's centre, where envs spawn (m).
    pub platform_size: f32,
    /// Slope angle at the top level (deg). The slope (rise over run) grows linearly with d from
    /// 0, as legged_gym's `slope = 0.4 d`, so level l has atan(d tan(max_slope_deg)).
    pub max_slope_deg: f32,
    /// Step height at level 0 and at the top level (m).
    pub step_height: [f32; 2],
    /// Horizontal depth of a step (m), rounded to whole cells.
    pub step_width: f32,
    /// Obstacle height at level 0 and at the top level (m); each obstacle is raised or sunk by
    /// this height or half of it.
    pub obstacle_height: [f32; 2],
    /// Obstacles per tile.
    pub num_obstacles: u32,
    /// Smallest and largest obstacle side (m), rounded to whole cells.
    pub obstacle_size: [f32; 2],
    /// Noise of the rough slope: heights uniform in [-this, this] (m).
    pub rough_noise: f32,
    /// The noise is quantised to multiples of this (m).
    pub rough_noise_step: f32,
    /// The noise is drawn on a grid of this spacing and interpolated linearly (m).
    pub rough_noise_spacing: f32,
    /// Collider representation.
    pub collider: TerrainCollider,
}

/// The default grid columns: legged_gym's `terrain_proportions` [0.1, 0.1, 0.35, 0.25, 0.2]
/// (smooth slope, rough slope, stairs up, stairs down, discrete) over its 20 columns. Stairs take
/// 12 of 20 columns (60 %); the former default, one column per type, gave them 2 of 7 (29 %),
/// which starved the terrain the paper tests most (Table VI: 15 cm stairs up and down, 12 cm
/// stairs up). No flat column: level 0 of every type is flat or nearly so (0 deg, 5 cm steps).
pub const DEFAULT_COLUMNS: [(TerrainType, usize); 6] = [
    // Smooth slope 0.1: half pits (uphill away from the centre), half hills, as legged_gym.
    (TerrainType::SlopeUp, 1),
    (TerrainType::SlopeDown, 1),
    // Rough slope 0.1.
    (TerrainType::RoughSlope, 2),
    // Stairs up 0.35, stairs down 0.25.
    (TerrainType::StairsUp, 7),
    (TerrainType::StairsDown, 5),
    // Discrete obstacles 0.2.
    (TerrainType::Obstacles, 4),
];

/// [`DEFAULT_COLUMNS`] expanded: one entry per grid column, in order.
pub fn default_columns() -> Vec<TerrainType> {
    DEFAULT_COLUMNS
        .iter()
        .flat_map(|&(t, n)| std::iter::repeat_n(t, n))
        .collect()
}

impl Default for TerrainSpec {
    fn default() -> Self {
        Self {
            // The half-space: the default terrain.
            kind: TerrainKind::Flat,
            // 10 levels (legged_gym num_rows).
            num_levels: 10,
            // legged_gym's proportions over 20 columns (see DEFAULT_COLUMNS).
            types: default_columns(),
            // 8 m (legged_gym terrain_length / terrain_width).
            tile_size: 8.0,
            // 25 m (legged_gym border_size); costs the mesh only four rectangles.
            border: 25.0,
            // 0.1 m (legged_gym horizontal_scale).
            horizontal_scale: 0.1,
            // 3 m (legged_gym platform_size).
            platform_size: 3.0,
            // 37 deg at the top (tan 0.754), slope linear in d: level 7 (d = 7/9) is 30.4 deg,
            // the paper's 30 deg test slope (Table VI, quad and biped), with two levels beyond it
            // (8: 33.8, 9: 37.0). Before: 30 deg linear in angle, so 30 deg only at the top.
            max_slope_deg: 37.0,
            // [0.05, 0.20] m (legged_gym 0.05 + 0.18 d reaches 0.21 at its top d = 0.9): 0.15 m,
            // the paper's stairs (quad up/down, biped down), at level 6 (d = 2/3), 0.117 / 0.133 m
            // (biped's 12 cm up) at levels 4 / 5, and 0.167 / 0.183 / 0.20 m above. Before:
            // [0.05, 0.23], with 0.15 m at level 5 and the top 8 cm beyond the test stairs.
            step_height: [0.05, 0.20],
            // 0.31 m (legged_gym), 0.30 m after rounding to 0.1 m cells (as in legged_gym).
            step_width: 0.31,
            // [0.05, 0.25] m: legged_gym's 0.05 + 0.2 d with d reaching 1.
            obstacle_height: [0.05, 0.25],
            // 20 rectangles per tile (legged_gym).
            num_obstacles: 20,
            // 1 to 2 m sides (legged_gym).
            obstacle_size: [1.0, 2.0],
            // +-0.05 m (legged_gym random_uniform_terrain).
            rough_noise: 0.05,
            // 0.005 m (legged_gym).
            rough_noise_step: 0.005,
            // 0.2 m (legged_gym downsampled_scale).
            rough_noise_spacing: 0.2,
            // Triangle mesh with vertical step faces.
            collider: TerrainCollider::Trimesh,
        }
    }
}

/// A check failure for `field` (prefixed with `terrain.`).
fn invalid(field: &str, value: impl std::fmt::Display, allowed: &str) -> SimError {
    SimError::invalid(format!("terrain.{field}"), value, allowed)
}

/// `value` must be finite and within [lo, hi].
fn check_range(field: &str, value: f32, lo: f32, hi: f32) -> Result<(), SimError> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(invalid(
            field,
            value,
            &format!("allowed range [{lo}, {hi}]"),
        ))
    }
}

/// `pair` must be an increasing (or equal) pair within [lo, hi].
fn check_pair(field: &str, pair: [f32; 2], lo: f32, hi: f32) -> Result<(), SimError> {
    check_range(field, pair[0], lo, hi)?;
    check_range(field, pair[1], lo, hi)?;
    if pair[0] > pair[1] {
        return Err(invalid(
            field,
            format!("{pair:?}"),
            "the first value must not exceed the second",
        ));
    }
    Ok(())
}

/// Whole cells in `length` (m) at `cell` (m), if it is a whole number within 1e-4 of a cell.
pub(crate) fn whole_cells(length: f32, cell: f32) -> Option<usize> {
    let n = (length / cell).round();
    ((n * cell - length).abs() <= 1e-4 * cell.max(1.0) && n >= 1.0).then_some(n as usize)
}

impl TerrainSpec {
    /// Difficulty in [0, 1] of `level`: level / (num_levels - 1), or 1 with a single level.
    pub fn difficulty(&self, level: u32) -> f32 {
        if self.num_levels <= 1 {
            1.0
        } else {
            level.min(self.num_levels - 1) as f32 / (self.num_levels - 1) as f32
        }
    }

    /// Slope (rise over run) of the slope tiles at `level`: d tan(max_slope_deg).
    pub fn slope(&self, level: u32) -> f32 {
        self.difficulty(level) * self.max_slope_deg.to_radians().tan()
    }

    /// Step height of the stair tiles at `level` (m).
    pub fn step_height_at(&self, level: u32) -> f32 {
        lerp(self.step_height, self.difficulty(level))
    }

    /// Obstacle height of the obstacle tiles at `level` (m).
    pub fn obstacle_height_at(&self, level: u32) -> f32 {
        lerp(self.obstacle_height, self.difficulty(level))
    }

    /// Grid cells per tile side.
    pub fn cells_per_tile(&self) -> usize {
        whole_cells(self.tile_size, self.horizontal_scale).unwrap_or(1)
    }

    /// Step width in whole cells (at least one).
    pub fn step_cells(&self) -> usize {
        ((self.step_width / self.horizontal_scale).round() as usize).max(1)
    }

    /// Platform side in whole cells (rounded up, so the platform is at least `platform_size`).
    pub fn platform_cells(&self) -> usize {
        ((self.platform_size / self.horizontal_scale) - 1e-4)
            .ceil()
            .max(0.0) as usize
    }

    /// The grid column of `terrain_type` (its first occurrence in `types`).
    pub fn column_of(&self, terrain_type: TerrainType) -> Option<u32> {
        self.types
            .iter()
            .position(|t| *t == terrain_type)
            .map(|c| c as u32)
    }

    /// Check every value against its allowed range.
    pub fn validate(&self) -> Result<(), SimError> {
        if !(1..=100).contains(&self.num_levels) {
            return Err(invalid(
                "num_levels",
                self.num_levels,
                "allowed range [1, 100]",
            ));
        }
        if self.types.is_empty() || self.types.len() > 100 {
            return Err(invalid(
                "types",
                self.types.len(),
                "between 1 and 100 columns",
            ));
        }
        check_range("horizontal_scale", self.horizontal_scale, 0.005, 1.0)?;
        check_range("tile_size", self.tile_size, 1.0, 100.0)?;
        if whole_cells(self.tile_size, self.horizontal_scale).is_none() {
            return Err(invalid(
                "tile_size",
                self.tile_size,
                "a whole number of horizontal_scale cells",
            ));
        }
        if self.cells_per_tile() > 4096 {
            return Err(invalid(
                "horizontal_scale",
                self.horizontal_scale,
                "at most 4096 cells per tile side",
            ));
        }
        check_range("border", self.border, 0.0, 1000.0)?;
        check_range("platform_size", self.platform_size, 0.0, self.tile_size)?;
        check_range("max_slope_deg", self.max_slope_deg, 0.0, 60.0)?;
        check_pair("step_height", self.step_height, 0.0, 1.0)?;
        check_range(
            "step_width",
            self.step_width,
            self.horizontal_scale,
            self.tile_size,
        )?;
        check_pair("obstacle_height", self.obstacle_height, 0.0, 2.0)?;
        if self.num_obstacles > 1000 {
            return Err(invalid(
                "num_obstacles",
                self.num_obstacles,
                "allowed range [0, 1000]",
            ));
        }
        check_pair(
            "obstacle_size",
            self.obstacle_size,
            self.horizontal_scale,
            self.tile_size,
        )?;
        check_range("rough_noise", self.rough_noise, 0.0, 1.0)?;
        check_range("rough_noise_step", self.rough_noise_step, 1e-4, 1.0)?;
        check_range(
            "rough_noise_spacing",
            self.rough_noise_spacing,
            self.horizontal_scale,
            self.tile_size,
        )?;
        if let TerrainCollider::Heightfield { subdivisions } = self.collider
            && !(1..=8).contains(&subdivisions)
        {
            return Err(invalid(
                "collider.heightfield.subdivisions",
                subdivisions,
                "allowed range [1, 8]",
            ));
        }
        match &self.kind {
            TerrainKind::Flat => {}
            TerrainKind::Curriculum { max_init_level } => {
                if *max_init_level >= self.num_levels {
                    return Err(invalid(
                        "kind.curriculum.max_init_level",
                        max_init_level,
                        &format!("below num_levels ({})", self.num_levels),
                    ));
                }
            }
            TerrainKind::Pinned {
                terrain_type,
                level,
            } => {
                if *level >= self.num_levels {
                    return Err(invalid(
                        "kind.pinned.level",
                        level,
                        &format!("below num_levels ({})", self.num_levels),
                    ));
                }
                if self.column_of(*terrain_type).is_none() {
                    return Err(invalid(
                        "kind.pinned.terrain_type",
                        terrain_type,
                        "one of the grid's `types`",
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Linear interpolation from `range[0]` at t = 0 to `range[1]` at t = 1.
fn lerp(range: [f32; 2], t: f32) -> f32 {
    range[0] + (range[1] - range[0]) * t
}

#[cfg(test)]
#[path = "spec_test.rs"]
mod test;
