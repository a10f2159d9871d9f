"""The yml's ``*_kwargs`` strings: evaluated as rl-zoo3 evaluates ``policy_kwargs``, and merged with a trial's values.

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

#: ``*_kwargs`` keys that rl-zoo3 handles itself (the others are evaluated when given as strings)
_ZOO_KWARGS_KEYS = frozenset({"policy_kwargs", "replay_buffer_kwargs", "monitor_kwargs", "env_kwargs", "normalize_kwargs"})
#: yml keys that configure rl-zoo3's run, not the algorithm's constructor
_ZOO_ONLY_KEYS = frozenset({"n_timesteps", "n_envs", "normalize", "env_wrapper", "frame_stack", "callback", "vec_env_wrapper"})


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
