"""The one list of the package's algorithms, read by the zoo, the benchmark and the plots.

Each :class:`Algorithm` names its class by module and attribute (it is imported only when asked for, so that
reading the list imports no algorithm) and carries what the zoo (:mod:`sppo_sb3.zoo`), the benchmark and the plots
(:mod:`sppo_lab`) need to know about it. rl-zoo3's own algorithms that the paper compares against
(Fig. 7: DDPG, PPO; and SAC, TD3) are listed for display only, in :data:`ZOO_BASELINES`. The package also has
algorithms the paper does not compare (``paper=False``: SACLag), which the benchmark runs only when asked to.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

#: the Optuna search space an algorithm uses: SPPO's own, or the one rl-zoo3 has for PPO, TRPO or SAC
SamplerName = Literal["sppo", "ppo", "trpo", "sac"]
#: the package's rl-zoo3 hyperparameter files (``ALGO.yml`` and the variant folders: ``velocity/``, ``dmc/``, ...):
#: ``sppo_sb3/hyperparams``, in a checkout a symlink to the repository's top-level ``hyperparams/`` (their one source,
#: resolved here), in an installed wheel a copy of its yml files (package data)
HYPERPARAMS_DIR: Path = (Path(__file__).resolve().parent / "hyperparams").resolve()


@dataclass(frozen=True)
class Algorithm:
    """One algorithm as the package's tooling sees it.

    :param name: rl-zoo3 name (``--algo``), also that of its hyperparameter file ``hyperparams/<name>.yml``.
    :param module: module that defines the class (``None``: one of rl-zoo3's own algorithms).
    :param class_name: the class's name in ``module``.
    :param display_name: name in the figures and tables.
    :param color: matplotlib colour of its curves and bars.
    :param sampler: its Optuna search space for ``sppo-train -optimize`` (``None``: none registered by the package).
    :param paper: one of the paper's compared algorithms (Tables I-II), in the benchmark's default grid.
    """

    name: str
    module: str | None
    class_name: str
    display_name: str
    color: str
    sampler: SamplerName | None = None
    paper: bool = True

    def load_class(self) -> type[BaseAlgorithm]:
        """Import and return the algorithm's class.

        :raises ValueError: for rl-zoo3's own algorithms, whose classes rl-zoo3 provides.
        """
        if self.module is None:
            raise ValueError(f"{self.name!r} is one of rl-zoo3's algorithms: take its class from rl_zoo3.utils.ALGOS")
        return getattr(importlib.import_module(self.module), self.class_name)


#: the package's algorithms, in the order the benchmark runs them
ALGORITHMS: dict[str, Algorithm] = {
    algo.name: algo
    for algo in (
        Algorithm("sppo", "sppo_sb3.sppo", "SPPO", "SPPO (ours)", "tab:red", sampler="sppo"),
        Algorithm("pdo", "sppo_sb3.pdo", "PDO", "PDO", "tab:green", sampler="ppo"),
        Algorithm("cpo", "sppo_sb3.cpo", "CPO", "CPO", "tab:orange", sampler="trpo"),
        Algorithm("sailr", "sppo_sb3.sailr", "SAILR", "SAILR", "tab:blue", sampler="ppo"),
        Algorithm("csc", "sppo_sb3.csc", "CSC", "CSC", "tab:purple", sampler="ppo"),
        Algorithm("saclag", "sppo_sb3.saclag", "SACLag", "SACLag", "tab:pink", sampler="sac", paper=False),
    )
}
#: rl-zoo3's algorithms that the comparisons may include (shown in figures and tables, trained by rl-zoo3 itself)
ZOO_BASELINES: dict[str, Algorithm] = {
    algo.name: algo
    for algo in (
        Algorithm("ddpg", None, "DDPG", "DDPG", "tab:brown"),
        Algorithm("ppo", None, "PPO", "PPO", "tab:gray"),
        Algorithm("sac", None, "SAC", "SAC", "tab:olive"),
        Algorithm("td3", None, "TD3", "TD3", "tab:cyan"),
    )
}
#: the paper's compared algorithms, in the order the benchmark runs them (its default grid)
PAPER_ALGORITHMS: tuple[str, ...] = tuple(name for name, algo in ALGORITHMS.items() if algo.paper)
#: display order of figures and tables: as the paper's Tables I-II, the safe-RL baselines first and SPPO last
DISPLAY_ORDER: tuple[str, ...] = ("cpo", "pdo", "csc", "sailr", "saclag", *ZOO_BASELINES, "sppo")


__all__ = ["ALGORITHMS", "DISPLAY_ORDER", "HYPERPARAMS_DIR", "PAPER_ALGORITHMS", "ZOO_BASELINES", "Algorithm"]
