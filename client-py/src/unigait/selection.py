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
from unigait.milestones import Milestone

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
) -> list[Candidate]:
    """Evaluate the run's ``last`` checkpoints on each of ``seeds``; the candidates, best first."""
    from unigait.client import Client

    if not seeds:
        raise ValueError("selection needs at least one validation seed")
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
            for seed in seeds:
                evals = {
                    s: client.evaluate(
                        onnx,
                        s,
                        num_envs=milestone.envs_for(s, num_envs),
                        seed=seed,
                        task_overrides_toml=engine,
                    ).metrics
                    for s in milestone.scenarios
                }
                scores.append(SeedScore(seed, *milestone.score(evals)))
            candidates.append(Candidate(path, iteration, tuple(scores)))
    return rank(candidates, milestone.criteria())


def rank(candidates: Sequence[Candidate], criteria: int) -> list[Candidate]:
    """Best first: seeds fully met, criteria met, summed margin, the later checkpoint."""
    return sorted(
        candidates,
        key=lambda c: (c.seeds_met(criteria), c.met, c.margin, c.iteration),
        reverse=True,
    )


def describe(candidates: Sequence[Candidate], milestone: Milestone, num_envs: int) -> str:
    """The model card's paragraph on how the checkpoint was chosen."""
    chosen = candidates[0]
    seeds = [s.seed for s in chosen.scores]
    per_seed = " + ".join(str(s) for s in seeds)
    scores = ", ".join(
        f"{c.iteration}: {c.met_per_seed(milestone.criteria())} ({c.margin:+.2f})"
        for c in sorted(candidates, key=lambda c: c.iteration)
    )
    on = f"validation seed {seeds[0]}" if len(seeds) == 1 else f"validation seeds {per_seed}"
    return (
        f"Chosen among the run's last {len(candidates)} checkpoints on {on} "
        f"({num_envs} envs per scenario): "
        f"{milestone.name} criteria met (summed relative margin) by iteration: {scores}. Iteration "
        f"{chosen.iteration} ranked first; the figures above come from the evaluation seed, "
        "which the choice never saw."
    )
