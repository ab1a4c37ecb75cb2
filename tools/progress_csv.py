"""Reading a learner's ``progress.csv`` for the plotting tools (either learner writes it)."""

from __future__ import annotations

import csv
from pathlib import Path


def rows(folder: Path) -> list[dict[str, str]]:
    """Every row of ``folder/progress.csv``."""
    with (folder / "progress.csv").open() as f:
        return list(csv.DictReader(f))


def series(
    table: list[dict[str, str]], key: str, x: str = "total_env_steps"
) -> tuple[list[float], list[float]]:
    """Column ``key`` against column ``x``, rows with an empty ``key`` (NaN) left out."""
    xs, ys = [], []
    for r in table:
        if r.get(key):
            xs.append(float(r[x]))
            ys.append(float(r[key]))
    return xs, ys


def smooth(ys: list[float], window: int) -> list[float]:
    """The running mean of the last ``window`` values (fewer at the start)."""
    out, total = [], 0.0
    for i, y in enumerate(ys):
        total += y - (ys[i - window] if i >= window else 0.0)
        out.append(total / min(i + 1, window))
    return out
