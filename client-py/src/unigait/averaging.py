"""A run's checkpoints averaged: the element-wise mean of their networks' weights.

Under PPO's adaptive learning rate the terrain run's checkpoints 25-100 iterations apart swing
on Table VI's columns far more than the trials' noise, and the mean of a stretch of them lands
on or above its best one (docs/src/decisions/0044-checkpoint-averaging.md). The averaged
checkpoint is a ``model_*.pt`` like any other: it exports, ships and resumes.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: The checkpoint's networks that are averaged; everything else is the last checkpoint's.
NETWORKS = ("actor_critic", "estimator")


class AveragingError(ValueError):
    """Checkpoints that cannot be averaged, with the file named."""


def _check_networks(path: Path, checkpoint: Any) -> None:
    if not isinstance(checkpoint, dict) or any(
        not isinstance(checkpoint.get(k), dict) for k in NETWORKS
    ):
        raise AveragingError(
            f"{path}: not a Python learner's checkpoint (no {', '.join(NETWORKS)})"
        )


def average_checkpoints(paths: Sequence[Path]) -> dict[str, Any]:
    """The last of ``paths`` with each network's floating-point tensors replaced by their mean.

    Integer tensors (counters) must agree and are kept. The result records the iterations it
    averages in ``averaged_from``.

    Raises:
        AveragingError: no paths, a ``.ckpt`` (the Rust learner's, whose networks this package
            does not load), an unreadable file, or networks that differ in their tensors' names
            or shapes.
    """
    import torch

    if not paths:
        raise AveragingError("nothing to average: give at least one checkpoint")
    for path in paths:
        if path.suffix != ".pt":
            raise AveragingError(f"{path}: only the Python learner's model_*.pt can be averaged")
    loaded: list[dict[str, Any]] = []
    for path in paths:
        try:
            checkpoint = torch.load(path, map_location="cpu", weights_only=False)
        except (OSError, RuntimeError, EOFError) as err:
            raise AveragingError(f"{path}: cannot be read ({err})") from err
        _check_networks(path, checkpoint)
        loaded.append(checkpoint)
    out = dict(loaded[-1])
    for key in NETWORKS:
        last_networks = loaded[-1][key]
        for path, checkpoint in zip(paths, loaded, strict=True):
            if set(checkpoint[key]) != set(last_networks):
                raise AveragingError(f"{path}: {key} holds other tensors than the last checkpoint")
        averaged: dict[str, Any] = {}
        for name, last in last_networks.items():
            tensors = [checkpoint[key][name] for checkpoint in loaded]
            for path, tensor in zip(paths, tensors, strict=True):
                if tensor.shape != last.shape:
                    raise AveragingError(
                        f"{path}: {key}.{name} has shape {tuple(tensor.shape)}, the last "
                        f"checkpoint's {tuple(last.shape)}: not the same networks"
                    )
            if last.is_floating_point():
                averaged[name] = torch.stack(tensors).mean(dim=0)
            elif any(not torch.equal(t, last) for t in tensors):
                raise AveragingError(f"{key}.{name}: an integer tensor the checkpoints disagree on")
            else:
                averaged[name] = last
        out[key] = averaged
    out["averaged_from"] = [int(c.get("iteration", 0)) for c in loaded]
    return out


def write_average(paths: Sequence[Path], out: Path) -> dict[str, Any]:
    """Average ``paths`` into ``out`` (a ``.pt``); returns the averaged checkpoint."""
    import torch

    averaged = average_checkpoints(paths)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(averaged, out)
    return averaged


def common_step(iterations: Sequence[int]) -> int | None:
    """The one distance between successive sorted ``iterations``, if there is one."""
    steps = {b - a for a, b in itertools.pairwise(sorted(iterations))}
    return steps.pop() if len(steps) == 1 else None


def describe_average(iterations: Sequence[int]) -> str:
    """One sentence for a model card: which iterations were averaged."""
    spans = sorted(iterations)
    step = common_step(spans)
    every = f", every {step}" if step else ""
    return (
        f"The weights are the mean of {len(spans)} checkpoints' (iterations {spans[0]}-"
        f"{spans[-1]}{every}; decision record 0044), not one checkpoint's."
    )
