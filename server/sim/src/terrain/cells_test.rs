//! Grid queries on hand-built cells: steps are steps, slopes are planes, the border is flat, and
//! the highest point within a radius sees a step face inside the radius.

use super::*;

/// A 10 x 4 grid of 0.1 m cells: cells 0..5 flat at 0, cells 5..10 a 0.15 m step.
fn step_grid() -> CellGrid {
    let mut g = CellGrid::new(10, 4, 0.1);
    for j in 0..4 {
        for i in 5..10 {
            g.set_flat(i, j, 0.15);
        }
    }
    g
}

/// A 4 x 4 grid of 0.1 m cells whose vertices lie on z = 0.5 x (a 26.6 deg slope along x).
fn slope_grid() -> CellGrid {
    let mut g = CellGrid::new(4, 4, 0.1);
    for b in 0..=4 {
        for a in 0..=4 {
            g.set_vertex(a, b, 0.5 * a as f32 * 0.1);
        }
    }
    for j in 0..4 {
        for i in 0..4 {
            g.set_triangles(i, j, (i + j) % 2 == 0);
        }
    }
    g
}

#[test]
fn a_step_is_a_step_on_both_sides_of_its_face() {
    let g = step_grid();
    let edge = 0.5;
    assert_eq!(g.height(edge - 1e-3, 0.2), 0.0);
    assert_eq!(g.height(edge + 1e-3, 0.2), 0.15);
    // Flat treads either side.
    assert_eq!(g.height(0.1, 0.2), 0.0);
    assert_eq!(g.height(0.9, 0.2), 0.15);
    assert_eq!(g.normal(edge + 1e-3, 0.2), Vec3::Z);
    assert_eq!(g.normal(edge - 1e-3, 0.2), Vec3::Z);
}

#[test]
fn outside_the_grid_is_flat_ground() {
    let g = step_grid();
    for (x, y) in [(-1.0, 0.2), (2.0, 0.2), (0.5, -3.0), (0.5, 7.0)] {
        assert_eq!(g.height(x, y), 0.0);
        assert_eq!(g.normal(x, y), Vec3::Z);
    }
    // Non-finite points do not panic.
    assert_eq!(g.height(f32::NAN, 0.0), 0.0);
    assert_eq!(g.normal(0.0, f32::INFINITY), Vec3::Z);
    assert!(g.max_height_within(f32::NAN, 0.0, 0.1).is_finite());
}

#[test]
fn triangles_follow_the_vertex_plane_whatever_the_split() {
    let g = slope_grid();
    let expected = Vec3::new(-0.5, 0.0, 1.0).normalize();
    for (x, y) in [(0.05, 0.05), (0.17, 0.31), (0.33, 0.12), (0.26, 0.38)] {
        assert!((g.height(x, y) - 0.5 * x).abs() < 1e-6, "at ({x}, {y})");
        assert!((g.normal(x, y) - expected).length() < 1e-5, "at ({x}, {y})");
    }
}

#[test]
fn max_height_within_sees_a_step_inside_the_radius_only() {
    let g = step_grid();
    // 2 cm from the face: a 3 cm radius reaches over it, a 1 cm one does not.
    assert_eq!(g.max_height_within(0.48, 0.2, 0.03), 0.15);
    assert_eq!(g.max_height_within(0.48, 0.2, 0.01), 0.0);
    // Diagonally: the face is 0.02 m away along x whatever the direction of the radius.
    assert_eq!(g.max_height_within(0.48, 0.215, 0.021), 0.15);
    // A step beyond the grid's edge (the border at 0) is not higher.
    assert_eq!(g.max_height_within(0.95, 0.2, 0.2), 0.15);
    // Zero radius: the height itself.
    assert_eq!(g.max_height_within(0.48, 0.2, 0.0), 0.0);
}

#[test]
fn max_height_within_finds_the_uphill_point_on_a_slope() {
    let g = slope_grid();
    let (x, y, r) = (0.2, 0.2, 0.05);
    let h = g.max_height_within(x, y, r);
    assert!((h - 0.5 * (x + r)).abs() < 1e-5, "{h}");
}

#[test]
fn max_height_in_square_covers_the_cells_it_meets() {
    let g = step_grid();
    assert_eq!(g.max_height_in_square(0.1, 0.1, 0.3, 0.3), 0.0);
    assert_eq!(g.max_height_in_square(0.1, 0.1, 0.55, 0.3), 0.15);
}
