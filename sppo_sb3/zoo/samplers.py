"""Optuna search spaces: SPPO's own (:func:`sample_sppo_params`) and the table of those the package's algorithms use.

Imports nothing else of :mod:`sppo_sb3.zoo` (the bottom of the package, with :mod:`~sppo_sb3.zoo.hyperparams`);
:func:`~sppo_sb3.zoo.registration.register_samplers` puts them into rl-zoo3's tables.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import optuna
from rl_zoo3 import hyperparams_opt as zoo_opt

#: a sampler (rl-zoo3's signature: ``trial, n_actions, n_envs, additional_args``) and its converter of trial params
SearchSpace = tuple[Callable[..., dict[str, Any]], Callable[[dict[str, Any]], dict[str, Any]]]

TOLD_SIZES: dict[str, dict[str, int]] = {
    "tiny": {"latent_dim": 32, "encoder_dim": 64, "hidden_dim": 128},
    "small": {"latent_dim": 50, "encoder_dim": 128, "hidden_dim": 256},
    "tdmpc": {"latent_dim": 50, "encoder_dim": 256, "hidden_dim": 512},
}


def convert_sppo_params(sampled_params: dict[str, Any]) -> dict[str, Any]:
    """SPPO constructor arguments from the raw values of :func:`sample_sppo_params` (a trial's ``params``).

    :param sampled_params: the trial's parameters.
    :return: the constructor arguments (``planner_kwargs`` and ``policy_kwargs`` as dicts).
    """
    p = dict(sampled_params)
    num_samples = 2 ** p.pop("num_samples_pow")
    planner_kwargs = {
        "num_samples": num_samples,
        "num_elites": min(2 ** p.pop("num_elites_pow"), num_samples // 2),
        "iterations": p.pop("iterations"),
        "temperature": p.pop("temperature"),
        "policy_fraction": p.pop("policy_fraction"),
    }
    return {
        "learning_rate": p.pop("learning_rate"),
        "batch_size": 2 ** p.pop("batch_size_pow"),
        "gamma": 1.0 - p.pop("one_minus_gamma"),
        "tau": p.pop("tau"),
        "horizon": p.pop("horizon"),
        "planner_kwargs": planner_kwargs,
        "policy_kwargs": dict(TOLD_SIZES[p.pop("told_size")]),
        **p,
    }


def sample_sppo_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict[str, Any]:
    """Optuna search space of SPPO (TOPO learning rate, batch, horizon, EMA; MPPI sizes; TOLD size).

    Signature of rl-zoo3's samplers. ``planner_kwargs`` and ``policy_kwargs`` are merged into the yml's by
    :class:`~sppo_sb3.zoo.experiment.SafeExperimentManager` (fields that are not searched, e.g. ``horizon_warmup``,
    keep their yml value).

    :param trial: the Optuna trial.
    :param n_actions: action dimension (unused).
    :param n_envs: number of envs (unused).
    :param additional_args: rl-zoo3's extra arguments (unused).
    :return: the SPPO constructor arguments of this trial.
    """
    return convert_sppo_params(
        {
            "learning_rate": trial.suggest_float("learning_rate", 1e-4, 3e-3, log=True),
            "batch_size_pow": trial.suggest_int("batch_size_pow", 6, 9),
            "one_minus_gamma": trial.suggest_float("one_minus_gamma", 0.002, 0.05, log=True),
            "tau": trial.suggest_float("tau", 0.002, 0.05, log=True),
            "horizon": trial.suggest_int("horizon", 3, 7),
            "num_samples_pow": trial.suggest_int("num_samples_pow", 6, 9),
            "num_elites_pow": trial.suggest_int("num_elites_pow", 3, 6),
            "iterations": trial.suggest_int("iterations", 2, 6),
            "temperature": trial.suggest_float("temperature", 0.1, 2.0, log=True),
            "policy_fraction": trial.suggest_categorical("policy_fraction", [0.05, 0.1, 0.25]),
            "told_size": trial.suggest_categorical("told_size", list(TOLD_SIZES)),
        }
    )


def search_spaces() -> dict[str, SearchSpace]:
    """The search spaces an algorithm may name (:attr:`~sppo_sb3.algorithms.Algorithm.sampler`), by that name.

    SPPO has its own; ``"ppo"``, ``"trpo"`` and ``"sac"`` are rl-zoo3's samplers of those algorithms (read from
    rl-zoo3's ``hyperparams_opt`` at each call).

    :return: ``{name: (sampler, converter)}``.
    """
    opt = zoo_opt  # rl-zoo3 keeps its samplers in hyperparams_opt
    return {
        "sppo": (sample_sppo_params, convert_sppo_params),
        "ppo": (opt.sample_ppo_params, opt.convert_onpolicy_params),
        "trpo": (opt.sample_trpo_params, opt.convert_onpolicy_params),
        "sac": (opt.sample_sac_params, opt.convert_offpolicy_params),
    }
