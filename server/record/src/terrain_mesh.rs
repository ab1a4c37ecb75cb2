//! A triangle mesh of the terrain around a point, for drawing (plain arrays, no rerun types).

use unigait_sim::terrain::Terrain;

/// Vertices, triangles and per-vertex colours.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TerrainMesh {
    /// Vertex positions (m, world).
    pub positions: Vec<[f32; 3]>,
    /// Triangles as vertex indices (counter-clockwise seen from above).
    pub triangles: Vec<[u32; 3]>,
    /// Vertex colours (RGBA), shaded by height so steps read.
    pub colors: Vec<[u8; 4]>,
}

impl TerrainMesh {
    fn push_quad(&mut self, corners: [[f32; 3]; 4], color: [u8; 4]) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&corners);
        self.colors.extend_from_slice(&[color; 4]);
        self.triangles.push([base, base + 1, base + 2]);
        self.triangles.push([base, base + 2, base + 3]);
    }
}

/// Side of a flat-ground tile (m).
pub const FLAT_TILE_M: f32 = 0.5;

/// Grey shaded by height: lighter higher, so stair treads stand apart.
fn shade(z: f32) -> [u8; 4] {
    let v = (150.0 + 120.0 * z).clamp(60.0, 235.0) as u8;
    [v, v, (f32::from(v) * 0.95) as u8, 255]
}

/// The terrain within `half_window` (m) of `centre` (world x, y).
///
/// Flat ground is a checkerboard of [`FLAT_TILE_M`] tiles aligned to the world axes (so a
/// camera that follows the robot still shows it move, and overlapping windows of several envs
/// agree). A grid is drawn cell by cell at its own resolution
/// (`horizontal_scale`): each cell a quad whose corners are sampled just inside the cell (so a
/// tread is flat and a slope is planar), plus a vertical wall wherever two neighbouring cells
/// meet at different heights (the grid's step faces are vertical).
pub fn terrain_mesh(terrain: &Terrain, centre: [f32; 2], half_window: f32) -> TerrainMesh {
    let mut mesh = TerrainMesh::default();
    let half = half_window.max(0.1);
    let Some(grid) = terrain.grid() else {
        let [cx, cy] = centre;
        let t = FLAT_TILE_M;
        let (x0, x1) = (
            ((cx - half) / t).floor() as i64,
            ((cx + half) / t).ceil() as i64,
        );
        let (y0, y1) = (
            ((cy - half) / t).floor() as i64,
            ((cy + half) / t).ceil() as i64,
        );
        let light = shade(0.0);
        let dark = light.map(|c| c.saturating_sub(22));
        for a in x0..x1 {
            for b in y0..y1 {
                let (x, y) = (a as f32 * t, b as f32 * t);
                mesh.push_quad(
                    [
                        [x, y, 0.0],
                        [x + t, y, 0.0],
                        [x + t, y + t, 0.0],
                        [x, y + t, 0.0],
                    ],
                    if (a + b).rem_euclid(2) == 0 {
                        light
                    } else {
                        dark
                    },
                );
            }
        }
        return mesh;
    };
    let cell = grid.spec().horizontal_scale;
    let first = [
        ((centre[0] - half) / cell).floor() as i64,
        ((centre[1] - half) / cell).floor() as i64,
    ];
    let cells = ((2.0 * half) / cell).ceil() as i64 + 1;
    let eps = 1e-3 * cell;
    // Height of cell (a, b) at its corner (dx, dy) in {0, 1}^2, sampled just inside it.
    let corner = |a: i64, b: i64, dx: i64, dy: i64| -> [f32; 3] {
        let x = (a + dx) as f32 * cell;
        let y = (b + dy) as f32 * cell;
        let sx = if dx == 0 { x + eps } else { x - eps };
        let sy = if dy == 0 { y + eps } else { y - eps };
        [x, y, grid.height(sx, sy)]
    };
    for a in first[0]..first[0] + cells {
        for b in first[1]..first[1] + cells {
            let c00 = corner(a, b, 0, 0);
            let c10 = corner(a, b, 1, 0);
            let c11 = corner(a, b, 1, 1);
            let c01 = corner(a, b, 0, 1);
            let mean = 0.25 * (c00[2] + c10[2] + c11[2] + c01[2]);
            mesh.push_quad([c00, c10, c11, c01], shade(mean));
            // Wall towards +x: this cell's right edge against the next cell's left edge.
            if a + 1 < first[0] + cells {
                let (n00, n01) = (corner(a + 1, b, 0, 0), corner(a + 1, b, 0, 1));
                if (n00[2] - c10[2]).abs() > 1e-4 || (n01[2] - c11[2]).abs() > 1e-4 {
                    mesh.push_quad([c10, n00, n01, c11], shade(mean.min(n00[2]) - 0.1));
                }
            }
            // Wall towards +y.
            if b + 1 < first[1] + cells {
                let (n00, n10) = (corner(a, b + 1, 0, 0), corner(a, b + 1, 1, 0));
                if (n00[2] - c01[2]).abs() > 1e-4 || (n10[2] - c11[2]).abs() > 1e-4 {
                    mesh.push_quad([c01, c11, n10, n00], shade(mean.min(n00[2]) - 0.1));
                }
            }
        }
    }
    mesh
}

#[cfg(test)]
mod test {
    use unigait_sim::terrain::{TerrainKind, TerrainSpec, TerrainType};

    use super::*;

    #[test]
    fn flat_is_a_checkerboard_aligned_to_the_world() {
        let m = terrain_mesh(&Terrain::Flat, [1.0, 2.0], 5.0);
        // x from -4 to 6, y from -3 to 7: 20 x 20 tiles of 0.5 m.
        assert_eq!(m.triangles.len(), 2 * 20 * 20);
        assert_eq!(m.positions[0], [-4.0, -3.0, 0.0]);
        assert!(m.positions.iter().all(|p| p[2] == 0.0));
        assert!(
            m.positions
                .iter()
                .all(|p| (p[0] / FLAT_TILE_M).fract() == 0.0 && (p[1] / FLAT_TILE_M).fract() == 0.0)
        );
        // Neighbouring tiles differ, so motion over flat ground reads.
        assert_ne!(m.colors[0], m.colors[4]);
    }

    #[test]
    fn stairs_have_treads_at_step_heights_and_walls() {
        let spec = TerrainSpec {
            kind: TerrainKind::Pinned {
                terrain_type: TerrainType::StairsUp,
                level: 0,
            },
            num_levels: 1,
            types: vec![TerrainType::StairsUp],
            step_height: [0.15, 0.15],
            ..TerrainSpec::default()
        };
        let terrain = Terrain::from_spec(&spec, 0).expect("terrain");
        let centre = [4.0, 4.0];
        let m = terrain_mesh(&terrain, centre, 4.0);
        let zs: Vec<f32> = m.positions.iter().map(|p| p[2]).collect();
        let lowest = zs.iter().copied().fold(f32::INFINITY, f32::min);
        assert!(lowest < -1.0, "the pit is deep: {lowest}");
        // Every vertex height is a whole number of steps (treads and vertical walls only).
        for z in zs {
            let steps = z / 0.15;
            assert!((steps - steps.round()).abs() < 1e-3, "height {z}");
        }
        assert!(m.triangles.len() > 2 * 80 * 80, "walls added");
        assert!(
            m.triangles
                .iter()
                .flatten()
                .all(|&i| (i as usize) < m.positions.len())
        );
    }
}
