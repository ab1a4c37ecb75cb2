"""How likely a policy is to meet a milestone on a draw it has not seen, from larger draws.

Why: docs/src/decisions/0043-rank-checkpoints-by-pass-chance.md.

A milestone judges a few trials: Table VI's columns are 20 trials each, and a policy that
crosses 97% of the time makes 20 of 20 in about half its draws. Which of two checkpoints meets
the milestone more often is then a question 20 trials answer badly and a few hundred answer
well. This module estimates, from evaluations with many trials on one or more seeds, the chance
that one fresh draw of the milestone's own size meets it:

- a check on a success rate (a metric named ``success_rate``, its trial count beside it as
  ``trials``): the successes pooled over the seeds, a Jeffreys prior on the rate
  (Beta(1/2, 1/2)), and the chance that ``n`` new trials meet the bound (the beta-binomial
  predictive), where ``n`` is the draw the milestone judges;
- any other check (a mean over many envs, whose spread between seeds is small): the share of
  the seeds on which it was met;
- a group (Table VI's 4 of 6): the chance that at least ``at_least`` of its checks are met,
  treating them as independent;
- the milestone: the product over its criteria.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from unigait.milestones import Check, Evals, Milestone


def trials_metric(metric: str) -> str | None:
    """The trial count's metric beside a success rate (``a/success_rate`` -> ``a/trials``)."""
    head, _, last = metric.rpartition("/")
    if not last.endswith("success_rate"):
        return None
    return f"{head}/trials" if head else "trials"


def _log_beta(a: float, b: float) -> float:
    return math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)


def draw_chance(check: Check, successes: float, trials: float, n: int) -> float:
    """The chance that ``n`` new trials meet ``check``, having seen ``successes`` of ``trials``.

    The rate's posterior is Beta(successes + 1/2, failures + 1/2); the count a new draw makes
    is then beta-binomial, summed over the counts whose rate ``check`` accepts.
    """
    a = successes + 0.5
    b = trials - successes + 0.5
    total = 0.0
    for x in range(n + 1):
        if check.passes(x / n):
            log_pmf = (
                math.lgamma(n + 1)
                - math.lgamma(x + 1)
                - math.lgamma(n - x + 1)
                + _log_beta(x + a, n - x + b)
                - _log_beta(a, b)
            )
            total += math.exp(log_pmf)
    return min(1.0, total)


def check_chance(check: Check, evals_per_seed: Sequence[Evals], n: int) -> float:
    """The chance that one draw of ``n`` trials meets ``check``, judged on every seed's evals."""
    counts = trials_metric(check.metric)
    pooled_successes = pooled_trials = 0.0
    if counts is not None:
        for evals in evals_per_seed:
            rate = check.value(evals)
            trials = evals.get(check.scenario, {}).get(counts)
            if rate is None or trials is None:
                counts = None
                break
            pooled_successes += round(rate * float(trials))
            pooled_trials += float(trials)
    if counts is not None and pooled_trials > 0:
        return draw_chance(check, pooled_successes, pooled_trials, n)
    met = [check.passes(check.value(evals)) for evals in evals_per_seed]
    return sum(met) / len(met) if met else 0.0


def at_least(chances: Sequence[float], k: int) -> float:
    """The chance that at least ``k`` of independent events with ``chances`` happen."""
    exactly = [1.0]  # exactly[j]: the chance that j of the events so far happened
    for p in chances:
        exactly = [
            (exactly[j] if j < len(exactly) else 0.0) * (1 - p)
            + (exactly[j - 1] * p if j > 0 else 0.0)
            for j in range(len(exactly) + 1)
        ]
    return sum(exactly[k:])


def milestone_chance(
    milestone: Milestone, evals_per_seed: Sequence[Evals], draw: Mapping[str, int]
) -> float:
    """The chance that one draw meets ``milestone``: ``draw`` maps each scenario to its size.

    Raises:
        ValueError: no seeds' evaluations.
    """
    if not evals_per_seed:
        raise ValueError("the pass chance needs at least one seed's evaluations")
    chance = 1.0
    in_group: dict[str, list[float]] = {g: [] for g in milestone.groups}
    for check in milestone.checks:
        p = check_chance(check, evals_per_seed, draw[check.scenario])
        if check.group is None:
            chance *= p
        else:
            in_group[check.group].append(p)
    for group, need in milestone.groups.items():
        chance *= at_least(in_group[group], need)
    return chance


class ReportError(ValueError):
    """Reports that cannot be judged together (the message names the file and what is wrong)."""


def evals_by_seed(reports: Sequence[Path]) -> dict[int, dict[str, dict[str, float]]]:
    """Each seed's evaluations from ``evaluate --report`` files: seed -> scenario -> metrics."""
    out: dict[int, dict[str, dict[str, float]]] = {}
    for path in reports:
        try:
            report = json.loads(path.read_text())
            seed, scenario = int(report["seed"]), str(report["scenario"])
            metrics = {str(k): float(v) for k, v in report["metrics"].items()}
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise ReportError(f"{path}: not an evaluation report ({err})") from err
        if scenario in out.setdefault(seed, {}):
            raise ReportError(f"{path}: a second {scenario} report for seed {seed}")
        out[seed][scenario] = metrics
    return out


def chance_table(
    milestone: Milestone, by_seed: Mapping[int, Evals], draw: Mapping[str, int]
) -> str:
    """Each check's and the milestone's pass chance, as a Markdown table.

    Raises:
        ReportError: a seed lacks one of the milestone's scenarios.
    """
    for seed, evals in by_seed.items():
        missing = [s for s in milestone.scenarios if s not in evals]
        if missing:
            raise ReportError(f"seed {seed} has no report of {', '.join(missing)}")
    per_seed = list(by_seed.values())
    lines = [
        f"{milestone.name} on one unseen draw, from seeds {', '.join(map(str, by_seed))}",
        "",
        "| check | seen | draw | chance |",
        "| --- | --- | --- | --- |",
    ]
    for check in milestone.checks:
        n = draw[check.scenario]
        counts = trials_metric(check.metric)
        seen = ", ".join(
            "missing" if (v := check.value(e)) is None else f"{v:.3g}" for e in per_seed
        )
        if counts is not None:
            trials = sum(e.get(check.scenario, {}).get(counts, 0.0) for e in per_seed)
            seen += f" ({trials:.0f} trials)"
        label = check.label + (f" [{check.group}]" if check.group else "")
        p = check_chance(check, per_seed, n)
        lines.append(f"| {label} {check.op} {check.bound:g} | {seen} | {n} | {p:.3f} |")
    chance = milestone_chance(milestone, per_seed, draw)
    lines += ["", f"chance of meeting {milestone.name}: {chance:.3f}"]
    return "\n".join(lines) + "\n"
