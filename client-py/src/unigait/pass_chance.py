"""How likely a policy is to meet a milestone on a draw it has not seen, from larger draws.

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

import math
from collections.abc import Mapping, Sequence

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
