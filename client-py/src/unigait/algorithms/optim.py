"""The optimiser both learners use."""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import nn


def adam(params: Iterable[nn.Parameter], lr: float) -> torch.optim.Adam:
    """Adam with the fused kernel (one pass over all parameters per step) where torch has it.

    Args:
        params: The parameters to optimise.
        lr: Learning rate.
    """
    params = list(params)
    try:
        return torch.optim.Adam(params, lr=lr, fused=True)
    except (RuntimeError, TypeError):
        return torch.optim.Adam(params, lr=lr)
