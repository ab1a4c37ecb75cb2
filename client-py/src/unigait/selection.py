"""Which of a run's last checkpoints to ship, judged on a validation seed.

A run's checkpoints 25 iterations apart differ more than one would guess (on ``unified_flat``
the quad velocity error went 0.19 -> 0.14 m/s between iterations 1500 and 1600, 64 envs, seed
1000). Shipping the latest takes whatever it is; choosing by the evaluation seed would report a
figure tuned on its own test. So the choice is made on other seeds (``seeds``) and the shipped
figures come from the evaluation seed, which the choice never saw.

Rank: the validation seeds on which every criterion is met (a recipe's ``confirm_seed`` asks
the same of its checks), then the criteria met summed over the seeds, then the summed relative
margin to the bounds (each clipped to [-1, 1], so one runaway figure does not outvote the
others), then the later checkpoint. More than one seed matters where a milestone rests on few
trials: Table VI's 20 a column make one seed's 20 of 20 a lucky draw about as often as not for
a column at 0.97. The milestone and its bounds come from the milestones file
(:mod:`unigait.milestones`).

Ranked ``by="pass_chance"``, every scenario is evaluated with the selection's envs (Table VI's
columns too, not the milestone's 20 trials), and the candidates are ranked by the estimated
chance of meeting the milestone on one unseen draw of the size it judges
(:mod:`unigait.pass_chance`), then by the summed margin and the later checkpoint: the ranking a
few hundred trials a column can tell apart where 20 cannot.
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from unigait.checkpoints import export_policy, read_checkpoint
from unigait.client import ConnectionOptions
from unigait.config import checkpoint_engine_overrides
from unigait.milestones import Evals, Milestone
from unigait.pass_chance import milestone_chance
from unigait.recipes import START_RANKS

_CHECKPOINT = re.compile(r"model_(\d+)\.(?:pt|ckpt)")


@dataclass(frozen=True)
class SeedScore:
    """How a checkpoint did on one validation seed."""

    seed: int
    met: int
    margin: float


@dataclass(frozen=True)
class Candidate:
    """A checkpoint and how it did on each validation seed."""

    path: Path
    iteration: int
    scores: tuple[SeedScore, ...]
    #: The estimated chance of meeting the milestone on one unseen draw (``by="pass_chance"``).
    chance: float | None = None

    def seeds_met(self, criteria: int) -> int:
        """The seeds on which all ``criteria`` were met."""
        return sum(s.met == criteria for s in self.scores)

    @property
    def met(self) -> int:
        """Criteria met, summed over the seeds."""
        return sum(s.met for s in self.scores)

    @property
    def margin(self) -> float:
        """Relative margins, summed over the seeds."""
        return sum(s.margin for s in self.scores)

    def met_per_seed(self, criteria: int) -> str:
        """Criteria met on each seed, ``8/8 + 7/8``."""
        return " + ".join(f"{s.met}/{criteria}" for s in self.scores)


def recent_checkpoints(run_dir: Path, last: int) -> list[tuple[int, Path]]:
    """The run's ``last`` numbered checkpoints, oldest first.

    ``model_<iteration>.pt``, or ``model_<iteration>.ckpt`` in a Rust learner's run.
    """
    found = [
        (int(m.group(1)), p)
        for p in run_dir.glob("model_*")
        if (m := _CHECKPOINT.fullmatch(p.name))
    ]
    return sorted(found)[-last:] if last > 0 else []


def select_checkpoint(
    run_dir: Path,
    milestone: Milestone,
    address: str,
    last: int,
    seeds: Sequence[int],
    num_envs: int,
    connection: ConnectionOptions | None = None,
    by: str = "criteria",
    judged_envs: int = 64,
) -> list[Candidate]:
    """Evaluate the run's ``last`` checkpoints on each of ``seeds``; the candidates, best first.

    ``by`` is ``"criteria"`` (each scenario at the milestone's own size, ranked by :func:`rank`)
    or ``"pass_chance"`` (each scenario at ``num_envs``, ranked by :func:`rank_by_chance` for a
    draw the size ``ship`` judges with ``judged_envs``).
    """
    from unigait.client import Client

    if not seeds:
        raise ValueError("selection needs at least one validation seed")
    if by not in RANKINGS:
        raise ValueError(f"unknown ranking {by!r}; known: {sorted(RANKINGS)}")
    by_chance = by == "pass_chance"
    draw = {s: milestone.envs_for(s, judged_envs) for s in milestone.scenarios}
    checkpoints = recent_checkpoints(run_dir, last)
    if not checkpoints:
        raise FileNotFoundError(f"no model_<iteration>.pt (or .ckpt) in {run_dir}")
    candidates = []
    with tempfile.TemporaryDirectory() as tmp, Client(address, **(connection or {})) as client:
        onnx_path = Path(tmp) / "policy.onnx"
        for iteration, path in checkpoints:
            export_policy(path, onnx_path)
            onnx = onnx_path.read_bytes()
            engine = checkpoint_engine_overrides(read_checkpoint(path))
            scores = []
            per_seed: list[Evals] = []
            for seed in seeds:
                evals = {
                    s: client.evaluate(
                        onnx,
                        s,
                        num_envs=num_envs if by_chance else milestone.envs_for(s, num_envs),
                        seed=seed,
                        task_overrides_toml=engine,
                    ).metrics
                    for s in milestone.scenarios
                }
                per_seed.append(evals)
                scores.append(SeedScore(seed, *milestone.score(evals)))
            chance = milestone_chance(milestone, per_seed, draw) if by_chance else None
            candidates.append(Candidate(path, iteration, tuple(scores), chance))
    if by_chance:
        return rank_by_chance(candidates)
    return rank(candidates, milestone.criteria())


def rank(candidates: Sequence[Candidate], criteria: int) -> list[Candidate]:
    """Best first: seeds fully met, criteria met, summed margin, the later checkpoint."""
    return sorted(
        candidates,
        key=lambda c: (c.seeds_met(criteria), c.met, c.margin, c.iteration),
        reverse=True,
    )


def rank_by_chance(candidates: Sequence[Candidate]) -> list[Candidate]:
    """Best first: the pass chance, the summed margin, the later checkpoint."""
    return sorted(candidates, key=lambda c: (c.chance or 0.0, c.margin, c.iteration), reverse=True)


#: The rankings ``select_checkpoint`` knows (``ship --select-by``, a recipe's ``start_rank``).
RANKINGS = START_RANKS


def describe(candidates: Sequence[Candidate], milestone: Milestone, num_envs: int) -> str:
    """The model card's paragraph on how the checkpoint was chosen."""
    chosen = candidates[0]
    seeds = [s.seed for s in chosen.scores]
    per_seed = " + ".join(str(s) for s in seeds)
    on = f"validation seed {seeds[0]}" if len(seeds) == 1 else f"validation seeds {per_seed}"
    if chosen.chance is not None:
        return _describe_chances(candidates, milestone, num_envs, on)
    scores = ", ".join(
        f"{c.iteration}: {c.met_per_seed(milestone.criteria())} ({c.margin:+.2f})"
        for c in sorted(candidates, key=lambda c: c.iteration)
    )
    return (
        f"Chosen among the run's last {len(candidates)} checkpoints on {on} "
        f"({num_envs} envs per scenario): "
        f"{milestone.name} criteria met (summed relative margin) by iteration: {scores}. Iteration "
        f"{chosen.iteration} ranked first; the figures above come from the evaluation seed, "
        "which the choice never saw."
    )


def _describe_chances(
    candidates: Sequence[Candidate], milestone: Milestone, num_envs: int, on: str
) -> str:
    chances = ", ".join(
        f"{c.iteration}: {c.chance or 0.0:.2f}"
        for c in sorted(candidates, key=lambda c: c.iteration)
    )
    chosen = candidates[0]
    return (
        f"Chosen among the run's last {len(candidates)} checkpoints by the estimated chance of "
        f"meeting {milestone.name} on one unseen draw of the size it judges, from {num_envs} envs "
        f"per scenario on {on} (`unigait.pass_chance`): by iteration, "
        f"{chances}. Iteration {chosen.iteration} ranked first; the figures above come from the "
        "evaluation seed, which the choice never saw."
    )
