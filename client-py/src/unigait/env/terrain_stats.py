"""The terrain curriculum's log, per iteration: levels per terrain type and mode, and level moves.

The mean level per terrain type and per mode, and the share of each type's ended episodes that
moved their env up or down a level.

The step reply carries each env's level but not its terrain type. The type needs no per-step
field: the server places env ``i`` of a session of ``n`` envs in grid column ``i * C // n`` (``C``
columns, legged_gym's blocks; ``initial_column`` in server/sim/src/terrain/curriculum.rs) and
never moves it to another column, and the session's spec lists the grid's columns
(``Spec.terrain_columns``). A sharded batch is one session per shard, so columns are counted per
shard.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from unigait.env.torch_env import TorchVecEnv

#: Task modes as this module counts them (index 0 quad, 1 biped).
MODES: tuple[str, ...] = ("quad", "biped")
#: Biped mode in the step's ``mode`` tensor (1 biped, 2 quad: the paper's x).
BIPED_MODE = 1


def initial_column(env_index: int, num_envs: int, num_columns: int) -> int:
    """Grid column of env ``env_index`` of ``num_envs`` (the server's rule, in blocks)."""
    columns = max(num_columns, 1)
    n = max(num_envs, 1)
    return (min(env_index, n - 1) * columns) // n


def env_terrain_types(terrain: str, columns: Sequence[str], counts: Sequence[int]) -> list[str]:
    """The terrain type of every env of a batch.

    Args:
        terrain: The spec's terrain description: ``"flat"``, ``"curriculum"`` or
            ``"<type> level <l>"`` (every env pinned to one tile).
        columns: The curriculum grid's column types (``Spec.terrain_columns``); a curriculum
            without them (an older server) counts every env as ``"curriculum"``.
        counts: Envs per session, in batch order (one entry unless sharded).

    Returns:
        One type name per env (``"flat"`` on flat ground).
    """
    total = sum(counts)
    if terrain == "curriculum" and columns:
        return [
            columns[initial_column(i, count, len(columns))]
            for count in counts
            for i in range(count)
        ]
    name = terrain.split(" ")[0] if terrain else "flat"
    return [name] * total


def grid_change(before: Sequence[str], after: Sequence[str]) -> str | None:
    """What a resumed run's grid changed: the columns whose type differs, or None.

    ``before`` is a checkpoint's ``terrain_columns``, ``after`` the new session's
    (``Spec.terrain_columns``); either empty (an older checkpoint or server, or flat ground)
    tells nothing. Each env keeps its column and its level, which on a changed column is a level
    of the new type (decision record 0037).
    """
    if not before or not after:
        return None
    if len(before) != len(after):
        return f"the grid has {len(after)} columns, the checkpoint's had {len(before)}"
    changed = [
        f"{i} ({old} -> {new})"
        for i, (old, new) in enumerate(zip(before, after, strict=True))
        if old != new
    ]
    if not changed:
        return None
    return "columns that changed type, their envs keeping their levels: " + ", ".join(changed)


class TerrainLevelStats:
    """Sums of the terrain level over env-steps, by terrain type and by mode, and level moves.

    Scalars ``terrain_level/<type>`` for every type of the batch's grid and
    ``terrain_level/quad`` / ``terrain_level/biped`` always, so the CSV has its columns from the
    first iteration (NaN where a rollout had no such env-step), then
    ``terrain_level/<type>/<mode>``: the mean level of the type's tiles over the env-steps taken
    in that mode (with a level per mode, decision 0036, where each mode's climbing shows). Then
    ``promoted/<type>`` and
    ``demoted/<type>``: the share of the type's episodes ended in the rollout after which the env
    came back a level higher or lower (NaN without an ended episode). A row's top level promotes
    to a random level (legged_gym's rule), which counts here by where it lands.

    Args:
        env_types: The terrain type of every env (:func:`env_terrain_types`).
        device: Where the sums live (that of the step tensors).
    """

    def __init__(self, env_types: Sequence[str], device: torch.device) -> None:
        self.types: tuple[str, ...] = tuple(dict.fromkeys(env_types))
        index = {name: k for k, name in enumerate(self.types)}
        self.type_of_env = torch.tensor(
            [index[t] for t in env_types], dtype=torch.int64, device=device
        )
        self.device = device
        self.clear()

    @classmethod
    def for_env(cls, env: TorchVecEnv) -> TerrainLevelStats:
        """The stats of ``env``'s batch (its terrain from the spec, shards from the session)."""
        counts = getattr(env.session, "counts", None) or [env.num_envs]
        spec = env.spec
        return cls(env_terrain_types(spec.terrain, spec.terrain_columns, list(counts)), env.device)

    def clear(self) -> None:
        """Start a new rollout's sums."""
        self.type_sum = torch.zeros(len(self.types), dtype=torch.float64, device=self.device)
        self.type_steps = torch.zeros(len(self.types), dtype=torch.float64, device=self.device)
        self.mode_sum = torch.zeros(len(MODES), dtype=torch.float64, device=self.device)
        self.mode_steps = torch.zeros(len(MODES), dtype=torch.float64, device=self.device)
        cells = len(self.types) * len(MODES)
        self.cell_sum = torch.zeros(cells, dtype=torch.float64, device=self.device)
        self.cell_steps = torch.zeros(cells, dtype=torch.float64, device=self.device)
        self.ends = torch.zeros(len(self.types), dtype=torch.float64, device=self.device)
        self.ups = torch.zeros(len(self.types), dtype=torch.float64, device=self.device)
        self.downs = torch.zeros(len(self.types), dtype=torch.float64, device=self.device)

    def add_episode_ends(
        self, level_before: torch.Tensor, level_after: torch.Tensor, dones: torch.Tensor
    ) -> None:
        """Count one step's ended episodes: levels int [N] before and after it, ``dones`` [N].

        An ended env's level after the step is its next episode's (the server resets it within
        the step), so the difference is the curriculum's verdict on the episode.
        """
        ended = dones.to(self.device).bool()
        change = level_after.to(self.device, torch.int64) - level_before.to(
            self.device, torch.int64
        )
        n = len(self.types)
        types = self.type_of_env
        self.ends += torch.bincount(types[ended], minlength=n)
        self.ups += torch.bincount(types[ended & (change > 0)], minlength=n)
        self.downs += torch.bincount(types[ended & (change < 0)], minlength=n)

    def add(self, level: torch.Tensor, mode: torch.Tensor) -> None:
        """Add one step: ``level`` int [N] and ``mode`` u8 [N] (1 biped, 2 quad) of every env."""
        lv = level.to(self.device, torch.float64)
        md = (mode.to(self.device) == BIPED_MODE).to(torch.int64)
        self.type_sum += torch.bincount(self.type_of_env, weights=lv, minlength=len(self.types))
        self.type_steps += torch.bincount(self.type_of_env, minlength=len(self.types))
        self.mode_sum += torch.bincount(md, weights=lv, minlength=len(MODES))
        self.mode_steps += torch.bincount(md, minlength=len(MODES))
        cell = self.type_of_env * len(MODES) + md
        cells = len(self.types) * len(MODES)
        self.cell_sum += torch.bincount(cell, weights=lv, minlength=cells)
        self.cell_steps += torch.bincount(cell, minlength=cells)

    def summary(self) -> dict[str, float]:
        """Mean level per type and per mode, and level moves per type, since the last summary.

        NaN where there was none; then clear.
        """

        def mean(total: torch.Tensor, count: torch.Tensor) -> float:
            return float(total) / float(count) if float(count) > 0 else math.nan

        out = {
            f"terrain_level/{name}": mean(self.type_sum[k], self.type_steps[k])
            for k, name in enumerate(self.types)
        }
        for k, name in enumerate(MODES):
            out[f"terrain_level/{name}"] = mean(self.mode_sum[k], self.mode_steps[k])
        for t, kind in enumerate(self.types):
            for k, name in enumerate(MODES):
                cell = t * len(MODES) + k
                out[f"terrain_level/{kind}/{name}"] = mean(
                    self.cell_sum[cell], self.cell_steps[cell]
                )
        for k, name in enumerate(self.types):
            out[f"promoted/{name}"] = mean(self.ups[k], self.ends[k])
            out[f"demoted/{name}"] = mean(self.downs[k], self.ends[k])
        self.clear()
        return out
