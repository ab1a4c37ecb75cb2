//! The grid as a rapier triangle mesh: the cells' faces plus vertical walls wherever two cells'
//! surfaces differ along their shared edge (steps, obstacle sides), plus the flat border.
//!
//! Why a mesh and not a heightfield: a heightfield only holds one height per vertex, so a step
//! between two samples becomes a ramp one sample wide; the mesh holds the step face exactly at
//! its cell edge. Flat or coplanar cells are merged into large rectangles (two triangles each),
//! which keeps the triangle count, and so the contact work per foot, small.

use rapier3d::math::Vec3;
use rapier3d::prelude::{SharedShape, TriMeshFlags};

use crate::error::SimError;

use super::cells::CellGrid;
use super::surface::{CellSurface, cell_triangles, corner_uv};

/// Two cells whose corner heights agree within this (m) are treated as one plane when merging.
const COPLANAR_TOLERANCE: f32 = 1e-5;

/// Vertex and index buffers of a triangle mesh under construction.
#[derive(Default)]
pub(crate) struct MeshBuffers {
    /// Vertex positions (m).
    pub(crate) vertices: Vec<Vec3>,
    /// Triangles, counter-clockwise seen from their front.
    pub(crate) indices: Vec<[u32; 3]>,
}

impl MeshBuffers {
    fn push_vertex(&mut self, p: Vec3) -> u32 {
        self.vertices.push(p);
        (self.vertices.len() - 1) as u32
    }

    fn triangle(&mut self, a: Vec3, b: Vec3, c: Vec3) {
        // Degenerate triangles (a zero-height wall piece) carry no surface.
        if (b - a).cross(c - a).length_squared() <= 1e-14 {
            return;
        }
        let ia = self.push_vertex(a);
        let ib = self.push_vertex(b);
        let ic = self.push_vertex(c);
        self.indices.push([ia, ib, ic]);
    }

    /// A quad a-b-c-d (in order around it) as two triangles sharing its vertices.
    fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        self.triangle(a, b, c);
        self.triangle(a, c, d);
    }
}

/// The triangle mesh of `cells` with a flat border of `border` (m) around it, as a shape for a
/// collider at the origin.
pub(crate) fn trimesh(cells: &CellGrid, border: f32) -> Result<SharedShape, SimError> {
    let buffers = mesh_buffers(cells, border);
    // No topology flags: merged rectangles meet their neighbours at T-junctions, which half-edge
    // topology (needed by FIX_INTERNAL_EDGES) rejects. Feet are balls, and a ball's contact with
    // a face edge inside a flat area still points straight up.
    SharedShape::trimesh_with_flags(buffers.vertices, buffers.indices, TriMeshFlags::empty())
        .map_err(|e| SimError::invalid("terrain", "grid", format!("triangle mesh: {e}")))
}

/// Vertex and index buffers of the mesh of `cells` plus the border.
pub(crate) fn mesh_buffers(cells: &CellGrid, border: f32) -> MeshBuffers {
    let mut out = MeshBuffers::default();
    faces(cells, &mut out);
    walls(cells, &mut out);
    border_faces(cells, border, &mut out);
    out
}

/// The cells' faces: greedy rectangles over cells sharing one plane, two triangles for every
/// other cell.
fn faces(cells: &CellGrid, out: &mut MeshBuffers) {
    let (nx, ny, s) = (cells.nx(), cells.ny(), cells.cell());
    let plane = |i: usize, j: usize| {
        let p = cells
            .surface(i as isize, j as isize)
            .plane(COPLANAR_TOLERANCE)?;
        // The plane as a function of world cell indices, so cells compare across positions.
        Some([p[0] - p[1] * i as f32 - p[2] * j as f32, p[1], p[2]])
    };
    let same = |a: [f32; 3], b: [f32; 3]| {
        // The offset grows with the index times the slope: scale its tolerance with the grid.
        let offset_tol = COPLANAR_TOLERANCE * (1.0 + (nx + ny) as f32 * 1e-2);
        (a[0] - b[0]).abs() <= offset_tol
            && (a[1] - b[1]).abs() <= COPLANAR_TOLERANCE
            && (a[2] - b[2]).abs() <= COPLANAR_TOLERANCE
    };
    let mut done = vec![false; nx * ny];
    for j in 0..ny {
        for i in 0..nx {
            if done[j * nx + i] {
                continue;
            }
            let Some(key) = plane(i, j) else {
                cell_faces(cells, i, j, out);
                done[j * nx + i] = true;
                continue;
            };
            let fits =
                |a: usize, b: usize| !done[b * nx + a] && plane(a, b).is_some_and(|p| same(p, key));
            let mut w = 1;
            while i + w < nx && fits(i + w, j) {
                w += 1;
            }
            let mut h = 1;
            while j + h < ny && (i..i + w).all(|a| fits(a, j + h)) {
                h += 1;
            }
            for b in j..j + h {
                done[b * nx + i..b * nx + i + w].fill(true);
            }
            // Corner heights from the corner cells' own surfaces (exact for flat cells and for
            // the grid's vertices).
            let z = |a: usize, b: usize, u: f32, v: f32| {
                cells.surface(a as isize, b as isize).height(u, v)
            };
            let (x0, x1) = (i as f32 * s, (i + w) as f32 * s);
            let (y0, y1) = (j as f32 * s, (j + h) as f32 * s);
            out.quad(
                Vec3::new(x0, y0, z(i, j, 0.0, 0.0)),
                Vec3::new(x1, y0, z(i + w - 1, j, 1.0, 0.0)),
                Vec3::new(x1, y1, z(i + w - 1, j + h - 1, 1.0, 1.0)),
                Vec3::new(x0, y1, z(i, j + h - 1, 0.0, 1.0)),
            );
        }
    }
}

/// The two triangles of a non-planar cell.
fn cell_faces(cells: &CellGrid, i: usize, j: usize, out: &mut MeshBuffers) {
    let s = cells.cell();
    let surface = cells.surface(i as isize, j as isize);
    let CellSurface::Triangles {
        corners,
        main_diagonal,
    } = surface
    else {
        return;
    };
    let corner = |k: usize| {
        let (u, v) = corner_uv(k);
        Vec3::new((i as f32 + u) * s, (j as f32 + v) * s, corners[k])
    };
    for [a, b, c] in cell_triangles(main_diagonal) {
        out.triangle(corner(a), corner(b), corner(c));
    }
}

/// Vertical walls along every cell edge where the two sides' surfaces differ, the grid's outer
/// edge (against the border at 0) included. Runs of edges with the same constant heights on both
/// sides (a stair riser) become one long wall.
fn walls(cells: &CellGrid, out: &mut MeshBuffers) {
    let (nx, ny, s) = (cells.nx() as isize, cells.ny() as isize, cells.cell());
    // Edges x = i * s, running along y.
    for i in 0..=nx {
        let x = i as f32 * s;
        wall_line(
            ny,
            |j| cells.across_vertical_edge(i, j),
            |t| Vec3::new(x, t * s, 0.0),
            out,
        );
    }
    // Edges y = j * s, running along x.
    for j in 0..=ny {
        let y = j as f32 * s;
        wall_line(
            nx,
            |i| cells.across_horizontal_edge(i, j),
            |t| Vec3::new(t * s, y, 0.0),
            out,
        );
    }
}

/// The walls along one grid line of `len` edges; `across(k)` gives both sides' heights at the
/// two ends of edge k, `at(t)` the point at `t` cells along the line (z ignored).
fn wall_line(
    len: isize,
    across: impl Fn(isize) -> ([f32; 2], [f32; 2]),
    at: impl Fn(f32) -> Vec3,
    out: &mut MeshBuffers,
) {
    let constant =
        |(a, b): ([f32; 2], [f32; 2])| (a[0] == a[1] && b[0] == b[1]).then_some((a[0], b[0]));
    let mut k = 0;
    while k < len {
        let sides = across(k);
        if sides.0 == sides.1 {
            k += 1;
            continue;
        }
        let start = k;
        k += 1;
        if let Some(heights) = constant(sides) {
            while k < len && constant(across(k)) == Some(heights) {
                k += 1;
            }
        }
        wall(at(start as f32), at(k as f32), sides, out);
    }
}

/// The wall between two surfaces meeting along the segment p0-p1: side A has heights `a` and
/// side B heights `b` at p0 and p1 (taken as constant along a merged run). Where the sides cross
/// over, the wall is two triangles meeting at the crossing.
fn wall(p0: Vec3, p1: Vec3, (a, b): ([f32; 2], [f32; 2]), out: &mut MeshBuffers) {
    let at = |p: Vec3, z: f32| Vec3::new(p.x, p.y, z);
    let (d0, d1) = (a[0] - b[0], a[1] - b[1]);
    if d0 * d1 >= 0.0 {
        out.quad(at(p0, a[0]), at(p1, a[1]), at(p1, b[1]), at(p0, b[0]));
    } else {
        let t = d0 / (d0 - d1);
        let cross = p0 + (p1 - p0) * t;
        let z = a[0] + (a[1] - a[0]) * t;
        out.triangle(at(p0, a[0]), at(cross, z), at(p0, b[0]));
        out.triangle(at(p1, a[1]), at(p1, b[1]), at(cross, z));
    }
}

/// The flat border at z = 0: four rectangles around the grid.
fn border_faces(cells: &CellGrid, border: f32, out: &mut MeshBuffers) {
    if border <= 0.0 {
        return;
    }
    let (x1, y1) = (
        cells.nx() as f32 * cells.cell(),
        cells.ny() as f32 * cells.cell(),
    );
    let b = border;
    let rect = |out: &mut MeshBuffers, xa: f32, ya: f32, xb: f32, yb: f32| {
        out.quad(
            Vec3::new(xa, ya, 0.0),
            Vec3::new(xb, ya, 0.0),
            Vec3::new(xb, yb, 0.0),
            Vec3::new(xa, yb, 0.0),
        );
    };
    rect(out, -b, -b, x1 + b, 0.0);
    rect(out, -b, y1, x1 + b, y1 + b);
    rect(out, -b, 0.0, 0.0, y1);
    rect(out, x1, 0.0, x1 + b, y1);
}

#[cfg(test)]
#[path = "mesh_test.rs"]
mod test;
