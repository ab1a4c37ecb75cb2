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

/// Grey shaded by height: lighter higher, so stair treads stand apart.
fn shade(z: f32) -> [u8; 4] {
    let v = (150.0 + 120.0 * z).clamp(60.0, 235.0) as u8;
    [v, v, (f32::from(v) * 0.95) as u8, 255]
}

/// The terrain within `half_window` (m) of `centre` (world x, y).
///
/// Flat ground is one quad. A grid is drawn cell by cell at its own resolution
/// (`horizontal_scale`): each cell a quad whose corners are sampled just inside the cell (so a
/// tread is flat and a slope is planar), plus a vertical wall wherever two neighbouring cells
/// meet at different heights (the grid's step faces are vertical).
pub fn terrain_mesh(terrain: &Terrain, centre: [f32; 2], half_window: f32) -> TerrainMesh {
    let mut mesh = TerrainMesh::default();
    let half = half_window.max(0.1);
    let Some(grid) = terrain.grid() else {
        let [cx, cy] = centre;
        mesh.push_quad(
            [
                [cx - half, cy - half, 0.0],
                [cx + half, cy - half, 0.0],
                [cx + half, cy + half, 0.0],
                [cx - half, cy + half, 0.0],
            ],
            shade(0.0),
        );
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
    fn flat_is_one_quad() {
        let m = terrain_mesh(&Terrain::Flat, [1.0, 2.0], 5.0);
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.triangles.len(), 2);
        assert_eq!(m.positions[2], [6.0, 7.0, 0.0]);
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
