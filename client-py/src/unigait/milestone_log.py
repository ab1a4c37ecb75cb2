"""A recipe run's milestone checks as tables: every ``validation.jsonl`` row, check by check.

A stage that stops on a milestone appends one record per check to its ``validation.jsonl``
(iteration, milestone, every scenario's metrics). This reads them back for a whole run, or one
stage, and lays them out one table per milestone: a row per check, a column per criterion of
the milestone (``milestones.toml``'s labels), passing figures in bold, as ``python -m unigait
checks LOG_DIR`` prints them. The figures are the recorded ones; what passes is judged by the
milestones file of today, so a bound changed since shows in the table.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from unigait.milestones import Milestone, milestone

VALIDATION_FILE = "validation.jsonl"


class MilestoneLogError(ValueError):
    """A folder without checks, or a record that cannot be read (the message names the file)."""


@dataclass(frozen=True)
class LoggedCheck:
    """One milestone check of one stage."""

    stage: str
    record: dict[str, Any]


def validation_files(log_dir: Path) -> list[Path]:
    """A stage folder's ``validation.jsonl``, or every stage's of a run folder, in stage order.

    Raises:
        MilestoneLogError: ``log_dir`` holds none.
    """
    own = log_dir / VALIDATION_FILE
    files = [own] if own.is_file() else sorted(log_dir.glob(f"*/{VALIDATION_FILE}"))
    if not files:
        raise MilestoneLogError(
            f"{log_dir}: no {VALIDATION_FILE} here or in its stage folders (a stage writes one "
            "when its stop rule names a milestone)"
        )
    return files


def read_milestone_log(log_dir: Path) -> list[LoggedCheck]:
    """Every check recorded under ``log_dir``, stage by stage, in the order they ran.

    Raises:
        MilestoneLogError: No checks, or a line that is not a check record.
    """
    out: list[LoggedCheck] = []
    for path in validation_files(log_dir):
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError as err:
                raise MilestoneLogError(f"{path}:{number}: not JSON ({err.msg})") from None
            if not isinstance(record, dict) or not {"iteration", "milestone", "evals"} <= set(
                record
            ):
                raise MilestoneLogError(
                    f"{path}:{number}: not a check record (needs iteration, milestone, evals)"
                )
            out.append(LoggedCheck(stage=path.parent.name, record=record))
    return out


def _cell(target: Milestone, index: int, evals: dict[str, Any]) -> str:
    check = target.checks[index]
    value = check.value(evals)
    if value is None:
        return "-"
    shown = f"{value:.3f}".rstrip("0").rstrip(".")
    return f"**{shown}**" if check.passes(value) else shown


def milestone_tables(checks: list[LoggedCheck]) -> str:
    """One Markdown table per milestone, in the order the milestones first appear.

    Raises:
        MilestoneLogError: A record names a milestone the milestones file does not have.
    """
    by_name: dict[str, list[LoggedCheck]] = {}
    for entry in checks:
        by_name.setdefault(str(entry.record["milestone"]), []).append(entry)
    tables: list[str] = []
    for name, entries in by_name.items():
        try:
            target = milestone(name)
        except KeyError as err:
            raise MilestoneLogError(f"{entries[0].stage}: {err.args[0]}") from None
        labels = [c.label for c in target.checks]
        lines = [
            f"{name}: {target.description}",
            "",
            "| iteration | stage | seed | met | " + " | ".join(labels) + " |",
            "| --- " * (4 + len(labels)) + "|",
        ]
        for entry in entries:
            r = entry.record
            met, criteria = target.score(r["evals"])[0], target.criteria()
            cells = [
                str(r["iteration"]),
                entry.stage,
                str(r.get("seed", "-")),
                f"{met} of {criteria}",
                *(_cell(target, i, r["evals"]) for i in range(len(labels))),
            ]
            lines.append("| " + " | ".join(cells) + " |")
        tables.append("\n".join(lines))
    return "\n\n".join(tables) + "\n"
