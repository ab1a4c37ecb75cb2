//! The heightfield comparison collider: turned Z-up with the grid's splits, it matches the
//! queries away from steps; at a step it is a ramp one sample wide.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::parry::query::Ray;

use super::*;
use crate::terrain::generator::generate;
use crate::terrain::spec::{TerrainKind, TerrainSpec, TerrainType};

fn spec() -> TerrainSpec {
    TerrainSpec {
        kind: TerrainKind::Curriculum { max_init_level: 5 },
        types: vec![
            TerrainType::SlopeUp,
            TerrainType::RoughSlope,
            TerrainType::StairsDown,
        ],
        num_levels: 3,
        border: 2.0,
        ..TerrainSpec::default()
    }
}

fn ray_height(shape: &SharedShape, pose: &Pose, x: f32, y: f32) -> Option<f32> {
    let ray = Ray::new(Vec3::new(x, y, 10.0), -Vec3::Z);
    shape.cast_ray(pose, &ray, 100.0, true).map(|t| 10.0 - t)
}

#[test]
fn heightfield_matches_the_queries_on_slopes() {
    let spec = spec();
    let cells = generate(&spec, 4);
    let (shape, pose) = heightfield(&cells, spec.border, 1);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..5000 {
        // Slope and rough slope columns, and the border beyond them.
        let x = rng.random_range(-1.5..25.5);
        let y = rng.random_range(-1.5..15.9);
        let hit = ray_height(&shape, &pose, x, y).expect("covered");
        let expected = cells.height(x, y);
        assert!(
            (hit - expected).abs() < 2e-4,
            "at ({x}, {y}): {hit} vs {expected}"
        );
    }
}

#[test]
fn heightfield_steps_are_ramps_one_sample_wide() {
    let spec = spec();
    let cells = generate(&spec, 4);
    let y = 2.5 * spec.tile_size;
    let x0 = 2.0 * spec.tile_size;
    let step = spec.step_height_at(2);
    for k in [1u32, 4] {
        let (shape, pose) = heightfield(&cells, spec.border, k);
        let sample = 0.1 / k as f32;
        // Half a sample before the first riser at x0 + 0.3: half-way up the ramp.
        let h = ray_height(&shape, &pose, x0 + 0.3 - 0.5 * sample, y).expect("hit");
        assert!((h - 0.5 * step).abs() < 1e-4, "k {k}: {h}");
        // A sample before it: the lower tread.
        let h = ray_height(&shape, &pose, x0 + 0.3 - 1.5 * sample, y).expect("hit");
        assert!(h.abs() < 1e-4, "k {k}: {h}");
    }
}
