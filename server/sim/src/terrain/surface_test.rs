//! Cell surfaces: both splits pass through the corners, are continuous across their diagonal,
//! and report the gradient of the face a point is on.

use super::*;

const CORNERS: [f32; 4] = [0.1, 0.4, -0.2, 0.9];

fn both_splits() -> [CellSurface; 2] {
    [true, false].map(|main_diagonal| CellSurface::Triangles {
        corners: CORNERS,
        main_diagonal,
    })
}

#[test]
fn triangles_pass_through_their_corners() {
    for s in both_splits() {
        for (k, h) in CORNERS.iter().enumerate() {
            let (u, v) = corner_uv(k);
            assert!((s.height(u, v) - h).abs() < 1e-6, "{s:?} corner {k}");
        }
    }
}

#[test]
fn triangles_are_continuous_across_the_diagonal() {
    for s in both_splits() {
        let main = matches!(
            s,
            CellSurface::Triangles {
                main_diagonal: true,
                ..
            }
        );
        for t in [0.1f32, 0.37, 0.8] {
            // A point on the diagonal, approached from both faces.
            let (u, v) = if main { (t, t) } else { (t, 1.0 - t) };
            let e = 1e-4;
            let a = s.height(u + e, v - e * if main { 1.0 } else { -1.0 });
            let b = s.height(u - e, v + e * if main { 1.0 } else { -1.0 });
            assert!((a - b).abs() < 1e-3, "{s:?} at {t}: {a} vs {b}");
        }
    }
}

#[test]
fn gradient_matches_finite_differences() {
    for s in both_splits() {
        for (u, v) in [(0.2f32, 0.7f32), (0.7, 0.2), (0.3, 0.4), (0.8, 0.9)] {
            let (du, dv) = s.gradient(u, v);
            let e = 1e-3;
            let fu = (s.height(u + e, v) - s.height(u - e, v)) / (2.0 * e);
            let fv = (s.height(u, v + e) - s.height(u, v - e)) / (2.0 * e);
            assert!(
                (du - fu).abs() < 1e-3 && (dv - fv).abs() < 1e-3,
                "{s:?} at ({u}, {v})"
            );
        }
    }
}

#[test]
fn split_is_the_other_diagonal_when_not_main() {
    // Corners with a ridge along 10-01: only the 10-01 split keeps the ridge.
    let ridge = [0.0, 1.0, 1.0, 0.0];
    let main = CellSurface::Triangles {
        corners: ridge,
        main_diagonal: true,
    };
    let other = CellSurface::Triangles {
        corners: ridge,
        main_diagonal: false,
    };
    assert!((other.height(0.5, 0.5) - 1.0).abs() < 1e-6);
    assert!(main.height(0.5, 0.5).abs() < 1e-6);
}

#[test]
fn flat_cells_are_level_with_equal_edges() {
    let s = CellSurface::Flat(0.3);
    assert_eq!(s.height(0.2, 0.9), 0.3);
    assert_eq!(s.gradient(0.2, 0.9), (0.0, 0.0));
    for side in [Side::West, Side::East, Side::South, Side::North] {
        assert_eq!(s.edge(side), [0.3, 0.3]);
    }
    assert_eq!(s.plane(0.0), Some([0.3, 0.0, 0.0]));
}

#[test]
fn edges_and_planes_of_triangle_cells() {
    let s = both_splits()[0];
    assert_eq!(s.edge(Side::West), [CORNERS[0], CORNERS[2]]);
    assert_eq!(s.edge(Side::East), [CORNERS[1], CORNERS[3]]);
    assert_eq!(s.edge(Side::South), [CORNERS[0], CORNERS[1]]);
    assert_eq!(s.edge(Side::North), [CORNERS[2], CORNERS[3]]);
    assert_eq!(s.max_corner(), 0.9);
    // Not coplanar: 0.1 + 0.9 != 0.4 - 0.2.
    assert_eq!(s.plane(1e-5), None);
    let tilted = CellSurface::Triangles {
        corners: [0.0, 0.1, 0.2, 0.3],
        main_diagonal: true,
    };
    let p = tilted.plane(1e-5).expect("coplanar");
    assert!((p[1] - 0.1).abs() < 1e-6 && (p[2] - 0.2).abs() < 1e-6);
}
