//! legged_gym's curriculum rule, case by case.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::*;

const TILE: f32 = 8.0;

#[test]
fn walking_more_than_half_a_tile_moves_up() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    assert_eq!(next_level(3, 4.01, 20.0, 10, TILE, &mut rng), 4);
    // Moving up wins over moving down (commands asked for far more).
    assert_eq!(next_level(3, 4.01, 100.0, 10, TILE, &mut rng), 4);
    // Exactly half a tile is not more than half.
    assert_eq!(next_level(3, 4.0, 0.0, 10, TILE, &mut rng), 3);
}

#[test]
fn walking_less_than_half_the_commanded_distance_moves_down() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    assert_eq!(next_level(3, 2.9, 6.0, 10, TILE, &mut rng), 2);
    assert_eq!(next_level(3, 3.0, 6.0, 10, TILE, &mut rng), 3);
    // Standing still under a zero command stays.
    assert_eq!(next_level(3, 0.0, 0.0, 10, TILE, &mut rng), 3);
    // Level 0 is the floor.
    assert_eq!(next_level(0, 0.0, 10.0, 10, TILE, &mut rng), 0);
}

#[test]
fn passing_the_top_level_sends_to_a_random_level() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut seen = [false; 10];
    for _ in 0..500 {
        let l = next_level(9, 5.0, 0.0, 10, TILE, &mut rng);
        assert!(l < 10);
        seen[l as usize] = true;
    }
    assert!(seen.iter().all(|s| *s));
    // Below the top: a plain step up.
    assert_eq!(next_level(8, 5.0, 0.0, 10, TILE, &mut rng), 9);
}

#[test]
fn columns_are_filled_in_blocks() {
    let columns: Vec<u32> = (0..14).map(|i| initial_column(i, 14, 7)).collect();
    assert_eq!(columns, [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6]);
    // Fewer envs than columns: spread out, never past the last column.
    let few: Vec<u32> = (0..3).map(|i| initial_column(i, 3, 7)).collect();
    assert_eq!(few, [0, 2, 4]);
    assert_eq!(initial_column(99, 3, 7), 4);
}
