"""Milestones as data: the checks ``ship`` judges a policy by, read from ``milestones.toml``.

A milestone lists the evaluation scenarios it needs and its checks (one metric of one scenario's
report against a bound); ``extends`` takes another milestone's first. Checks in a group count
together: the group passes when at least ``at_least`` of them do (M3: Table VI on 4 of 6
columns). No bound lives in code.
"""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from unigait.assets import milestones_file

Evals = Mapping[str, Mapping[str, float]]

_CHECK_KEYS = {"label", "scenario", "metric", "op", "bound", "group"}
_MILESTONE_KEYS = {"description", "extends", "scenarios", "checks", "groups", "num_envs"}


class MilestoneError(ValueError):
    """A milestones file that does not say what it must (the message names file and key)."""


@dataclass(frozen=True)
class Check:
    """One criterion: ``metric`` of ``scenario``'s report compared with ``bound``."""

    scenario: str
    metric: str
    op: str
    bound: float
    label: str
    group: str | None = None

    def passes(self, value: float | None) -> bool:
        """Whether ``value`` meets the criterion (a missing value does not)."""
        if value is None:
            return False
        return value <= self.bound if self.op == "<=" else value >= self.bound

    def value(self, evals: Evals) -> float | None:
        """The figure this check judges, if the evaluation has it."""
        value = evals.get(self.scenario, {}).get(self.metric)
        return None if value is None else float(value)

    def margin(self, value: float | None) -> float:
        """How far ``value`` clears the bound, relative to it, clipped to [-1, 1] (missing: -1)."""
        if value is None:
            return -1.0
        relative = (value - self.bound) / abs(self.bound) if self.bound else value
        if self.op == "<=":
            relative = -relative
        return max(-1.0, min(1.0, relative))


@dataclass(frozen=True)
class Milestone:
    """A named set of checks and the scenarios they need."""

    name: str
    description: str
    scenarios: tuple[str, ...]
    checks: tuple[Check, ...]
    #: Group name -> how many of its checks must pass.
    groups: Mapping[str, int]
    #: Scenario -> envs it is always evaluated with (the paper's 20 trials for Table VI), whatever
    #: the caller's default.
    num_envs: Mapping[str, int] = dataclasses.field(default_factory=dict)

    def envs_for(self, scenario: str, default: int) -> int:
        """How many envs ``scenario`` is evaluated with."""
        return int(self.num_envs.get(scenario, default))

    def criteria(self) -> int:
        """How many criteria there are: each ungrouped check, and each group as one."""
        return sum(c.group is None for c in self.checks) + len(self.groups)

    def score(self, evals: Evals) -> tuple[int, float]:
        """(criteria met, summed margin of every check): how a selection ranks checkpoints."""
        met, margin = 0, 0.0
        passed_in: dict[str, int] = dict.fromkeys(self.groups, 0)
        for check in self.checks:
            value = check.value(evals)
            margin += check.margin(value)
            if check.group is None:
                met += check.passes(value)
            else:
                passed_in[check.group] += check.passes(value)
        met += sum(passed_in[g] >= need for g, need in self.groups.items())
        return met, margin

    def met(self, evals: Evals) -> bool:
        """Whether every criterion is met."""
        return self.score(evals)[0] == self.criteria()

    def unmet(self, evals: Evals) -> list[str]:
        """The criteria not met, each with its figures (``quad yaw-rate error 0.226 > 0.2``).

        A group that falls short is one entry: how many of its checks pass, how many it needs,
        and each failing check's figure.
        """
        out: list[str] = []
        short: dict[str, list[str]] = {g: [] for g in self.groups}
        for check in self.checks:
            value = check.value(evals)
            if check.passes(value):
                continue
            shown = "missing" if value is None else _figure(value)
            failing = f"{check.label} {shown} (needs {check.op} {_figure(check.bound)})"
            if check.group is None:
                out.append(failing)
            else:
                short[check.group].append(failing)
        for group, need in self.groups.items():
            size = sum(c.group == group for c in self.checks)
            passed = size - len(short[group])
            if passed < need:
                out.append(f"{group}: {passed} of {size}, needs {need}: " + "; ".join(short[group]))
        return out


def _figure(value: float) -> str:
    """``value`` to 3 decimals without trailing zeros (``0.226``, ``1``), as the Rust learner."""
    return f"{value:.3f}".rstrip("0").rstrip(".")


def _check(raw: Any, where: str, groups: Mapping[str, int]) -> Check:
    if not isinstance(raw, dict):
        raise MilestoneError(f"{where}: a check must be a table")
    unknown = set(raw) - _CHECK_KEYS
    if unknown:
        raise MilestoneError(
            f"{where}: unknown key(s) {sorted(unknown)}; known {sorted(_CHECK_KEYS)}"
        )
    missing = {"label", "scenario", "metric", "op", "bound"} - set(raw)
    if missing:
        raise MilestoneError(f"{where}: missing {sorted(missing)}")
    if raw["op"] not in ("<=", ">="):
        raise MilestoneError(f"{where}: op must be '<=' or '>=', got {raw['op']!r}")
    group = raw.get("group")
    if group is not None and group not in groups:
        raise MilestoneError(f"{where}: group {group!r} is not in the milestone's groups")
    return Check(
        raw["scenario"], raw["metric"], raw["op"], float(raw["bound"]), raw["label"], group
    )


def parse_milestones(doc: Mapping[str, Any], source: str = "milestones") -> dict[str, Milestone]:
    """Every milestone of a parsed milestones file (``source`` names it in errors)."""
    out: dict[str, Milestone] = {}

    def build(name: str, seen: tuple[str, ...]) -> Milestone:
        if name in out:
            return out[name]
        if name in seen:
            raise MilestoneError(f"{source}: [{name}] extends itself through {list(seen)}")
        raw = doc.get(name)
        if not isinstance(raw, dict):
            raise MilestoneError(f"{source}: no milestone [{name}]")
        unknown = set(raw) - _MILESTONE_KEYS
        if unknown:
            raise MilestoneError(
                f"{source}: [{name}] has unknown key(s) {sorted(unknown)}; "
                f"known {sorted(_MILESTONE_KEYS)}"
            )
        base = build(raw["extends"], (*seen, name)) if "extends" in raw else None
        groups = {**(base.groups if base else {})}
        groups.update({g: int(v["at_least"]) for g, v in raw.get("groups", {}).items()})
        checks = tuple(
            _check(c, f"{source}: [{name}] check {i + 1}", groups)
            for i, c in enumerate(raw.get("checks", []))
        )
        scenarios = [*(base.scenarios if base else ())]
        scenarios += [s for s in raw.get("scenarios", []) if s not in scenarios]
        for c in checks:
            if c.scenario not in scenarios:
                raise MilestoneError(
                    f"{source}: [{name}] checks scenario {c.scenario!r}, not in its scenarios"
                )
        num_envs = {**(base.num_envs if base else {})}
        num_envs.update({s: int(n) for s, n in raw.get("num_envs", {}).items()})
        milestone = Milestone(
            name,
            str(raw.get("description", "")),
            tuple(scenarios),
            (*(base.checks if base else ()), *checks),
            groups,
            num_envs,
        )
        out[name] = milestone
        return milestone

    for name in doc:
        build(name, ())
    return out


def load_milestones(path: Path | None = None) -> dict[str, Milestone]:
    """The milestones of ``path`` (default: the packaged ``milestones.toml``)."""
    path = path or milestones_file()
    return parse_milestones(tomllib.loads(path.read_text()), str(path))


def milestone(name: str, path: Path | None = None) -> Milestone:
    """Milestone ``name``.

    Raises:
        KeyError: No such milestone (the message lists the known ones).
    """
    known = load_milestones(path)
    if name not in known:
        raise KeyError(f"unknown milestone {name!r}; known: {sorted(known)}")
    return known[name]
