"""A traversal report's trials as a table: where each one ended, and how.

``evaluate --report R.json`` keeps every traversal trial: its case, how it ended, how far it got
along its course, where it stood across the course and which way it faced at the end, when it
ended and the friction of its contacts. ``python -m unigait trials R.json`` lays them out as one
Markdown table per scenario (a ``table_vi`` report holds one per column), the trials that did not
cross by default, every trial with ``--all``; ``--by-friction`` counts each case's crossings by
the friction of its contacts instead. A trial's number is the one ``evaluate
--record-env`` takes with the report's own scenario, seed and trials: its place in the report's
list, across the cases and, in a ``table_vi`` report, across the columns.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any


class TrialTableError(ValueError):
    """A report that cannot be read or holds no traversal (the message names the file)."""


@dataclass(frozen=True)
class Trial:
    """One traversal trial of a report."""

    scenario: str
    number: int
    outcome: dict[str, Any]


COLUMNS = (
    ("trial", "trial"),
    ("case", "case"),
    ("end", "end"),
    ("progress_m", "progress (m)"),
    ("lateral_m", "across (m)"),
    ("heading_off_deg", "heading off (deg)"),
    ("time_s", "time (s)"),
    ("contact_friction", "friction"),
)


def read_trials(path: Path) -> list[Trial]:
    """Every traversal trial of the report at ``path``, scenario by scenario, in report order.

    Raises:
        TrialTableError: the file is missing, is not JSON, or holds no traversal trials.
    """
    try:
        report = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise TrialTableError(f"{path}: {err}") from err
    if not isinstance(report, dict):
        raise TrialTableError(f"{path}: not an evaluation report")
    parts = report.get("parts") or [report]
    outcomes = [
        (str(part.get("scenario", "?")), outcome)
        for part in parts
        if isinstance(part, dict) and isinstance(part.get("traversal"), dict)
        for outcome in part["traversal"].get("outcomes", [])
    ]
    trials = [Trial(scenario, k, outcome) for k, (scenario, outcome) in enumerate(outcomes)]
    if not trials:
        raise TrialTableError(f"{path}: no traversal trials (a tracking or transition report?)")
    return trials


def _cell(outcome: dict[str, Any], key: str, number: int) -> str:
    if key == "trial":
        return str(number)
    if key == "heading_off_deg":
        value = outcome.get("heading_off_rad")
        return "-" if value is None else f"{math.degrees(value):.0f}"
    value = outcome.get(key)
    if value is None:
        # Reports written before a field existed (lateral_m, heading_off_rad) lack it.
        return "-"
    return f"{value:.2f}" if isinstance(value, float) else str(value)


def trial_tables(trials: list[Trial], everything: bool = False) -> str:
    """One Markdown table per scenario: the trials that did not cross, or all of them."""
    out: list[str] = []
    for scenario in dict.fromkeys(t.scenario for t in trials):
        mine = [t for t in trials if t.scenario == scenario]
        shown = [t for t in mine if everything or t.outcome.get("end") != "crossed"]
        crossed = sum(t.outcome.get("end") == "crossed" for t in mine)
        out.append(f"### {scenario}: {crossed} of {len(mine)} crossed\n\n")
        if not shown:
            out.append("every trial crossed\n\n")
            continue
        out.append("| " + " | ".join(label for _, label in COLUMNS) + " |\n")
        out.append("|" + " --- |" * len(COLUMNS) + "\n")
        for t in shown:
            cells = [_cell(t.outcome, key, t.number) for key, _ in COLUMNS]
            out.append("| " + " | ".join(cells) + " |\n")
        out.append("\n")
    return "".join(out)


# Contact-friction bins of ``--by-friction``. A 30 deg slope holds a standing robot only above
# tan 30 deg = 0.58, and Table V's friction averaged with the ground's starts at 0.6 (decision
# record 0034): the lowest bins are where a climb has almost no grip to spare.
FRICTION_EDGES = (0.65, 0.7, 0.8, 0.9, 1.0)


def _friction_labels() -> list[str]:
    edges = FRICTION_EDGES
    middle = [f"{lo:.2f}-{hi:.2f}" for lo, hi in itertools.pairwise(edges)]
    return [f"< {edges[0]:.2f}", *middle, f">= {edges[-1]:.2f}"]


def _friction_bin(friction: float) -> int:
    return sum(friction >= edge for edge in FRICTION_EDGES)


def friction_tables(trials: list[Trial]) -> str:
    """One Markdown table per scenario: each case's trials crossed / run, by contact friction."""
    labels = _friction_labels()
    out: list[str] = []
    for scenario in dict.fromkeys(t.scenario for t in trials):
        mine = [t for t in trials if t.scenario == scenario]
        out.append(f"### {scenario}: crossed / trials by contact friction\n\n")
        out.append("| case | " + " | ".join(labels) + " |\n")
        out.append("|" + " --- |" * (len(labels) + 1) + "\n")
        for case in dict.fromkeys(str(t.outcome.get("case", "?")) for t in mine):
            ran = [0] * len(labels)
            crossed = [0] * len(labels)
            for t in mine:
                friction = t.outcome.get("contact_friction")
                if str(t.outcome.get("case", "?")) != case or friction is None:
                    continue
                k = _friction_bin(float(friction))
                ran[k] += 1
                crossed[k] += t.outcome.get("end") == "crossed"
            cells = [f"{c}/{n}" if n else "-" for c, n in zip(crossed, ran, strict=True)]
            out.append(f"| {case} | " + " | ".join(cells) + " |\n")
        out.append("\n")
    return "".join(out)
