"""Deployment safety: the learned policy evaluated with and without the shield, side by side.

The paper bounds the safety of the learned policy deployed *without* the shield (Corollary 1: ``V̄^Π̃ <= Q̄^ζ +
min{β + η, 2γ} / (1 - γ) + ε``). :func:`evaluate_deployment` measures both deployments of any algorithm of the
package the same way: the policy's own actions (``predict`` with the algorithm's own shield turned off), executed
either as they are (``shielded=False``) or through :class:`~sppo_sb3.shield.ShieldWrapper` with the model's rule
(``shielded=True``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from sppo_sb3.common.keys import COST_KEY, INTERVENED_KEY
from sppo_sb3.shield.base import ShieldingRule
from sppo_sb3.shield.wrapper import ShieldWrapper

DEPLOYMENT_KEYS = ("mean_reward", "mean_violations", "safe_episode_rate", "mean_interventions")
"""What :func:`evaluate_deployment` returns, per deployment (logged as ``eval/<key>`` and ``eval_unshielded/<key>``)."""


@contextlib.contextmanager
def own_shield_off(model: BaseAlgorithm) -> Iterator[None]:
    """Turn off the shield an algorithm applies inside ``predict`` (SPPO's ``shield_at_predict``) for a while."""
    previous = getattr(model, "shield_at_predict", None)
    if previous is not None:
        model.shield_at_predict = False  # type: ignore[attr-defined]
    try:
        yield
    finally:
        if previous is not None:
            model.shield_at_predict = previous  # type: ignore[attr-defined]


def deployment_rule(model: BaseAlgorithm) -> ShieldingRule | None:
    """The shield a model was trained with: its own ``shield_rule``, else the rule of a :class:`ShieldWrapper` around
    its training envs (an algorithm shielded by the wrapper, e.g. through rl-zoo3's ``env_wrapper``), else ``None``."""
    rule = getattr(model, "shield_rule", None)
    venv = model.get_env()
    if rule is None and venv is not None and venv.env_is_wrapped(ShieldWrapper, indices=[0])[0]:
        rule = venv.get_attr("rule", indices=[0])[0]
    return rule


def evaluate_deployment(
    model: BaseAlgorithm,
    make_env: Callable[[], gym.Env],
    n_eval_episodes: int = 10,
    shielded: bool = True,
    deterministic: bool = True,
    seed: int | None = 0,
    vec_normalize: VecNormalize | None = None,
) -> dict[str, float]:
    """Run the learned policy for ``n_eval_episodes`` full episodes, with or without the model's shield.

    :param model: a trained algorithm (the shield is :func:`deployment_rule`'s; where it finds none, both deployments
        are the same).
    :param make_env: builds one evaluation env (raw observations, ``info["cost"]``), e.g.
        ``lambda: gym.make("SafePointCircle-v0")``.
    :param n_eval_episodes: episodes to run.
    :param shielded: execute the actions through :class:`ShieldWrapper` with the model's rule.
    :param deterministic: deterministic actions (deployment).
    :param seed: seeds the first reset (the following episodes continue the env's RNG); ``None``: unseeded.
    :param vec_normalize: the ``VecNormalize`` the model was trained under: the policy sees the observations
        normalised with its statistics, the shield the raw ones; ``None``: the observations go to ``predict`` as they
        are.
    :return: mean return, mean violations per episode, safe-episode rate (% of episodes without a violation) and
        mean shield interventions per episode.
    """
    if n_eval_episodes < 1:
        raise ValueError(f"n_eval_episodes must be >= 1, got {n_eval_episodes}.")
    env = make_env()
    rule = deployment_rule(model)
    if shielded and rule is not None:
        env = ShieldWrapper(env, rule)
    returns, violations, interventions = [], [], []
    with own_shield_off(model):
        for episode in range(n_eval_episodes):
            obs, _ = env.reset(seed=seed if episode == 0 else None)
            totals = np.zeros(3)
            state: Any = None
            done, start = False, np.array([True])
            while not done:
                policy_obs = obs if vec_normalize is None else vec_normalize.normalize_obs(obs)
                action, state = model.predict(policy_obs, state=state, episode_start=start, deterministic=deterministic)
                obs, reward, terminated, truncated, info = env.step(action)
                start = np.array([False])
                totals += (float(reward), float(info.get(COST_KEY, 0.0)) > 0, bool(info.get(INTERVENED_KEY, False)))
                done = terminated or truncated
            returns.append(totals[0])
            violations.append(totals[1])
            interventions.append(totals[2])
    env.close()
    return {
        "mean_reward": float(np.mean(returns)),
        "mean_violations": float(np.mean(violations)),
        "safe_episode_rate": 100.0 * float(np.mean(np.asarray(violations) == 0)),
        "mean_interventions": float(np.mean(interventions)),
    }
