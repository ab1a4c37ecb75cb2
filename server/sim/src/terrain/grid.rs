//! A generated curriculum grid: its heights, its rapier collider (built once, shared by every
//! world), its tiles' spawn points, and where envs start on it.

use rand::{Rng, RngExt};
use rapier3d::math::{Pose, Vec3};
use rapier3d::prelude::{ColliderBuilder, SharedShape};

use crate::error::SimError;

use super::cells::CellGrid;
use super::curriculum::{self, EpisodeDistance, LevelRule, initial_column};
use super::generator::generate;
use super::heightfield::heightfield;
use super::mesh::trimesh;
use super::spec::{TerrainCollider, TerrainKind, TerrainSpec, TerrainType};

/// Side of the central square whose highest point is a tile's spawn height (m), as legged_gym.
const ORIGIN_SQUARE: f32 = 2.0;

/// The curriculum grid of a [`TerrainSpec`]: tiles of `tile_size` with level `l` along +x
/// (x in [l, l+1) * tile_size) and column `c` along +y, a flat border at z = 0 around it.
pub struct TerrainGrid {
    spec: TerrainSpec,
    seed: u64,
    cells: CellGrid,
    /// Spawn height of each tile, `level * columns + column` (m).
    origin_heights: Vec<f32>,
    /// The collider's shape (shared, never copied) and pose.
    shape: SharedShape,
    pose: Pose,
    /// A curriculum's starting level of each env by index (a resumed run's levels); empty: the
    /// level is drawn from `0..=max_init_level`.
    initial_levels: Vec<u32>,
    /// Each env's starting (quad, biped) levels, when a resumed run keeps a level per mode.
    initial_mode_levels: Vec<[u32; 2]>,
}

impl std::fmt::Debug for TerrainGrid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TerrainGrid")
            .field("spec", &self.spec)
            .field("seed", &self.seed)
            .field("cells", &(self.cells.nx(), self.cells.ny()))
            .finish_non_exhaustive()
    }
}

/// Grids are generated deterministically: the same spec and seed make the same grid.
impl PartialEq for TerrainGrid {
    fn eq(&self, other: &Self) -> bool {
        self.spec == other.spec && self.seed == other.seed
    }
}

impl TerrainGrid {
    /// Generate the grid of `spec` from `seed` and build its collider. The spec's `kind` only
    /// decides placement and level changes; the grid is built whatever it is.
    pub fn new(spec: &TerrainSpec, seed: u64) -> Result<Self, SimError> {
        spec.validate()?;
        let cells = generate(spec, seed);
        let (shape, pose) = match spec.collider {
            TerrainCollider::Trimesh => (trimesh(&cells, spec.border)?, Pose::IDENTITY),
            TerrainCollider::Heightfield { subdivisions } => {
                heightfield(&cells, spec.border, subdivisions)
            }
        };
        let mut grid = Self {
            spec: spec.clone(),
            seed,
            cells,
            origin_heights: Vec::new(),
            shape,
            pose,
            initial_levels: Vec::new(),
            initial_mode_levels: Vec::new(),
        };
        grid.origin_heights = (0..spec.num_levels)
            .flat_map(|level| (0..spec.types.len() as u32).map(move |column| (level, column)))
            .map(|(level, column)| grid.central_max_height(level, column))
            .collect();
        Ok(grid)
    }

    /// The spec the grid was built from.
    pub fn spec(&self) -> &TerrainSpec {
        &self.spec
    }

    /// The seed the grid was built from.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Number of levels (rows along x).
    pub fn num_levels(&self) -> u32 {
        self.spec.num_levels
    }

    /// Number of columns (along y).
    pub fn num_columns(&self) -> u32 {
        self.spec.types.len() as u32
    }

    /// The terrain type of `column`, if it exists.
    pub fn column_type(&self, column: u32) -> Option<TerrainType> {
        self.spec.types.get(column as usize).copied()
    }

    /// Terrain height at (x, y) (m). A step is a step: on either side of its face the height is
    /// that side's tread.
    #[inline]
    pub fn height(&self, x: f32, y: f32) -> f32 {
        self.cells.height(x, y)
    }

    /// Unit normal of the face under (x, y).
    #[inline]
    pub fn normal(&self, x: f32, y: f32) -> Vec3 {
        self.cells.normal(x, y)
    }

    /// Highest terrain point within `radius` of (x, y) (m); a step face within the radius
    /// counts with its top.
    #[inline]
    pub fn max_height_within(&self, x: f32, y: f32, radius: f32) -> f32 {
        self.cells.max_height_within(x, y, radius)
    }

    /// The collider: the shared shape at its pose (a mesh at the origin, or a heightfield turned
    /// Z-up), for a fixed body at the origin.
    pub fn collider(&self) -> ColliderBuilder {
        ColliderBuilder::new(self.shape.clone()).position(self.pose)
    }

    /// Centre of tile (`level`, `column`) with z the highest point of its central 2 m x 2 m
    /// (legged_gym's env origin). Out-of-range indices are clamped to the grid.
    pub fn tile_origin(&self, level: u32, column: u32) -> Vec3 {
        let level = level.min(self.num_levels() - 1);
        let column = column.min(self.num_columns() - 1);
        let t = self.spec.tile_size;
        let z = self.origin_heights[(level * self.num_columns() + column) as usize];
        Vec3::new((level as f32 + 0.5) * t, (column as f32 + 0.5) * t, z)
    }

    fn central_max_height(&self, level: u32, column: u32) -> f32 {
        let t = self.spec.tile_size;
        let (cx, cy) = ((level as f32 + 0.5) * t, (column as f32 + 0.5) * t);
        let h = 0.5 * ORIGIN_SQUARE.min(t);
        self.cells
            .max_height_in_square(cx - h, cy - h, cx + h, cy + h)
    }

    /// Start env i of a curriculum at `levels[i]` rather than at a drawn level: a resumed run
    /// carries its envs' levels over instead of climbing back from `0..=max_init_level`.
    /// Refused for a kind other than a curriculum and for a level off the grid.
    pub fn set_initial_levels(&mut self, levels: Vec<u32>) -> Result<(), SimError> {
        self.check_initial("terrain.initial_levels", &levels)?;
        self.initial_levels = levels;
        Ok(())
    }

    /// Start env i's modes at `levels[i]` (quad, biped) when the task keeps a level per mode
    /// (decision record 0036): a resumed run carries both over. Checked as
    /// [`TerrainGrid::set_initial_levels`].
    pub fn set_initial_mode_levels(&mut self, levels: Vec<[u32; 2]>) -> Result<(), SimError> {
        self.check_initial("terrain.initial_mode_levels", levels.as_flattened())?;
        self.initial_mode_levels = levels;
        Ok(())
    }

    /// Env `env_index`'s starting (quad, biped) levels, if the session gave them.
    pub fn initial_mode_levels(&self, env_index: usize) -> Option<[u32; 2]> {
        self.initial_mode_levels.get(env_index).copied()
    }

    fn check_initial(&self, field: &str, levels: &[u32]) -> Result<(), SimError> {
        if !matches!(self.spec.kind, TerrainKind::Curriculum { .. }) {
            return Err(SimError::invalid(
                field,
                format!("{} levels", levels.len()),
                "only for the curriculum",
            ));
        }
        if let Some((i, level)) = levels
            .iter()
            .enumerate()
            .find(|(_, l)| **l >= self.num_levels())
        {
            return Err(SimError::invalid(
                format!("{field}[{i}]"),
                level,
                format!("0..{}", self.num_levels()),
            ));
        }
        Ok(())
    }

    /// The starting tile (level, column) of env `env_index` of `num_envs`: columns by env
    /// index as legged_gym (`column = index * columns / num_envs`), the level uniform in
    /// `0..=max_init_level` for a curriculum (or the env's entry of
    /// [`TerrainGrid::set_initial_levels`]), the pinned tile for a pinned kind, (0, 0) for flat.
    pub fn initial_tile(
        &self,
        env_index: usize,
        num_envs: usize,
        rng: &mut impl Rng,
    ) -> (u32, u32) {
        match self.spec.kind {
            TerrainKind::Flat => (0, 0),
            TerrainKind::Curriculum { max_init_level } => {
                let level = match self.initial_levels.get(env_index) {
                    Some(&level) => level,
                    None => rng.random_range(0..=max_init_level.min(self.num_levels() - 1)),
                };
                (
                    level,
                    initial_column(env_index, num_envs, self.num_columns()),
                )
            }
            TerrainKind::Pinned {
                terrain_type,
                level,
            } => (level, self.spec.column_of(terrain_type).unwrap_or(0)),
        }
    }

    /// A deterministic stand-in for [`TerrainGrid::initial_tile`] (no random draw): the same
    /// column, and level `env_index % (max_init_level + 1)` for a curriculum, so n envs with n a
    /// multiple of columns * (max_init_level + 1) cover every starting tile.
    pub fn deterministic_tile(&self, env_index: usize, num_envs: usize) -> (u32, u32) {
        match self.spec.kind {
            TerrainKind::Curriculum { max_init_level } => {
                let levels = max_init_level.min(self.num_levels() - 1) as usize + 1;
                (
                    (env_index % levels) as u32,
                    initial_column(env_index, num_envs, self.num_columns()),
                )
            }
            TerrainKind::Flat => (0, 0),
            TerrainKind::Pinned {
                terrain_type,
                level,
            } => (level, self.spec.column_of(terrain_type).unwrap_or(0)),
        }
    }

    /// The level after `episode` (what the env walked against what its commands asked for):
    /// [`curriculum::next_level`] with `rule` for a curriculum, unchanged for a pinned or flat
    /// kind.
    pub fn next_level(
        &self,
        current: u32,
        episode: EpisodeDistance,
        rule: &LevelRule,
        rng: &mut impl Rng,
    ) -> u32 {
        match self.spec.kind {
            TerrainKind::Curriculum { .. } => {
                curriculum::next_level(current, episode, rule, self.num_levels(), rng)
            }
            TerrainKind::Flat | TerrainKind::Pinned { .. } => current,
        }
    }
}

#[cfg(test)]
#[path = "grid_test.rs"]
mod test;
