"""Both sides of the physics cross-checks, and their figures side by side.

Ours: the example binary of the sim crate (``cargo build --release -p unigait-sim --examples``,
then ``target/release/examples/crosscheck``), which prints one JSON document. Theirs:
:mod:`unigait.mujoco.scenarios`. :func:`figures` pairs the scalar figures of every scenario;
the tolerances live in ``tests/test_mujoco_crosscheck.py``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from unigait.mujoco.model import PhysicsOptions
from unigait.mujoco.scenarios import SCENARIOS, run


def find_crosscheck_binary(search_from: Sequence[Path] | None = None) -> Path:
    """``$UNIGAIT_CROSSCHECK_BIN`` or ``target/release/examples/crosscheck`` of the repository.

    The binary is a repository tool: the checkout is found above ``search_from`` (default: this
    module, for an editable install, then the working directory, for an installed package run
    from a checkout). The path is returned whether or not the file exists.

    Raises:
        FileNotFoundError: Not in a checkout (no ``Cargo.toml`` beside ``server/`` above any start).
    """
    env = os.environ.get("UNIGAIT_CROSSCHECK_BIN")
    if env:
        return Path(env)
    starts = search_from if search_from is not None else (Path(__file__), Path.cwd())
    for start in starts:
        for parent in (start.resolve(), *start.resolve().parents):
            if (parent / "Cargo.toml").is_file() and (parent / "server").is_dir():
                return parent / "target" / "release" / "examples" / "crosscheck"
    raise FileNotFoundError(
        "the crosscheck binary is built in a unigait checkout (`cargo build --release -p "
        "unigait-sim --examples`), and none was found above "
        f"{', '.join(str(s) for s in starts)}; run from one or set UNIGAIT_CROSSCHECK_BIN"
    )


def run_ours(
    binary: Path, names: list[str] | None = None, armature: float | None = None
) -> dict[str, Any]:
    """Run the example binary (the named scenarios, or all) and parse its JSON.

    Args:
        binary: The example binary.
        names: Scenario names; None = all.
        armature: Override the nominal joint armature (kg m^2), to find a difference's cause.
    """
    extra = [] if armature is None else ["--armature", str(armature)]
    out = subprocess.run(
        [str(binary), *extra, *(names or [])],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    return json.loads(out.stdout)


@dataclass(frozen=True)
class Figure:
    """One scalar measured by both engines."""

    scenario: str
    quantity: str
    ours: float
    mujoco: float

    @property
    def ratio(self) -> float:
        """ours / MuJoCo (nan when MuJoCo's is 0)."""
        return self.ours / self.mujoco if self.mujoco != 0.0 else math.nan


def _scalars(result: dict[str, Any], prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for key, value in result.items():
        if key == "params":
            continue
        name = f"{prefix}{key}"
        if isinstance(value, bool):
            continue
        if isinstance(value, int | float):
            out[name] = float(value)
        elif (
            isinstance(value, list)
            and 0 < len(value) <= 4
            and all(isinstance(v, int | float) for v in value)
        ):
            for i, v in enumerate(value):
                out[f"{name}[{i}]"] = float(v)
    return out


def figures(ours: dict[str, Any], theirs: dict[str, Any]) -> list[Figure]:
    """Every scalar (and short vector entry) both sides report, scenario by scenario."""
    rows: list[Figure] = []
    for scenario, result in theirs.items():
        if scenario not in ours:
            continue
        a, b = _scalars(ours[scenario]), _scalars(result)
        rows.extend(Figure(scenario, k, a[k], b[k]) for k in b if k in a)
    return rows


def format_table(rows: list[Figure]) -> str:
    """A Markdown table: scenario, quantity, ours, MuJoCo, ratio."""
    lines = ["| scenario | quantity | ours | MuJoCo | ratio |", "| --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(
            f"| {r.scenario} | {r.quantity} | {r.ours:.4g} | {r.mujoco:.4g} | {r.ratio:.3f} |"
        )
    return "\n".join(lines)


def compare(
    binary: Path | None = None,
    names: list[str] | None = None,
    armature: float | None = None,
) -> list[Figure]:
    """Run the named physics scenarios (all by default) in both engines and pair the figures.

    Args:
        binary: Our example binary; None = :func:`find_crosscheck_binary`.
        names: Scenario names; None = all.
        armature: Joint armature for both engines (kg m^2); None = the nominal 0.02.
    """
    names = names or list(SCENARIOS)
    ours = run_ours(binary or find_crosscheck_binary(), names, armature)
    options = PhysicsOptions() if armature is None else PhysicsOptions(armature=armature)
    return figures(ours, run(names, options))
