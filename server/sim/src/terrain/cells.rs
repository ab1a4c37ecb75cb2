//! The stored terrain: a grid of square cells over x in [0, nx * cell], y in [0, ny * cell], each
//! a [`CellSurface`]. Outside the grid the ground is flat at z = 0 (the border). Queries are
//! plain arithmetic on the stored values: no rapier involved.

use rapier3d::math::Vec3;

use super::surface::{CellSurface, Side, corner_uv};

/// Heights of a terrain grid.
#[derive(Clone, Debug)]
pub(crate) struct CellGrid {
    /// Cell side (m).
    cell: f32,
    inv_cell: f32,
    /// Cells along x and y.
    nx: usize,
    ny: usize,
    /// Vertex heights (m), `(nx + 1) * (ny + 1)`, x fastest. Used by cells made of triangles.
    vertices: Vec<f32>,
    /// Height of each flat cell (m), NaN for a cell made of triangles; `nx * ny`, x fastest.
    flat: Vec<f32>,
    /// Whether each triangle cell is split along its 00-11 diagonal.
    main_diagonal: Vec<bool>,
}

/// Bit-for-bit equality (flat heights hold NaN for triangle cells, which `==` on f32 rejects).
impl PartialEq for CellGrid {
    fn eq(&self, other: &Self) -> bool {
        let bits = |v: &[f32]| v.iter().map(|h| h.to_bits()).collect::<Vec<_>>();
        self.cell.to_bits() == other.cell.to_bits()
            && (self.nx, self.ny) == (other.nx, other.ny)
            && bits(&self.vertices) == bits(&other.vertices)
            && bits(&self.flat) == bits(&other.flat)
            && self.main_diagonal == other.main_diagonal
    }
}

/// A cell and the position (u, v) in [0, 1]^2 of a point within it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Located {
    i: usize,
    j: usize,
    u: f32,
    v: f32,
}

impl CellGrid {
    /// A grid of `nx` x `ny` flat cells at height 0.
    pub(crate) fn new(nx: usize, ny: usize, cell: f32) -> Self {
        Self {
            cell,
            inv_cell: 1.0 / cell,
            nx,
            ny,
            vertices: vec![0.0; (nx + 1) * (ny + 1)],
            flat: vec![0.0; nx * ny],
            main_diagonal: vec![true; nx * ny],
        }
    }

    /// Cell side (m).
    pub(crate) fn cell(&self) -> f32 {
        self.cell
    }

    /// Cells along x.
    pub(crate) fn nx(&self) -> usize {
        self.nx
    }

    /// Cells along y.
    pub(crate) fn ny(&self) -> usize {
        self.ny
    }

    fn vertex_index(&self, a: usize, b: usize) -> usize {
        b * (self.nx + 1) + a
    }

    fn cell_index(&self, i: usize, j: usize) -> usize {
        j * self.nx + i
    }

    /// Height of vertex (a, b) (m).
    pub(crate) fn vertex(&self, a: usize, b: usize) -> f32 {
        self.vertices[self.vertex_index(a, b)]
    }

    /// Set the height of vertex (a, b) (m).
    pub(crate) fn set_vertex(&mut self, a: usize, b: usize, h: f32) {
        let k = self.vertex_index(a, b);
        self.vertices[k] = h;
    }

    /// Make cell (i, j) a horizontal face at `h` (m).
    pub(crate) fn set_flat(&mut self, i: usize, j: usize, h: f32) {
        let k = self.cell_index(i, j);
        self.flat[k] = h;
    }

    /// Make cell (i, j) two triangles through its vertices, split along the 00-11 diagonal when
    /// `main_diagonal`.
    pub(crate) fn set_triangles(&mut self, i: usize, j: usize, main_diagonal: bool) {
        let k = self.cell_index(i, j);
        self.flat[k] = f32::NAN;
        self.main_diagonal[k] = main_diagonal;
    }

    /// The surface of cell (i, j); cells outside the grid are the flat border at 0.
    #[inline]
    pub(crate) fn surface(&self, i: isize, j: isize) -> CellSurface {
        if i < 0 || j < 0 || i as usize >= self.nx || j as usize >= self.ny {
            return CellSurface::Flat(0.0);
        }
        let (i, j) = (i as usize, j as usize);
        let k = self.cell_index(i, j);
        let flat = self.flat[k];
        if !flat.is_nan() {
            return CellSurface::Flat(flat);
        }
        let v0 = self.vertex_index(i, j);
        let v1 = v0 + self.nx + 1;
        CellSurface::Triangles {
            corners: [
                self.vertices[v0],
                self.vertices[v0 + 1],
                self.vertices[v1],
                self.vertices[v1 + 1],
            ],
            main_diagonal: self.main_diagonal[k],
        }
    }

    /// The cell holding (x, y) and the point's cell coordinates; `None` outside the grid (or for
    /// a non-finite point). A point on a cell edge belongs to the cell on its +x / +y side.
    #[inline]
    fn locate(&self, x: f32, y: f32) -> Option<Located> {
        let gx = x * self.inv_cell;
        let gy = y * self.inv_cell;
        // Written so that NaN fails the test too.
        if !(gx >= 0.0 && gy >= 0.0 && gx <= self.nx as f32 && gy <= self.ny as f32) {
            return None;
        }
        let i = (gx as usize).min(self.nx - 1);
        let j = (gy as usize).min(self.ny - 1);
        Some(Located {
            i,
            j,
            u: gx - i as f32,
            v: gy - j as f32,
        })
    }

    /// Terrain height at (x, y) (m).
    #[inline]
    pub(crate) fn height(&self, x: f32, y: f32) -> f32 {
        match self.locate(x, y) {
            Some(p) => self.surface(p.i as isize, p.j as isize).height(p.u, p.v),
            None => 0.0,
        }
    }

    /// Unit normal of the face under (x, y).
    #[inline]
    pub(crate) fn normal(&self, x: f32, y: f32) -> Vec3 {
        let Some(p) = self.locate(x, y) else {
            return Vec3::Z;
        };
        let (du, dv) = self.surface(p.i as isize, p.j as isize).gradient(p.u, p.v);
        if du == 0.0 && dv == 0.0 {
            return Vec3::Z;
        }
        Vec3::new(-du * self.inv_cell, -dv * self.inv_cell, 1.0).normalize()
    }

    /// Highest terrain point within `radius` of (x, y) (m). Exact on flat cells (a step face
    /// within the radius counts: its top is in the disc). On a triangle cell the candidates are
    /// the cell's point nearest (x, y), its corners inside the disc and the disc's most uphill
    /// points, which finds the maximum of a plane over the disc up to where it meets a crease.
    pub(crate) fn max_height_within(&self, x: f32, y: f32, radius: f32) -> f32 {
        let r = radius.max(0.0);
        let mut best = self.height(x, y);
        if r == 0.0 || !(x.is_finite() && y.is_finite()) {
            return best;
        }
        let i0 = ((x - r) * self.inv_cell).floor() as isize;
        let i1 = ((x + r) * self.inv_cell).floor() as isize;
        let j0 = ((y - r) * self.inv_cell).floor() as isize;
        let j1 = ((y + r) * self.inv_cell).floor() as isize;
        // Cells beyond the grid are all the flat border at 0: one of them is enough.
        let (ci0, ci1) = (i0.max(-1), i1.min(self.nx as isize));
        let (cj0, cj1) = (j0.max(-1), j1.min(self.ny as isize));
        for j in cj0..=cj1 {
            for i in ci0..=ci1 {
                best = best.max(self.cell_max_in_disc(i, j, x, y, r));
            }
        }
        best
    }

    /// Highest point of cell (i, j) within the disc of radius `r` around (x, y), or -inf when
    /// the disc misses the cell.
    fn cell_max_in_disc(&self, i: isize, j: isize, x: f32, y: f32, r: f32) -> f32 {
        let s = self.cell;
        let (x0, y0) = (i as f32 * s, j as f32 * s);
        let (nearest_x, nearest_y) = (x.clamp(x0, x0 + s), y.clamp(y0, y0 + s));
        let r2 = r * r;
        let in_disc = |px: f32, py: f32| (px - x).powi(2) + (py - y).powi(2) <= r2;
        if !in_disc(nearest_x, nearest_y) {
            return f32::NEG_INFINITY;
        }
        let surface = self.surface(i, j);
        if let CellSurface::Flat(h) = surface {
            return h;
        }
        let local = |px: f32, py: f32| {
            (
                ((px - x0) * self.inv_cell).clamp(0.0, 1.0),
                ((py - y0) * self.inv_cell).clamp(0.0, 1.0),
            )
        };
        let (nu, nv) = local(nearest_x, nearest_y);
        let mut best = surface.height(nu, nv);
        for k in 0..4 {
            let (u, v) = corner_uv(k);
            if in_disc(x0 + u * s, y0 + v * s) {
                best = best.max(surface.height(u, v));
            }
        }
        // The uphill point of the disc for each of the cell's two faces.
        for (fu, fv) in [(0.25, 0.75), (0.75, 0.25)] {
            let (du, dv) = surface.gradient(fu, fv);
            let norm = (du * du + dv * dv).sqrt();
            if norm > 0.0 {
                let (px, py) = (x + r * du / norm, y + r * dv / norm);
                if (x0..=x0 + s).contains(&px) && (y0..=y0 + s).contains(&py) {
                    let (u, v) = local(px, py);
                    best = best.max(surface.height(u, v));
                }
            }
        }
        best
    }

    /// Highest point of the cells meeting the axis-aligned square [x0, x1] x [y0, y1] (m),
    /// from their flat heights and corners.
    pub(crate) fn max_height_in_square(&self, x0: f32, y0: f32, x1: f32, y1: f32) -> f32 {
        let first = |v: f32| (v * self.inv_cell).floor() as isize;
        // A square side lying on a cell edge does not take in the cell beyond it.
        let last = |lo: f32, hi: f32| ((hi * self.inv_cell).ceil() as isize - 1).max(first(lo));
        let mut best = f32::NEG_INFINITY;
        for j in first(y0)..=last(y0, y1) {
            for i in first(x0)..=last(x0, x1) {
                best = best.max(self.surface(i, j).max_corner());
            }
        }
        best
    }

    /// The two sides' edge heights across the cell edge on the west side of cell (i, j):
    /// (west neighbour's east edge, this cell's west edge).
    pub(crate) fn across_vertical_edge(&self, i: isize, j: isize) -> ([f32; 2], [f32; 2]) {
        (
            self.surface(i - 1, j).edge(Side::East),
            self.surface(i, j).edge(Side::West),
        )
    }

    /// The two sides' edge heights across the cell edge on the south side of cell (i, j):
    /// (south neighbour's north edge, this cell's south edge).
    pub(crate) fn across_horizontal_edge(&self, i: isize, j: isize) -> ([f32; 2], [f32; 2]) {
        (
            self.surface(i, j - 1).edge(Side::North),
            self.surface(i, j).edge(Side::South),
        )
    }
}

#[cfg(test)]
#[path = "cells_test.rs"]
mod test;
