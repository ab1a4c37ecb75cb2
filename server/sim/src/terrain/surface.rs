//! The surface over one grid cell: a horizontal face, or two triangles through the cell's corner
//! heights. Both the height queries and the collider are built from it, so what the robot touches
//! and what the queries answer are the same surface.

/// A side of a cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Side {
    /// The edge at u = 0 (smaller x).
    West,
    /// The edge at u = 1 (larger x).
    East,
    /// The edge at v = 0 (smaller y).
    South,
    /// The edge at v = 1 (larger y).
    North,
}

/// The surface over one cell, in cell coordinates u, v in [0, 1] (x and y over the cell size).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum CellSurface {
    /// A horizontal face at this height (m). Where a neighbour's surface differs along the
    /// shared edge, a vertical wall joins them: this is how steps stay vertical.
    Flat(f32),
    /// Two triangles through the corner heights `[h00, h10, h01, h11]` (first digit u, second
    /// v), split along the 00-11 diagonal when `main_diagonal`, else along the 10-01 diagonal.
    Triangles {
        /// Corner heights (m).
        corners: [f32; 4],
        /// Which diagonal splits the cell.
        main_diagonal: bool,
    },
}

/// Corner indices of the two triangles of a cell split along the main (00-11) or the other
/// (10-01) diagonal, counter-clockwise seen from above.
pub(crate) fn cell_triangles(main_diagonal: bool) -> [[usize; 3]; 2] {
    if main_diagonal {
        [[0, 1, 3], [0, 3, 2]]
    } else {
        [[0, 1, 2], [1, 3, 2]]
    }
}

/// Cell coordinates (u, v) of corner `k` (0 = 00, 1 = 10, 2 = 01, 3 = 11).
pub(crate) fn corner_uv(k: usize) -> (f32, f32) {
    ((k & 1) as f32, (k >> 1) as f32)
}

impl CellSurface {
    /// Height at (u, v) (m).
    #[inline]
    pub(crate) fn height(&self, u: f32, v: f32) -> f32 {
        match *self {
            CellSurface::Flat(h) => h,
            CellSurface::Triangles {
                corners: [h00, h10, h01, h11],
                main_diagonal,
            } => {
                if main_diagonal {
                    if u >= v {
                        h00 + u * (h10 - h00) + v * (h11 - h10)
                    } else {
                        h00 + u * (h11 - h01) + v * (h01 - h00)
                    }
                } else if u + v <= 1.0 {
                    h00 + u * (h10 - h00) + v * (h01 - h00)
                } else {
                    h11 + (1.0 - u) * (h01 - h11) + (1.0 - v) * (h10 - h11)
                }
            }
        }
    }

    /// Gradient (dh/du, dh/dv) of the face containing (u, v) (m per cell).
    #[inline]
    pub(crate) fn gradient(&self, u: f32, v: f32) -> (f32, f32) {
        match *self {
            CellSurface::Flat(_) => (0.0, 0.0),
            CellSurface::Triangles {
                corners: [h00, h10, h01, h11],
                main_diagonal,
            } => {
                if main_diagonal {
                    if u >= v {
                        (h10 - h00, h11 - h10)
                    } else {
                        (h11 - h01, h01 - h00)
                    }
                } else if u + v <= 1.0 {
                    (h10 - h00, h01 - h00)
                } else {
                    (h11 - h01, h11 - h10)
                }
            }
        }
    }

    /// Heights at the two ends of `side`, in the order of increasing u or v.
    #[inline]
    pub(crate) fn edge(&self, side: Side) -> [f32; 2] {
        match *self {
            CellSurface::Flat(h) => [h, h],
            CellSurface::Triangles {
                corners: [h00, h10, h01, h11],
                ..
            } => match side {
                Side::West => [h00, h01],
                Side::East => [h10, h11],
                Side::South => [h00, h10],
                Side::North => [h01, h11],
            },
        }
    }

    /// Highest corner (m); for a flat cell its height.
    #[inline]
    pub(crate) fn max_corner(&self) -> f32 {
        match *self {
            CellSurface::Flat(h) => h,
            CellSurface::Triangles { corners, .. } => corners.into_iter().fold(f32::MIN, f32::max),
        }
    }

    /// The single plane (height at 00, dh/du, dh/dv) through all four corners, if they are
    /// coplanar within `tolerance` (m); a flat cell is the plane (h, 0, 0).
    pub(crate) fn plane(&self, tolerance: f32) -> Option<[f32; 3]> {
        match *self {
            CellSurface::Flat(h) => Some([h, 0.0, 0.0]),
            CellSurface::Triangles {
                corners: [h00, h10, h01, h11],
                ..
            } => {
                ((h00 + h11 - h10 - h01).abs() <= tolerance).then_some([h00, h10 - h00, h01 - h00])
            }
        }
    }
}

#[cfg(test)]
#[path = "surface_test.rs"]
mod test;
