"""SPPO's network and planner sizes, by name: ``"cpu"`` (the default, for a few CPU cores) and ``"tdmpc"`` (TD-MPC's).

TD-MPC's sizes (TOLD 50 / 256 / 512, MPPI 512 samples × 6 iterations, batches of 512 sequences of 5 steps) are
meant for a GPU: on a CPU they plan at about 175 ms per action, about 5 hours for 100k env steps. The ``"cpu"`` sizes
(TOLD 32 / 64 / 128, MPPI 64 samples × 3 iterations, batches of 128 sequences of 3 steps) plan at about 2 ms per
action, and are the ones every CPU result of the package used (``docs/guide/performance.md``). Arguments given
explicitly (``policy_kwargs``, ``planner_kwargs``, ``batch_size``, ``horizon``) override the named sizes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

SizesName = Literal["cpu", "tdmpc"]


@dataclass(frozen=True)
class Sizes:
    """One set of sizes.

    :param latent_dim: TOLD's latent size.
    :param encoder_dim: the encoder's hidden width.
    :param hidden_dim: the hidden width of the dynamics, reward, policy and value networks.
    :param num_samples: MPPI samples per iteration.
    :param num_elites: MPPI elites.
    :param iterations: MPPI iterations per planned action.
    :param batch_size: sequences per TOPO update.
    :param horizon: steps per sequence, and the planning horizon.
    """

    latent_dim: int
    encoder_dim: int
    hidden_dim: int
    num_samples: int
    num_elites: int
    iterations: int
    batch_size: int
    horizon: int

    def policy_kwargs(self) -> dict[str, Any]:
        return {"latent_dim": self.latent_dim, "encoder_dim": self.encoder_dim, "hidden_dim": self.hidden_dim}

    def planner_kwargs(self) -> dict[str, Any]:
        return {"num_samples": self.num_samples, "num_elites": self.num_elites, "iterations": self.iterations}


#: the named sizes
SIZES: dict[str, Sizes] = {
    "cpu": Sizes(32, 64, 128, 64, 8, 3, batch_size=128, horizon=3),
    "tdmpc": Sizes(50, 256, 512, 512, 64, 6, batch_size=512, horizon=5),
}


def named_sizes(name: str) -> Sizes:
    """The sizes called ``name``.

    :raises ValueError: an unknown name.
    """
    if name not in SIZES:
        raise ValueError(f"sizes={name!r} is not a set of SPPO sizes: use one of {', '.join(map(repr, SIZES))}.")
    return SIZES[name]
