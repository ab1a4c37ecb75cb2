//! Terrains: the shape robots walk on, its rapier collider, and fast height queries.
//!
//! [`Terrain::Flat`] is the infinite plane z = 0. [`Terrain::Grid`] is legged_gym's curriculum
//! grid ([`TerrainGrid`], built from a [`TerrainSpec`]): tiles of flat ground, slopes, rough
//! slopes, stairs and obstacles in rows of growing difficulty. The grid's queries are plain
//! arithmetic on its stored cells and answer for exactly the surface its collider has: step faces
//! are vertical in both.

mod cells;
mod curriculum;
mod generator;
mod grid;
mod heightfield;
mod mesh;
mod spec;
mod surface;

use std::sync::Arc;

use rand::Rng;
use rapier3d::math::Vec3;
use rapier3d::prelude::{ColliderBuilder, SharedShape};

use crate::error::SimError;

pub use curriculum::{EpisodeDistance, LevelRule, Reach, initial_column, next_level};
pub use grid::TerrainGrid;
pub use spec::{
    DEFAULT_COLUMNS, TerrainCollider, TerrainKind, TerrainSpec, TerrainType, default_columns,
};

/// A terrain shared by every robot of a world.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Terrain {
    /// An infinite plane at z = 0.
    #[default]
    Flat,
    /// A generated curriculum grid (shared: cloning the terrain does not copy it).
    Grid(Arc<TerrainGrid>),
}

impl Terrain {
    /// The terrain of `spec`: [`Terrain::Flat`] for [`TerrainKind::Flat`], else the grid
    /// generated from `seed`.
    pub fn from_spec(spec: &TerrainSpec, seed: u64) -> Result<Terrain, SimError> {
        spec.validate()?;
        match spec.kind {
            TerrainKind::Flat => Ok(Terrain::Flat),
            TerrainKind::Curriculum { .. } | TerrainKind::Pinned { .. } => {
                Ok(Terrain::Grid(Arc::new(TerrainGrid::new(spec, seed)?)))
            }
        }
    }

    /// This terrain with env i of its curriculum starting at `levels[i]` (see
    /// [`TerrainGrid::set_initial_levels`]); refused on flat ground and on a grid already shared.
    pub fn with_initial_levels(self, levels: Vec<u32>) -> Result<Terrain, SimError> {
        let count = levels.len();
        self.with_grid("terrain.initial_levels", count, |grid| {
            grid.set_initial_levels(levels)
        })
    }

    /// This terrain with env i's modes starting at `levels[i]` (quad, biped; see
    /// [`TerrainGrid::set_initial_mode_levels`]); refused as [`Terrain::with_initial_levels`].
    pub fn with_initial_mode_levels(self, levels: Vec<[u32; 2]>) -> Result<Terrain, SimError> {
        let count = levels.len();
        self.with_grid("terrain.initial_mode_levels", count, |grid| {
            grid.set_initial_mode_levels(levels)
        })
    }

    fn with_grid(
        mut self,
        field: &str,
        count: usize,
        set: impl FnOnce(&mut TerrainGrid) -> Result<(), SimError>,
    ) -> Result<Terrain, SimError> {
        match &mut self {
            Terrain::Flat => Err(SimError::invalid(
                field,
                format!("{count} levels"),
                "only for the curriculum",
            )),
            Terrain::Grid(g) => match Arc::get_mut(g) {
                Some(grid) => {
                    set(grid)?;
                    Ok(self)
                }
                None => Err(SimError::invalid(
                    field,
                    "a shared grid",
                    "a grid of its own",
                )),
            },
        }
    }

    /// The grid, if this terrain is one.
    pub fn grid(&self) -> Option<&TerrainGrid> {
        match self {
            Terrain::Flat => None,
            Terrain::Grid(g) => Some(g),
        }
    }

    /// Terrain height at (x, y) (m).
    #[inline]
    pub fn height(&self, x: f32, y: f32) -> f32 {
        match self {
            Terrain::Flat => 0.0,
            Terrain::Grid(g) => g.height(x, y),
        }
    }

    /// Unit surface normal at (x, y).
    #[inline]
    pub fn normal(&self, x: f32, y: f32) -> Vec3 {
        match self {
            Terrain::Flat => Vec3::Z,
            Terrain::Grid(g) => g.normal(x, y),
        }
    }

    /// Highest terrain point within `radius` of (x, y) (m).
    #[inline]
    pub fn max_height_within(&self, x: f32, y: f32, radius: f32) -> f32 {
        match self {
            Terrain::Flat => 0.0,
            Terrain::Grid(g) => g.max_height_within(x, y, radius),
        }
    }

    /// The rapier collider of this terrain (for a fixed body at the origin).
    pub fn collider(&self) -> ColliderBuilder {
        match self {
            Terrain::Flat => ColliderBuilder::new(SharedShape::halfspace(Vec3::Z)),
            Terrain::Grid(g) => g.collider(),
        }
    }

    /// Spawn origin (x, y) of env `index` of `count`. On flat ground the envs stand on a grid 3 m
    /// apart so recordings are readable (robots never collide with each other anyway). On a grid,
    /// the centre of the env's [`TerrainGrid::deterministic_tile`] (the env layer draws the real
    /// starting tile with [`Terrain::initial_tile`] and spawns at [`TerrainGrid::tile_origin`]).
    pub fn env_origin(&self, index: usize, count: usize) -> (f32, f32) {
        match self {
            Terrain::Flat => {
                let cols = (count as f32).sqrt().ceil().max(1.0) as usize;
                let spacing = 3.0;
                (
                    (index % cols) as f32 * spacing,
                    (index / cols) as f32 * spacing,
                )
            }
            Terrain::Grid(g) => {
                let (level, column) = g.deterministic_tile(index, count);
                let o = g.tile_origin(level, column);
                (o.x, o.y)
            }
        }
    }

    /// Starting tile (level, column) of env `index` of `count` (see
    /// [`TerrainGrid::initial_tile`]); (0, 0) on flat ground.
    pub fn initial_tile(&self, index: usize, count: usize, rng: &mut impl Rng) -> (u32, u32) {
        match self {
            Terrain::Flat => (0, 0),
            Terrain::Grid(g) => g.initial_tile(index, count, rng),
        }
    }
}
