//! legged_gym's game-inspired terrain curriculum as pure functions: which column an env starts
//! in, and how its level changes between episodes.

use rand::{Rng, RngExt};

/// The grid column of env `env_index` of `num_envs` with `num_columns` columns: envs fill the
/// columns in contiguous blocks, as legged_gym (`floor(index / (num_envs / num_columns))`).
pub fn initial_column(env_index: usize, num_envs: usize, num_columns: u32) -> u32 {
    let columns = num_columns.max(1) as usize;
    let n = num_envs.max(1);
    ((env_index.min(n - 1) * columns) / n) as u32
}

/// The level after an episode (legged_gym's `_update_terrain_curriculum`): up one when the env
/// walked more than half a tile (`distance_walked > tile_size / 2`), down one when it walked
/// less than half of what its commands asked for (`distance_walked < commanded_distance * 0.5`)
/// and is not moving up. Going down stops at level 0; going past the top level sends the env to
/// a level drawn uniformly from `0..num_levels`, so solved envs keep visiting every level.
///
/// `commanded_distance` is |command xy| x episode length (m), as legged_gym.
pub fn next_level(
    current: u32,
    distance_walked: f32,
    commanded_distance: f32,
    num_levels: u32,
    tile_size: f32,
    rng: &mut impl Rng,
) -> u32 {
    let up = distance_walked > 0.5 * tile_size;
    let down = !up && distance_walked < 0.5 * commanded_distance;
    if up {
        let next = current.saturating_add(1);
        if next >= num_levels {
            return rng.random_range(0..num_levels.max(1));
        }
        next
    } else if down {
        current.saturating_sub(1)
    } else {
        current.min(num_levels.saturating_sub(1))
    }
}

#[cfg(test)]
#[path = "curriculum_test.rs"]
mod test;
