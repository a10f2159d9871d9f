"""The package's algorithms and their Optuna search spaces, registered in rl-zoo3's tables.

:func:`register_algos` adds the algorithms of :data:`sppo_sb3.algorithms.ALGORITHMS` to rl-zoo3's ``ALGOS`` (one whose
module does not import is skipped with a warning and listed in :data:`UNAVAILABLE`) and, through
:func:`register_samplers`, their samplers (:mod:`~sppo_sb3.zoo.samplers`) to ``HYPERPARAMS_SAMPLER`` and
``HYPERPARAMS_CONVERTER``. Enough for ``sppo-enjoy`` and ``sppo-record-video``; ``sppo-train`` also needs
:func:`~sppo_sb3.zoo.patches.install`.
"""

from __future__ import annotations

import warnings

from rl_zoo3 import hyperparams_opt as zoo_opt
from rl_zoo3.utils import ALGOS as ZOO_ALGOS
from stable_baselines3.common.base_class import BaseAlgorithm

from sppo_sb3.algorithms import ALGORITHMS
from sppo_sb3.zoo.samplers import search_spaces

#: algorithms that could not be imported, with the reason
UNAVAILABLE: dict[str, str] = {}


def algo_classes() -> dict[str, type[BaseAlgorithm]]:
    """The package's algorithms that import, by zoo name (the others go to :data:`UNAVAILABLE`, with a warning).

    :return: the classes, by zoo name.
    """
    classes: dict[str, type[BaseAlgorithm]] = {}
    for name, algo in ALGORITHMS.items():
        try:
            classes[name] = algo.load_class()
            UNAVAILABLE.pop(name, None)
        except Exception as exc:  # a module being written must not break the other algorithms
            UNAVAILABLE[name] = f"{type(exc).__name__}: {exc}"
            warnings.warn(f"sppo_sb3.zoo: algorithm {name!r} is not available ({UNAVAILABLE[name]})", stacklevel=2)
    return classes


def register_samplers(classes: dict[str, type[BaseAlgorithm]] | None = None) -> None:
    """Register each algorithm's Optuna search space (:attr:`~sppo_sb3.algorithms.Algorithm.sampler`).

    SPPO has its own (:func:`~sppo_sb3.zoo.samplers.sample_sppo_params`); PDO, SAILR and CSC use rl-zoo3's PPO
    sampler, CPO its TRPO sampler, SACLag its SAC sampler. Entries already present (a user's own sampler) are kept.

    :param classes: the available algorithms (default: all that import).
    """
    opt = zoo_opt  # rl-zoo3 keeps its samplers in hyperparams_opt
    classes = algo_classes() if classes is None else classes
    spaces = search_spaces()
    for name, algo in ALGORITHMS.items():
        if name in classes and algo.sampler is not None:
            sampler, converter = spaces[algo.sampler]
            opt.HYPERPARAMS_SAMPLER.setdefault(name, sampler)  # type: ignore[arg-type]
            opt.HYPERPARAMS_CONVERTER.setdefault(name, converter)  # type: ignore[arg-type]


def register_algos() -> dict[str, type[BaseAlgorithm]]:
    """Add the package's algorithms to rl-zoo3's ``ALGOS`` and their samplers to the zoo's Optuna tables.

    :return: the registered classes, by zoo name.
    """
    classes = algo_classes()
    ZOO_ALGOS.update(classes)
    register_samplers(classes)
    return classes
