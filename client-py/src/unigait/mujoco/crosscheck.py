"""Both sides of the physics cross-checks, and their figures side by side.

Ours: the ``unigait-crosscheck`` binary (a repository tool: ``cargo build --release -p
unigait-crosscheck`` builds ``target/release/unigait-crosscheck``), which prints one JSON
document; :func:`find_crosscheck_binary` says where it is looked for. Theirs:
:mod:`unigait.mujoco.scenarios`. :func:`figures` pairs the scalar figures of every scenario;
the tolerances live in ``tests/test_mujoco_crosscheck.py``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from unigait.mujoco.model import PhysicsOptions
from unigait.mujoco.scenarios import SCENARIOS, run

#: The cross-check driver's executable name (the ``unigait-crosscheck`` crate's binary).
CROSSCHECK_BINARY = "unigait-crosscheck"


def find_crosscheck_binary() -> Path:
    """The cross-check driver: ``$UNIGAIT_CROSSCHECK_BIN``, else ``unigait-crosscheck`` on PATH.

    Nothing is guessed from where this package or the working directory is: an installed
    package has no checkout to look in.

    Raises:
        FileNotFoundError: Neither is set or found.
    """
    env = os.environ.get("UNIGAIT_CROSSCHECK_BIN")
    if env:
        return Path(env)
    found = shutil.which(CROSSCHECK_BINARY)
    if found:
        return Path(found)
    raise FileNotFoundError(
        f"the cross-check driver `{CROSSCHECK_BINARY}` is not on PATH: build it in a unigait "
        f"checkout (`cargo build --release -p {CROSSCHECK_BINARY}`), then put target/release "
        "on PATH or set UNIGAIT_CROSSCHECK_BIN to the binary"
    )


def run_ours(
    binary: Path,
    names: list[str] | None = None,
    armature: float | None = None,
    engine: str | None = None,
) -> dict[str, Any]:
    """Run the cross-check driver (the named scenarios, or all) and parse its JSON.

    Args:
        binary: The driver (see :func:`find_crosscheck_binary`).
        names: Scenario names; None = all.
        armature: Override the nominal joint armature (kg m^2), to find a difference's cause.
        engine: ``"rapier"`` or ``"articulated"`` (``physics.engine``); None = the default.
    """
    extra = [] if armature is None else ["--armature", str(armature)]
    if engine is not None:
        extra += ["--engine", engine]
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
        binary: The cross-check driver; None = :func:`find_crosscheck_binary`.
        names: Scenario names; None = all.
        armature: Joint armature for both engines (kg m^2); None = the nominal 0.02.
    """
    names = names or list(SCENARIOS)
    ours = run_ours(binary or find_crosscheck_binary(), names, armature)
    options = PhysicsOptions() if armature is None else PhysicsOptions(armature=armature)
    return figures(ours, run(names, options))
