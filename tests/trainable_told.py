"""A small TOLD with its EMA target and TOPO's two optimisers, ready for ``topo_update``: shared by the tests that train
one of its heads."""

from __future__ import annotations

from typing import Any

import torch as th
from tiny_hyperparams import SMALL_TOLD

from sppo_sb3.sppo.optim import init_optimizer_state
from sppo_sb3.sppo.world_model import TOLD


def trainable_told(**heads: Any) -> tuple[TOLD, TOLD, th.optim.Optimizer, th.optim.Optimizer]:
    """``(model, target, optimizer, pi_optimizer)`` for 3-dimensional observations and 2-dimensional actions, seeded;
    ``heads`` are TOLD's optional heads (``termination=True``, ``intervention=True``)."""
    th.manual_seed(0)
    model = TOLD(obs_dim=3, action_dim=2, **SMALL_TOLD, **heads)
    target = TOLD(obs_dim=3, action_dim=2, **SMALL_TOLD, **heads)
    target.load_state_dict(model.state_dict())
    optimizer = th.optim.Adam([p for n, p in model.named_parameters() if not n.startswith("pi.")])
    pi_optimizer = th.optim.Adam(model.pi.parameters())
    for opt in (optimizer, pi_optimizer):
        init_optimizer_state(opt)
    return model, target, optimizer, pi_optimizer
