//! Each tile type against its analytic shape, and the grid's determinism.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::terrain::spec::TerrainKind;

fn spec() -> TerrainSpec {
    TerrainSpec {
        kind: TerrainKind::Curriculum { max_init_level: 5 },
        ..TerrainSpec::default()
    }
}

/// World (x, y) of tile point (u, v) of tile (level, column).
fn at(spec: &TerrainSpec, level: u32, column: u32, u: f32, v: f32) -> (f32, f32) {
    (
        level as f32 * spec.tile_size + u,
        column as f32 * spec.tile_size + v,
    )
}

fn column(spec: &TerrainSpec, t: TerrainType) -> u32 {
    spec.column_of(t).expect("type on the grid")
}

#[test]
fn slopes_are_the_analytic_pyramid() {
    let spec = spec();
    let grid = generate(&spec, 3);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    for (t, sign) in [(TerrainType::SlopeDown, 1.0), (TerrainType::SlopeUp, -1.0)] {
        for level in [0, 4, 9] {
            let slope = spec.slope(level);
            for _ in 0..500 {
                let (u, v) = (rng.random_range(0.0..8.0), rng.random_range(0.0..8.0));
                let (x, y) = at(&spec, level, column(&spec, t), u, v);
                let expected = sign * pyramid(u, v, 8.0, 3.0, slope);
                let h = grid.height(x, y);
                assert!(
                    (h - expected).abs() < 2e-4,
                    "{t} level {level} at ({u}, {v}): {h} vs {expected}"
                );
            }
        }
    }
}

#[test]
fn the_slopes_reach_thirty_degrees_at_level_seven_and_37_at_the_top() {
    let spec = spec();
    let grid = generate(&spec, 3);
    let c = column(&spec, TerrainType::SlopeDown);
    // Mid-way down the +x face, and on the -y face.
    // atan(7/9 tan 37 deg) = 30.37 deg; atan(tan 37 deg) = 37 deg.
    for (level, deg) in [(7, 30.37), (9, 37.0)] {
        for (u, v, axis) in [(6.0, 4.3, 0), (3.7, 1.5, 1)] {
            let (x, y) = at(&spec, level, c, u, v);
            let n = grid.normal(x, y);
            let tilt = n.z.acos().to_degrees();
            assert!(
                (tilt - deg).abs() < 0.01,
                "level {level}: tilt {tilt} at ({u}, {v})"
            );
            // The normal leans away from the centre, downhill: sin(tilt).
            let lean = if axis == 0 { n.x } else { -n.y };
            assert!((lean - deg.to_radians().sin()).abs() < 1e-3, "normal {n:?}");
        }
    }
}

#[test]
fn stairs_have_vertical_steps_and_flat_treads() {
    let spec = spec();
    let grid = generate(&spec, 3);
    let w = spec.step_cells() as f32 * spec.horizontal_scale;
    assert!(
        (w - 0.3).abs() < 1e-6,
        "step width rounds to 0.3 m on 0.1 m cells"
    );
    for (t, sign) in [
        (TerrainType::StairsDown, 1.0),
        (TerrainType::StairsUp, -1.0),
    ] {
        for level in [0, 5, 9] {
            let h = spec.step_height_at(level);
            let c = column(&spec, t);
            // Walk in from the tile's -x edge along its centre line.
            for k in 1..=8 {
                let edge = k as f32 * w;
                let (x, y) = at(&spec, level, c, edge, 4.0);
                let below = grid.height(x - 1e-3, y);
                let above = grid.height(x + 1e-3, y);
                assert!(
                    (above - below - sign * h).abs() < 1e-5,
                    "{t} level {level} edge {k}: {below} -> {above}"
                );
                // Mid-tread: flat, at the tread's height.
                let mid = grid.height(x + 0.5 * w, y);
                assert_eq!(mid, above);
                assert_eq!(grid.normal(x + 0.5 * w, y), rapier3d::math::Vec3::Z);
            }
            // The platform is flat and at least platform_size wide.
            let (cx, cy) = at(&spec, level, c, 4.0, 4.0);
            let top = grid.height(cx, cy);
            assert!((top - sign * 8.0 * h).abs() < 1e-5, "{t} platform at {top}");
            for d in [-1.5f32, 1.49] {
                let (x, y) = at(&spec, level, c, 4.0 + d, 4.0 + d);
                assert_eq!(grid.height(x, y), top);
            }
        }
    }
    // The paper's test stairs: 0.15 m at level 6.
    assert!((spec.step_height_at(6) - 0.15).abs() < 1e-6);
}

#[test]
fn every_tile_meets_its_neighbours_at_zero() {
    let spec = spec();
    let grid = generate(&spec, 9);
    for level in 0..spec.num_levels {
        for c in 0..spec.types.len() as u32 {
            for k in 0..80 {
                let t = k as f32 * 0.1 + 0.05;
                // 1 mm inside each edge.
                for (u, v) in [(1e-3, t), (8.0 - 1e-3, t), (t, 1e-3), (t, 8.0 - 1e-3)] {
                    let (x, y) = at(&spec, level, c, u, v);
                    let h = grid.height(x, y);
                    let obstacles = spec.types[c as usize] == TerrainType::Obstacles;
                    // Slopes and noise are 0 at the edge itself: within 1 mm of 30 deg of it.
                    assert!(
                        obstacles || h.abs() <= 2e-3,
                        "tile ({level}, {c}) at ({u}, {v}): {h}"
                    );
                }
            }
        }
    }
}

#[test]
fn rough_slope_is_the_hill_plus_bounded_noise_with_a_flat_platform() {
    let spec = spec();
    let grid = generate(&spec, 5);
    let c = column(&spec, TerrainType::RoughSlope);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut max_dev: f32 = 0.0;
    for level in [0, 9] {
        for _ in 0..2000 {
            let (u, v) = (rng.random_range(0.0..8.0), rng.random_range(0.0..8.0));
            let (x, y) = at(&spec, level, c, u, v);
            let hill = pyramid(u, v, 8.0, 3.0, spec.slope(level));
            let dev = grid.height(x, y) - hill;
            assert!(dev.abs() <= spec.rough_noise + 1e-4, "noise {dev}");
            max_dev = max_dev.max(dev.abs());
        }
        for (u, v) in [(4.0, 4.0), (2.6, 5.4), (5.45, 2.55)] {
            let (x, y) = at(&spec, level, c, u, v);
            let top = pyramid(4.0, 4.0, 8.0, 3.0, spec.slope(level));
            assert!(
                (grid.height(x, y) - top).abs() < 1e-5,
                "platform at ({u}, {v})"
            );
        }
    }
    assert!(max_dev > 0.02, "the noise is there ({max_dev})");
}

#[test]
fn obstacles_take_the_levels_heights_and_leave_the_platform_clear() {
    let spec = spec();
    let grid = generate(&spec, 5);
    let c = column(&spec, TerrainType::Obstacles);
    for level in [0, 9] {
        let h = spec.obstacle_height_at(level);
        let allowed = [0.0, -h, -0.5 * h, 0.5 * h, h];
        let mut seen_raised = false;
        for b in 0..80 {
            for a in 0..80 {
                let (u, v) = ((a as f32 + 0.5) * 0.1, (b as f32 + 0.5) * 0.1);
                let (x, y) = at(&spec, level, c, u, v);
                let z = grid.height(x, y);
                assert!(allowed.iter().any(|v| (v - z).abs() < 1e-6), "height {z}");
                seen_raised |= z > 0.0;
                if (u - 4.0).abs() < 1.5 && (v - 4.0).abs() < 1.5 {
                    assert_eq!(z, 0.0, "platform at ({u}, {v})");
                }
            }
        }
        assert!(seen_raised);
    }
}

#[test]
fn same_seed_same_heights_other_seed_other_heights() {
    let spec = spec();
    let (a, b, other) = (generate(&spec, 7), generate(&spec, 7), generate(&spec, 8));
    assert!(a == b);
    assert!(a != other, "random tiles depend on the seed");
}

#[test]
fn stair_rings_keep_the_platform() {
    // 80 cells, 3-cell steps, 30-cell platform: 8 rings, a 32-cell top.
    assert_eq!(stair_ring(0, 40, 80, 3, 30), 0);
    assert_eq!(stair_ring(3, 40, 80, 3, 30), 1);
    assert_eq!(stair_ring(23, 40, 80, 3, 30), 7);
    assert_eq!(stair_ring(24, 40, 80, 3, 30), 8);
    assert_eq!(stair_ring(40, 40, 80, 3, 30), 8);
    assert_eq!(stair_ring(79, 40, 80, 3, 30), 0);
}
