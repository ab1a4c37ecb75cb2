//! The mesh against the height queries: what a ray hits is what `height` answers, and step
//! faces are vertical walls at their cell edges.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::math::Pose;
use rapier3d::parry::query::Ray;

use super::*;
use crate::terrain::generator::generate;
use crate::terrain::spec::{TerrainKind, TerrainSpec, TerrainType};

fn spec() -> TerrainSpec {
    TerrainSpec {
        kind: TerrainKind::Curriculum { max_init_level: 5 },
        ..TerrainSpec::default()
    }
}

/// Height of the shape's surface under (x, y), by a vertical ray from above.
fn ray_height(shape: &SharedShape, x: f32, y: f32) -> Option<f32> {
    let ray = Ray::new(Vec3::new(x, y, 10.0), -Vec3::Z);
    shape
        .cast_ray(&Pose::IDENTITY, &ray, 100.0, true)
        .map(|t| 10.0 - t)
}

#[test]
fn the_mesh_is_the_surface_the_queries_answer_for() {
    let spec = spec();
    let cells = generate(&spec, 11);
    let shape = trimesh(&cells, spec.border).expect("mesh");
    let (w, h) = (cells.nx() as f32 * 0.1, cells.ny() as f32 * 0.1);
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut checked = 0;
    while checked < 20_000 {
        let x = rng.random_range(-10.0..w + 10.0);
        let y = rng.random_range(-10.0..h + 10.0);
        // A ray exactly on a wall may hit either side.
        let near_edge = |v: f32| ((v * 10.0) - (v * 10.0).round()).abs() < 1e-3;
        if near_edge(x) || near_edge(y) {
            continue;
        }
        let hit = ray_height(&shape, x, y).expect("the mesh covers the grid and the border");
        let expected = cells.height(x, y);
        assert!(
            (hit - expected).abs() < 2e-4,
            "at ({x}, {y}): mesh {hit}, query {expected}"
        );
        checked += 1;
    }
}

#[test]
fn step_faces_are_vertical_walls_on_their_cell_edges() {
    let spec = spec();
    let cells = generate(&spec, 11);
    let shape = trimesh(&cells, spec.border).expect("mesh");
    let column = spec.column_of(TerrainType::StairsDown).expect("stairs");
    let (x0, y) = (9.0 * spec.tile_size, (column as f32 + 0.5) * spec.tile_size);
    let step = spec.step_height_at(9);
    // The first riser stands at x0 + 0.3 m, from 0 to `step`; aim at it from 0.2 m away at
    // several heights: a vertical face is hit 0.2 m away, facing -x, at every height.
    for z in [0.1 * step, 0.5 * step, 0.98 * step] {
        let ray = Ray::new(Vec3::new(x0 + 0.1, y, z), Vec3::X);
        let hit = shape
            .cast_ray_and_get_normal(&Pose::IDENTITY, &ray, 10.0, true)
            .expect("the riser");
        assert!(
            (hit.time_of_impact - 0.2).abs() < 1e-4,
            "hit at {} (z {z})",
            hit.time_of_impact
        );
        assert!(
            (hit.normal - -Vec3::X).length() < 1e-4,
            "normal {:?}",
            hit.normal
        );
    }
}

#[test]
fn flat_and_coplanar_cells_merge_into_few_triangles() {
    let flat = TerrainSpec {
        types: vec![TerrainType::Flat],
        num_levels: 3,
        ..spec()
    };
    let buffers = mesh_buffers(&generate(&flat, 0), flat.border);
    // One rectangle for the grid, four for the border.
    assert_eq!(buffers.indices.len(), 10);
    let full = mesh_buffers(&generate(&spec(), 0), 25.0);
    // The rough slopes (2 of 20 columns) dominate with two triangles per cell; the other 180
    // tiles take about 160 each.
    let rough_cells = 2 * 10 * 80 * 80;
    assert!(
        full.indices.len() < 2 * rough_cells + 200 * 180,
        "{} triangles",
        full.indices.len()
    );
}

#[test]
fn crossing_walls_split_at_the_crossing() {
    let mut out = MeshBuffers::default();
    let (p0, p1) = (Vec3::ZERO, Vec3::new(0.0, 1.0, 0.0));
    // Side A goes from 0 to 1, side B from 1 to 0: they cross half-way.
    wall(p0, p1, ([0.0, 1.0], [1.0, 0.0]), &mut out);
    assert_eq!(out.indices.len(), 2);
    assert!(
        out.vertices
            .iter()
            .any(|v| (*v - Vec3::new(0.0, 0.5, 0.5)).length() < 1e-6)
    );
    // Equal at one end: one triangle.
    let mut out = MeshBuffers::default();
    wall(p0, p1, ([0.0, 1.0], [0.0, 0.0]), &mut out);
    assert_eq!(out.indices.len(), 1);
}
