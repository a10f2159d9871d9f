"""The one MLP builder of the package: TOLD's networks (eq. 9) and the learned shielding rules' heads."""

from __future__ import annotations

from collections.abc import Sequence

from torch import nn


def mlp(
    in_dim: int,
    hidden: Sequence[int],
    out_dim: int,
    activation: type[nn.Module] = nn.ELU,
    zero_head: bool = False,
    norm: bool = False,
) -> nn.Sequential:
    """``Linear → activation`` (``Linear → LayerNorm → activation`` with ``norm``) for each hidden width, then a final
    ``Linear``.

    :param in_dim: input size.
    :param hidden: the hidden layers' widths.
    :param out_dim: output size.
    :param activation: the hidden layers' activation class.
    :param zero_head: zero the final layer's weight and bias (a learned rule's head, whose bias its owner sets).
    :param norm: a LayerNorm between each hidden ``Linear`` and its activation (TD-MPC2's hidden layers).
    """
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), *([nn.LayerNorm(width)] if norm else []), activation()]
        in_dim = width
    head = nn.Linear(in_dim, out_dim)
    if zero_head:
        nn.init.zeros_(head.weight)
        nn.init.zeros_(head.bias)
    return nn.Sequential(*layers, head)
