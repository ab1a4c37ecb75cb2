"""Plain MLP builder."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

from torch import nn

_ACTIVATIONS: dict[str, type[nn.Module]] = {
    "elu": nn.ELU,
    "relu": nn.ReLU,
    "tanh": nn.Tanh,
    "selu": nn.SELU,
}


def mlp(
    in_dim: int, hidden_dims: Sequence[int], out_dim: int, activation: str = "elu"
) -> nn.Sequential:
    """An MLP ``in_dim -> hidden_dims... -> out_dim`` with ``activation`` between layers.

    Args:
        in_dim: Input size.
        hidden_dims: Hidden layer sizes, e.g. ``(512, 256, 128)``.
        out_dim: Output size (no activation after the last layer).
        activation: ``"elu"``, ``"relu"``, ``"tanh"`` or ``"selu"``.
    """
    try:
        act = _ACTIVATIONS[activation.lower()]
    except KeyError:
        raise ValueError(
            f"unknown activation {activation!r}; known: {sorted(_ACTIVATIONS)}"
        ) from None
    layers: list[nn.Module] = []
    dims = [in_dim, *hidden_dims]
    for a, b in itertools.pairwise(dims):
        layers += [nn.Linear(a, b), act()]
    layers.append(nn.Linear(dims[-1], out_dim))
    return nn.Sequential(*layers)
