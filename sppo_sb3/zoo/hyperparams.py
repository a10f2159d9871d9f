"""The yml files: which one ``sppo-train`` reads without ``-conf``, and their ``*_kwargs`` strings, evaluated as
rl-zoo3 evaluates ``policy_kwargs`` and merged with a trial's values.

Imports nothing else of :mod:`sppo_sb3.zoo` (the bottom of the package, with :mod:`~sppo_sb3.zoo.samplers`); also used
by the benchmark scripts to read the yml files without rl-zoo3's ``ExperimentManager``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch as th
import yaml
from torch import nn

from sppo_sb3.algorithms import ALGORITHMS, HYPERPARAMS_DIR

#: ``*_kwargs`` keys that rl-zoo3 handles itself (the others are evaluated when given as strings)
_ZOO_KWARGS_KEYS = frozenset({"policy_kwargs", "replay_buffer_kwargs", "monitor_kwargs", "env_kwargs", "normalize_kwargs"})
#: yml keys that configure rl-zoo3's run, not the algorithm's constructor
_ZOO_ONLY_KEYS = frozenset({"n_timesteps", "n_envs", "normalize", "env_wrapper", "frame_stack", "callback", "vec_env_wrapper"})
#: the folders of :data:`~sppo_sb3.algorithms.HYPERPARAMS_DIR` that hold the default hyperparameters of a task family
#: whose tasks the top-level ``ALGO.yml`` does not have (Safety-Gymnasium's velocity and navigation tasks, the
#: dm_control tasks), in the order :func:`default_config` reads them
FAMILY_FOLDERS: tuple[str, ...] = ("velocity", "navigation", "dmc")


def _entries(path: Path) -> dict[str, Any]:
    with open(path) as file:
        return dict(yaml.safe_load(file) or {})


def default_config(algo: str, env_id: str, hyperparams_dir: Path = HYPERPARAMS_DIR) -> Path | None:
    """The yml file ``sppo-train`` reads for ``algo`` on ``env_id`` when no ``-conf`` is given: the package's own.

    That is the first of ``ALGO.yml`` and ``FAMILY/ALGO.yml`` (:data:`FAMILY_FOLDERS`) in ``hyperparams_dir`` that has
    an entry for the task, else a top-level ``ALGO.yml`` with a ``default`` entry. Where the package has none, rl-zoo3's
    own ``hyperparams/ALGO.yml`` applies (``None``; e.g. ``ppo`` on ``CartPole-v1``), except for the package's
    algorithms, which rl-zoo3 has no file for.

    :param algo: the ``--algo`` name.
    :param env_id: the task's gymnasium id.
    :param hyperparams_dir: the folder of the package's yml files.
    :return: the file, or ``None`` for rl-zoo3's own.
    :raises FileNotFoundError: the package's folder is missing (a checkout without its ``sppo_sb3/hyperparams`` symlink).
    :raises ValueError: ``algo`` is one of the package's algorithms and no file of the package has the task.
    """
    if not hyperparams_dir.is_dir():
        raise FileNotFoundError(
            f"{hyperparams_dir}: the package's hyperparameter folder is missing (in a checkout, sppo_sb3/hyperparams is a "
            "symlink to ../hyperparams: clone with `git config core.symlinks true`); pass -conf FILE meanwhile"
        )
    candidates = [hyperparams_dir / f"{algo}.yml", *(hyperparams_dir / folder / f"{algo}.yml" for folder in FAMILY_FOLDERS)]
    existing = [path for path in candidates if path.is_file()]
    for path in existing:
        if env_id in _entries(path):
            return path
    top = candidates[0]
    if top.is_file() and "default" in _entries(top):
        return top
    if algo in ALGORITHMS:
        looked = ", ".join(str(path.relative_to(hyperparams_dir)) for path in existing) or f"no {algo}.yml at all"
        raise ValueError(
            f"the package has no {algo} hyperparameters for {env_id} (looked in {hyperparams_dir}: {looked}); "
            f"pass -conf FILE with an entry for {env_id}"
        )
    return None


def eval_yml_string(source: str) -> Any:
    """Evaluate a yml string as rl-zoo3 does (``nn``, ``th`` and ``np`` in scope: ``activation_fn=nn.ReLU``).

    :param source: the Python expression, e.g. ``"dict(num_samples=64)"``.
    :return: its value.
    """
    return eval(source, {"nn": nn, "th": th, "np": np})  # same trust model as rl-zoo3's own eval of policy_kwargs


def eval_kwargs_strings(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """Evaluate the ``*_kwargs`` values given as Python strings (``planner_kwargs: "dict(num_samples=64)"``).

    rl-zoo3 does this for ``policy_kwargs`` and ``replay_buffer_kwargs`` only; the package's algorithms have more
    (``planner_kwargs``, ``topo_kwargs``). Done in place; returns ``hyperparams``.

    :param hyperparams: one yml entry (or its processed form).
    :return: ``hyperparams``, evaluated in place.
    """
    for key, value in list(hyperparams.items()):
        if key.endswith("_kwargs") and key not in _ZOO_KWARGS_KEYS and isinstance(value, str):
            hyperparams[key] = eval_yml_string(value)
    return hyperparams


def merge_kwargs(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """``{**base, **update}`` where ``*_kwargs`` dicts are merged one level deep instead of replaced.

    :param base: e.g. the yml's hyperparameters.
    :param update: e.g. a trial's sampled hyperparameters.
    :return: a new dict (neither argument is modified).
    """
    merged = dict(base)
    for key, value in update.items():
        old = merged.get(key)
        if isinstance(old, str) and key.endswith("_kwargs"):
            old = eval_yml_string(old)
        merged[key] = {**old, **value} if isinstance(old, dict) and isinstance(value, dict) else value
    return merged


def constructor_kwargs(path: Path, env_id: str) -> dict[str, Any]:
    """An algorithm's constructor keywords for ``env_id`` from a yml file of ``hyperparams/``, as rl-zoo3 would pass
    them (every ``*_kwargs`` string evaluated, ``policy`` and ``shield`` kept, the run's own keys dropped).

    :param path: the yml file, e.g. ``hyperparams/sppo.yml``.
    :param env_id: the task's entry.
    :raises KeyError: the file has no entry for ``env_id``.
    """
    entries = yaml.safe_load(Path(path).read_text())
    if env_id not in entries:
        raise KeyError(f"{path} has no entry for {env_id} (it has: {', '.join(entries)})")
    kwargs = eval_kwargs_strings(dict(entries[env_id]))
    for key in ("policy_kwargs", "replay_buffer_kwargs"):  # rl-zoo3 evaluates these itself
        if isinstance(kwargs.get(key), str):
            kwargs[key] = eval_yml_string(kwargs[key])
    return {key: value for key, value in kwargs.items() if key not in _ZOO_ONLY_KEYS}
