//! The grid as a parry heightfield, for comparison with the mesh. A heightfield holds one height
//! per sample, so each step becomes a ramp one sample wide (the higher side keeps its edge: a
//! sample on a step edge takes the top of the step). Parry's heightfield is Y-up, with rows along
//! its local z and columns along x; the collider pose turns it Z-up.

use rapier3d::math::{Pose, Rotation, Vec3};
use rapier3d::parry::shape::{HeightField, HeightFieldCellStatus, HeightFieldFlags};
use rapier3d::prelude::{Array2, SharedShape};

use super::cells::CellGrid;
use super::surface::CellSurface;

/// The heightfield of `cells` sampled `subdivisions` times per cell, with a flat border of at
/// least `border` (m), and the pose of its collider.
pub(crate) fn heightfield(cells: &CellGrid, border: f32, subdivisions: u32) -> (SharedShape, Pose) {
    let k = subdivisions.max(1) as isize;
    let fine = cells.cell() / k as f32;
    let pad = (border / fine).ceil().max(1.0) as isize;
    let (fx, fy) = (cells.nx() as isize * k, cells.ny() as isize * k);
    let (cols, rows) = ((fx + 2 * pad + 1) as usize, (fy + 2 * pad + 1) as usize);
    // Row r lies at fine y index fy + pad - r (rows run along local z = world -y); column c at
    // fine x index c - pad.
    let fine_x = |c: usize| c as isize - pad;
    let fine_y = |r: usize| fy + pad - r as isize;
    let heights = Array2::from_fn(rows, cols, |r, c| {
        sample_top(cells, k, fine_x(c), fine_y(r))
    });
    let mut field = HeightField::with_flags(
        heights,
        Vec3::new((cols - 1) as f32 * fine, 1.0, (rows - 1) as f32 * fine),
        HeightFieldFlags::empty(),
    );
    // Parry's default split joins (x0, z1)-(x1, z0), i.e. world (x0, y0)-(x1, y1): our main
    // diagonal; its zigzag split is our other one.
    for r in 0..rows - 1 {
        for c in 0..cols - 1 {
            let (i, j) = (fine_x(c).div_euclid(k), (fine_y(r) - 1).div_euclid(k));
            if let CellSurface::Triangles {
                main_diagonal: false,
                ..
            } = cells.surface(i, j)
            {
                field.set_cell_status(r, c, HeightFieldCellStatus::ZIGZAG_SUBDIVISION);
            }
        }
    }
    let centre = Vec3::new(
        0.5 * cells.nx() as f32 * cells.cell(),
        0.5 * cells.ny() as f32 * cells.cell(),
        0.0,
    );
    // +90 deg about x turns local y (up) into world z and local z into world -y.
    let pose = Pose::from_parts(
        centre,
        Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2),
    );
    (SharedShape::new(field), pose)
}

/// Height of the fine sample at fine indices (a, b): the highest surface among the cells
/// touching it, so a step's top edge stays where it is and its face becomes a ramp below it.
fn sample_top(cells: &CellGrid, k: isize, a: isize, b: isize) -> f32 {
    let touching = |f: isize| {
        let cell = f.div_euclid(k);
        if f.rem_euclid(k) == 0 {
            [cell - 1, cell]
        } else {
            [cell, cell]
        }
    };
    let mut top = f32::NEG_INFINITY;
    for i in touching(a) {
        for j in touching(b) {
            let u = (a - i * k) as f32 / k as f32;
            let v = (b - j * k) as f32 / k as f32;
            top = top.max(cells.surface(i, j).height(u, v));
        }
    }
    top
}

#[cfg(test)]
#[path = "heightfield_test.rs"]
mod test;
