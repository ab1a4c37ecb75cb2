//! The curriculum grid generator: one tile per (level, column), each shaped by its terrain type
//! and the level's difficulty. Deterministic: tile (level, column) draws from its own stream of
//! the seed, so a tile does not depend on the others.
//!
//! Every tile is at height 0 along its outer edge, so neighbouring tiles always meet; steps and
//! obstacle sides are flat cells next to each other (vertical faces on cell edges), slopes are
//! triangles through the vertex heights.

use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::cells::CellGrid;
use super::spec::{TerrainSpec, TerrainType};

/// Build the heights of the whole grid of `spec` (validated) from `seed`.
pub(crate) fn generate(spec: &TerrainSpec, seed: u64) -> CellGrid {
    let n = spec.cells_per_tile();
    let levels = spec.num_levels as usize;
    let columns = spec.types.len();
    let mut grid = CellGrid::new(levels * n, columns * n, spec.horizontal_scale);
    for level in 0..levels {
        for (column, &terrain_type) in spec.types.iter().enumerate() {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream((level * columns + column) as u64);
            let mut tile = Tile {
                grid: &mut grid,
                i0: level * n,
                j0: column * n,
                n,
            };
            shape_tile(&mut tile, spec, terrain_type, level as u32, &mut rng);
        }
    }
    grid
}

/// One tile of the grid: cells `i0 .. i0 + n` x `j0 .. j0 + n`.
struct Tile<'a> {
    grid: &'a mut CellGrid,
    i0: usize,
    j0: usize,
    n: usize,
}

impl Tile<'_> {
    /// Tile side (m).
    fn size(&self) -> f32 {
        self.n as f32 * self.grid.cell()
    }

    /// Make every cell a horizontal face at `height(a, b)` (tile cell indices).
    fn fill_flat(&mut self, height: impl Fn(usize, usize) -> f32) {
        for b in 0..self.n {
            for a in 0..self.n {
                self.grid.set_flat(self.i0 + a, self.j0 + b, height(a, b));
            }
        }
    }

    /// Make every cell two triangles through the vertex heights `height(u, v)` (tile
    /// coordinates, m). Each cell is split along the diagonal whose midpoint lies closest to
    /// `height` at the cell centre, so creases along diagonals (a pyramid's ridges) are exact.
    fn fill_triangles(&mut self, height: impl Fn(f32, f32) -> f32) {
        let s = self.grid.cell();
        for b in 0..=self.n {
            for a in 0..=self.n {
                let h = height(a as f32 * s, b as f32 * s);
                self.grid.set_vertex(self.i0 + a, self.j0 + b, h);
            }
        }
        for b in 0..self.n {
            for a in 0..self.n {
                let (i, j) = (self.i0 + a, self.j0 + b);
                let centre = height((a as f32 + 0.5) * s, (b as f32 + 0.5) * s);
                let main = 0.5 * (self.grid.vertex(i, j) + self.grid.vertex(i + 1, j + 1));
                let other = 0.5 * (self.grid.vertex(i + 1, j) + self.grid.vertex(i, j + 1));
                let main_diagonal = (main - centre).abs() <= (other - centre).abs();
                self.grid.set_triangles(i, j, main_diagonal);
            }
        }
    }
}

fn shape_tile(
    tile: &mut Tile,
    spec: &TerrainSpec,
    terrain_type: TerrainType,
    level: u32,
    rng: &mut impl Rng,
) {
    let platform = spec.platform_size;
    match terrain_type {
        TerrainType::Flat => tile.fill_flat(|_, _| 0.0),
        TerrainType::SlopeUp => {
            let size = tile.size();
            tile.fill_triangles(|u, v| -pyramid(u, v, size, platform, spec.slope(level)));
        }
        TerrainType::SlopeDown => {
            let size = tile.size();
            tile.fill_triangles(|u, v| pyramid(u, v, size, platform, spec.slope(level)));
        }
        TerrainType::RoughSlope => {
            let size = tile.size();
            tile.fill_triangles(|u, v| pyramid(u, v, size, platform, spec.slope(level)));
            add_noise(tile, spec, rng);
        }
        TerrainType::StairsUp => stairs(tile, spec, -spec.step_height_at(level)),
        TerrainType::StairsDown => stairs(tile, spec, spec.step_height_at(level)),
        TerrainType::Obstacles => obstacles(tile, spec, spec.obstacle_height_at(level), rng),
    }
}

/// Height (m) at tile point (u, v) of a pyramid with planar faces of `slope` (rise over run),
/// 0 at the tile edge, flat on the central square of side `platform`.
pub(crate) fn pyramid(u: f32, v: f32, size: f32, platform: f32, slope: f32) -> f32 {
    let c = 0.5 * size;
    let from_centre = (u - c).abs().max((v - c).abs()).max(0.5 * platform);
    slope * (c - from_centre).max(0.0)
}

/// Ring of cell (a, b) of a pyramid staircase: 0 on the outermost ring of `step` cells, one more
/// per ring inwards, capped so the innermost square (the platform) keeps at least `platform`
/// cells per side.
pub(crate) fn stair_ring(a: usize, b: usize, n: usize, step: usize, platform: usize) -> usize {
    let from_edge = a.min(b).min(n - 1 - a).min(n - 1 - b);
    let top = n.saturating_sub(platform) / (2 * step);
    (from_edge / step).min(top)
}

/// Pyramid stairs: each ring `step_height` (m) above the one outside it (below when negative).
fn stairs(tile: &mut Tile, spec: &TerrainSpec, step_height: f32) {
    let (n, step, platform) = (tile.n, spec.step_cells(), spec.platform_cells());
    tile.fill_flat(|a, b| stair_ring(a, b, n, step, platform) as f32 * step_height);
}

/// Uniform noise in [-rough_noise, rough_noise], quantised to `rough_noise_step`, drawn on a grid
/// of `rough_noise_spacing` and interpolated linearly, added to the vertices. The tile's edge and
/// its platform stay noise-free, so tiles meet exactly and spawn areas stay flat.
fn add_noise(tile: &mut Tile, spec: &TerrainSpec, rng: &mut impl Rng) {
    let s = tile.grid.cell();
    let size = tile.size();
    let steps = (spec.rough_noise / spec.rough_noise_step).floor() as i32;
    let knots = (size / spec.rough_noise_spacing).ceil() as usize + 1;
    let noise: Vec<f32> = (0..knots * knots)
        .map(|_| rng.random_range(-steps..=steps) as f32 * spec.rough_noise_step)
        .collect();
    let at = |k: usize, l: usize| noise[l.min(knots - 1) * knots + k.min(knots - 1)];
    let c = 0.5 * size;
    let half_platform = 0.5 * spec.platform_size;
    for b in 1..tile.n {
        for a in 1..tile.n {
            let (u, v) = (a as f32 * s, b as f32 * s);
            if (u - c).abs().max((v - c).abs()) <= half_platform + 1e-4 {
                continue;
            }
            let (gu, gv) = (u / spec.rough_noise_spacing, v / spec.rough_noise_spacing);
            let (k, l) = (gu.floor() as usize, gv.floor() as usize);
            let (fu, fv) = (gu - k as f32, gv - l as f32);
            let value = (1.0 - fv) * ((1.0 - fu) * at(k, l) + fu * at(k + 1, l))
                + fv * ((1.0 - fu) * at(k, l + 1) + fu * at(k + 1, l + 1));
            let (i, j) = (tile.i0 + a, tile.j0 + b);
            let h = tile.grid.vertex(i, j) + value;
            tile.grid.set_vertex(i, j, h);
        }
    }
}

/// legged_gym's discrete obstacles: `num_obstacles` rectangles with sides in `obstacle_size`,
/// each raised or sunk by `height` or half of it, later ones over earlier ones; then the central
/// platform is cleared to 0.
fn obstacles(tile: &mut Tile, spec: &TerrainSpec, height: f32, rng: &mut impl Rng) {
    let s = tile.grid.cell();
    let n = tile.n;
    let min_side = ((spec.obstacle_size[0] / s).round() as usize).clamp(1, n);
    let max_side = ((spec.obstacle_size[1] / s).round() as usize).clamp(min_side, n);
    let heights = [-height, -0.5 * height, 0.5 * height, height];
    let mut cells = vec![0.0f32; n * n];
    for _ in 0..spec.num_obstacles {
        let w = rng.random_range(min_side..=max_side);
        let l = rng.random_range(min_side..=max_side);
        let a0 = rng.random_range(0..=n - w);
        let b0 = rng.random_range(0..=n - l);
        let h = heights[rng.random_range(0..heights.len())];
        for b in b0..b0 + l {
            cells[b * n + a0..b * n + a0 + w].fill(h);
        }
    }
    let platform = spec.platform_cells().min(n);
    let p0 = (n - platform) / 2;
    for b in p0..p0 + platform {
        cells[b * n + p0..b * n + p0 + platform].fill(0.0);
    }
    tile.fill_flat(|a, b| cells[b * n + a]);
}

#[cfg(test)]
#[path = "generator_test.rs"]
mod test;
