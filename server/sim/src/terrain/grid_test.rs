//! Tile origins, starting tiles and level changes of a generated grid.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::*;

fn walked(walked: f32, commanded: f32) -> EpisodeDistance {
    EpisodeDistance {
        walked,
        commanded,
        commanded_biped: 0.0,
        walked_biped: 0.0,
        ..EpisodeDistance::default()
    }
}

fn grid(kind: TerrainKind) -> TerrainGrid {
    let spec = TerrainSpec {
        kind,
        ..TerrainSpec::default()
    };
    TerrainGrid::new(&spec, 1).expect("grid")
}

#[test]
fn tile_origins_are_tile_centres_at_the_platform_height() {
    let g = grid(TerrainKind::Curriculum { max_init_level: 5 });
    let spec = g.spec().clone();
    for level in 0..g.num_levels() {
        for column in 0..g.num_columns() {
            let o = g.tile_origin(level, column);
            assert_eq!(o.x, (level as f32 + 0.5) * 8.0);
            assert_eq!(o.y, (column as f32 + 0.5) * 8.0);
            // Every platform is flat: the origin sits on it.
            assert!(
                (o.z - g.height(o.x, o.y)).abs() < 1e-5,
                "tile ({level}, {column})"
            );
            assert!((o.z - g.max_height_within(o.x, o.y, 0.6)).abs() < 1e-5);
        }
    }
    // Eight 0.20 m steps up to (or down into) the top level's platform.
    let stairs = spec.column_of(TerrainType::StairsDown).expect("stairs");
    assert!((g.tile_origin(9, stairs).z - 8.0 * 0.20).abs() < 1e-5);
    let pit = spec.column_of(TerrainType::StairsUp).expect("stairs");
    assert!((g.tile_origin(9, pit).z + 8.0 * 0.20).abs() < 1e-5);
    // Out of range: clamped.
    assert_eq!(g.tile_origin(50, 50), g.tile_origin(9, 19));
}

#[test]
fn curriculum_envs_fill_columns_in_blocks_at_random_levels_up_to_the_max() {
    let g = grid(TerrainKind::Curriculum { max_init_level: 3 });
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let n = 200;
    let mut seen = [false; 4];
    for i in 0..n {
        let (level, column) = g.initial_tile(i, n, &mut rng);
        assert_eq!(column as usize, i / 10);
        assert!(level <= 3);
        seen[level as usize] = true;
    }
    assert!(seen.iter().all(|s| *s), "every level 0..=3 drawn");
}

#[test]
fn deterministic_tiles_cover_every_starting_tile() {
    let g = grid(TerrainKind::Curriculum { max_init_level: 9 });
    let mut tiles: Vec<(u32, u32)> = (0..200).map(|i| g.deterministic_tile(i, 200)).collect();
    tiles.sort();
    tiles.dedup();
    assert_eq!(tiles.len(), 200);
}

#[test]
fn pinned_envs_stay_on_their_tile() {
    let g = grid(TerrainKind::Pinned {
        terrain_type: TerrainType::StairsUp,
        level: 5,
    });
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    // Stairs up are columns 4-10 of the default grid: the first one.
    assert_eq!(g.initial_tile(17, 100, &mut rng), (5, 4));
    assert_eq!(g.deterministic_tile(17, 100), (5, 4));
    assert_eq!(
        g.next_level(5, walked(100.0, 10.0), &LevelRule::default(), &mut rng),
        5
    );
    assert_eq!(
        g.next_level(5, walked(0.0, 100.0), &LevelRule::default(), &mut rng),
        5
    );
}

#[test]
fn curriculum_grids_move_levels_pinned_and_flat_do_not() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let g = grid(TerrainKind::Curriculum { max_init_level: 5 });
    // The spec's default rule: up above 70 % and 2 m, down below 50 %.
    assert_eq!(
        g.next_level(3, walked(7.5, 10.0), &LevelRule::default(), &mut rng),
        4
    );
    assert_eq!(
        g.next_level(3, walked(6.0, 10.0), &LevelRule::default(), &mut rng),
        3
    );
    assert_eq!(
        g.next_level(3, walked(1.0, 10.0), &LevelRule::default(), &mut rng),
        2
    );
    let flat = grid(TerrainKind::Flat);
    assert_eq!(
        flat.next_level(3, walked(7.5, 10.0), &LevelRule::default(), &mut rng),
        3
    );
    assert_eq!(flat.initial_tile(3, 10, &mut rng), (0, 0));
}

#[test]
fn grids_compare_by_spec_and_seed() {
    let spec = TerrainSpec {
        kind: TerrainKind::Curriculum { max_init_level: 1 },
        num_levels: 2,
        ..TerrainSpec::default()
    };
    let a = TerrainGrid::new(&spec, 1).expect("grid");
    let b = TerrainGrid::new(&spec, 1).expect("grid");
    let c = TerrainGrid::new(&spec, 2).expect("grid");
    assert_eq!(a, b);
    assert_ne!(a, c);
    assert!(format!("{a:?}").contains("TerrainGrid"));
}

#[test]
fn a_resumed_curriculum_starts_its_envs_on_the_levels_it_is_given() {
    let mut g = grid(TerrainKind::Curriculum { max_init_level: 1 });
    // Levels far above max_init_level: only the given levels can put envs there.
    let levels: Vec<u32> = (0..40).map(|i| 9 - (i % 4)).collect();
    g.set_initial_levels(levels.clone())
        .expect("levels on the grid");
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    for (i, level) in levels.iter().enumerate() {
        assert_eq!(g.initial_tile(i, 40, &mut rng), (*level, (i / 2) as u32));
    }
    // An env past the list draws as before.
    assert!(g.initial_tile(45, 50, &mut rng).0 <= 1);
    // Levels off the grid and non-curriculum grids are refused.
    assert!(g.set_initial_levels(vec![0, 10]).is_err());
    let mut pinned = grid(TerrainKind::Pinned {
        terrain_type: TerrainType::StairsUp,
        level: 2,
    });
    assert!(pinned.set_initial_levels(vec![3]).is_err());
}
