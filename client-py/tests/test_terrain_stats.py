"""Terrain level per type and per mode: env -> column layout and hand-computed means."""

from __future__ import annotations

import math

import torch

from unigait.env.terrain_stats import (
    TerrainLevelStats,
    env_terrain_types,
    grid_change,
    initial_column,
)

#: The server's default grid (a curriculum spec's ``terrain_columns``): legged_gym's
#: proportions over 20 columns.
DEFAULT_GRID = (
    ["slope_up", "slope_down"]
    + ["rough_slope"] * 2
    + ["stairs_up"] * 7
    + ["stairs_down"] * 5
    + ["obstacles"] * 4
)


def test_columns_in_blocks_as_the_server() -> None:
    assert [initial_column(i, 14, 7) for i in range(14)] == [i // 2 for i in range(14)]
    assert [initial_column(i, 3, 7) for i in range(3)] == [0, 2, 4]
    # 40 envs on 20 columns: two per column; stairs up are columns 4-10 -> envs 8-21.
    types = env_terrain_types("curriculum", DEFAULT_GRID, [40])
    assert types[:2] == ["slope_up", "slope_up"]
    assert types[2:4] == ["slope_down", "slope_down"]
    assert types[8:22] == ["stairs_up"] * 14
    assert types[22:32] == ["stairs_down"] * 10
    assert types[32:] == ["obstacles"] * 8
    # Sharded (20 + 20): each shard lays out its own 20 columns, one env each.
    sharded = env_terrain_types("curriculum", DEFAULT_GRID, [20, 20])
    assert sharded[:20] == sharded[20:]
    assert sharded[4:11] == ["stairs_up"] * 7
    # A grid of its own: 6 envs on 3 columns.
    own = env_terrain_types("curriculum", ["slope_up", "slope_up", "stairs_down"], [6])
    assert own == ["slope_up"] * 4 + ["stairs_down"] * 2
    # An older server names no columns: one type for the whole grid.
    assert env_terrain_types("curriculum", [], [2]) == ["curriculum"] * 2
    assert env_terrain_types("stairs_down level 6", [], [3]) == ["stairs_down"] * 3
    assert env_terrain_types("flat", [], [2]) == ["flat", "flat"]


def test_means_per_type_and_mode_by_hand() -> None:
    stats = TerrainLevelStats(
        ["stairs_up", "stairs_up", "obstacles", "slope_up"], torch.device("cpu")
    )
    # Step 1: levels 2, 4, 6, 1; modes quad, biped, biped, quad (the wire's 2 and 1).
    stats.add(torch.tensor([2, 4, 6, 1]), torch.tensor([2, 1, 1, 2], dtype=torch.uint8))
    # Step 2: levels 3, 5, 7, 1; all quad.
    stats.add(torch.tensor([3, 5, 7, 1]), torch.tensor([2, 2, 2, 2], dtype=torch.uint8))
    out = stats.summary()
    # stairs_up: (2 + 4 + 3 + 5) / 4 = 3.5; obstacles (6 + 7) / 2 = 6.5; slope_up 1.
    assert out["terrain_level/stairs_up"] == 3.5
    assert out["terrain_level/obstacles"] == 6.5
    assert out["terrain_level/slope_up"] == 1.0
    # quad: (2 + 1 + 3 + 5 + 7 + 1) / 6 = 19 / 6; biped: (4 + 6) / 2 = 5.
    assert math.isclose(out["terrain_level/quad"], 19 / 6)
    assert out["terrain_level/biped"] == 5.0
    # Per type and mode: stairs up on four legs (2 + 3 + 5) / 3, on two 4; obstacles 7 and 6;
    # slope up 1 on four legs and never on two.
    assert math.isclose(out["terrain_level/stairs_up/quad"], 10 / 3)
    assert out["terrain_level/stairs_up/biped"] == 4.0
    assert out["terrain_level/obstacles/quad"] == 7.0
    assert out["terrain_level/obstacles/biped"] == 6.0
    assert out["terrain_level/slope_up/quad"] == 1.0
    assert math.isnan(out["terrain_level/slope_up/biped"])
    assert list(out) == [
        "terrain_level/stairs_up",
        "terrain_level/obstacles",
        "terrain_level/slope_up",
        "terrain_level/quad",
        "terrain_level/biped",
        "terrain_level/stairs_up/quad",
        "terrain_level/stairs_up/biped",
        "terrain_level/obstacles/quad",
        "terrain_level/obstacles/biped",
        "terrain_level/slope_up/quad",
        "terrain_level/slope_up/biped",
        "promoted/stairs_up",
        "demoted/stairs_up",
        "promoted/obstacles",
        "demoted/obstacles",
        "promoted/slope_up",
        "demoted/slope_up",
    ]
    # Cleared: the same keys (the CSV's columns from the first row on), NaN without steps.
    again = stats.summary()
    assert list(again) == list(out)
    assert all(math.isnan(v) for v in again.values())
    # A rollout with no biped step: the biped key is there, NaN.
    stats.add(torch.tensor([1, 1, 1, 1]), torch.tensor([2, 2, 2, 2]))
    assert math.isnan(stats.summary()["terrain_level/biped"])


def test_level_moves_per_type_by_hand() -> None:
    stats = TerrainLevelStats(
        ["stairs_up", "stairs_up", "stairs_up", "obstacles"], torch.device("cpu")
    )
    # Step 1: envs 0 and 3 end; env 0 comes back a level up, env 3 stays. Env 1's level may not
    # change without an end, and does not count.
    stats.add_episode_ends(
        torch.tensor([2, 4, 6, 1]), torch.tensor([3, 4, 6, 1]), torch.tensor([1, 0, 0, 1])
    )
    # Step 2: envs 1 and 2 end; env 1 down, env 2 from the top level to a random lower one.
    stats.add_episode_ends(
        torch.tensor([3, 4, 9, 1]), torch.tensor([3, 3, 0, 1]), torch.tensor([0, 1, 1, 0])
    )
    out = stats.summary()
    # stairs_up: 3 ends, 1 up, 2 down; obstacles: 1 end, no move.
    assert math.isclose(out["promoted/stairs_up"], 1 / 3)
    assert math.isclose(out["demoted/stairs_up"], 2 / 3)
    assert out["promoted/obstacles"] == 0.0 and out["demoted/obstacles"] == 0.0
    assert math.isnan(stats.summary()["promoted/stairs_up"])


def test_a_resumed_grid_names_the_columns_that_changed_type() -> None:
    stage_19 = list(DEFAULT_GRID)
    stage_19[11:13] = ["slope_up", "slope_up"]
    assert grid_change(DEFAULT_GRID, stage_19) == (
        "columns that changed type, their envs keeping their levels: "
        "11 (stairs_down -> slope_up), 12 (stairs_down -> slope_up)"
    )
    assert grid_change(DEFAULT_GRID, DEFAULT_GRID) is None
    assert grid_change([], stage_19) is None  # a checkpoint from before the grid was saved
    assert grid_change(DEFAULT_GRID, []) is None  # flat ground, or an older server
    assert grid_change(DEFAULT_GRID, DEFAULT_GRID[:10]) == (
        "the grid has 10 columns, the checkpoint's had 20"
    )
