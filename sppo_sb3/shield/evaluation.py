"""Deployment safety: the learned policy evaluated with and without the shield, side by side.

The paper bounds the safety of the learned policy deployed *without* the shield (Corollary 1: ``V̄^Π̃ <= Q̄^ζ +
min{β + η, 2γ} / (1 - γ) + ε``). :func:`evaluate_deployment` measures both deployments of any algorithm of the
package the same way: the policy's own actions (``predict`` with the algorithm's own shield turned off), executed
either as they are (``shielded=False``) or through :class:`~sppo_sb3.shield.ShieldWrapper` with the model's rule
(``shielded=True``), each action held for as many env steps as in training (:func:`deployment_action_repeat`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from sppo_sb3.common.action_repeat import ActionRepeat
from sppo_sb3.common.costs import costly_steps, intervention_count
from sppo_sb3.common.keys import INTERVENED_KEY
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


def deployment_action_repeat(model: BaseAlgorithm) -> int:
    """How many env steps each of a model's actions was held for in training: the ``action_repeat`` of a
    :class:`ShieldWrapper` or the ``repeat`` of an :class:`~sppo_sb3.common.action_repeat.ActionRepeat` around its
    training envs, else 1 (also where the model has no env)."""
    venv = model.get_env()
    if venv is not None:
        for wrapper, attribute in ((ShieldWrapper, "action_repeat"), (ActionRepeat, "repeat")):
            if venv.env_is_wrapped(wrapper, indices=[0])[0]:
                return int(venv.get_attr(attribute, indices=[0])[0])
    return 1


@dataclass
class Episode:
    """One deployed episode.

    :param reward: its return.
    :param length: its steps (the policy's: one per action, however many env steps each was held for).
    :param terminated: whether it ended by termination (not by truncation).
    :param violations: its env steps with a positive cost.
    :param intervention_steps: the steps (1-based) at which a shield overrode the action.
    :param interventions: its env steps at which a shield overrode the action (more than ``intervention_steps`` where
        a held action was overridden on several of its env steps).
    """

    reward: float
    length: int
    terminated: bool
    violations: int
    intervention_steps: list[int]
    interventions: int = 0


def run_episode(
    model: BaseAlgorithm,
    env: gym.Env,
    seed: int | None,
    deterministic: bool = True,
    vec_normalize: VecNormalize | None = None,
) -> Episode:
    """Run the policy's own actions (its own shield off) for one episode of ``env``.

    :param model: a trained algorithm.
    :param env: one env (raw observations, ``info["cost"]``, and ``info["intervened"]`` where it is shielded).
    :param seed: seed of the reset (``None``: continue the env's RNG).
    :param deterministic: deterministic actions.
    :param vec_normalize: the ``VecNormalize`` the model was trained under (see :func:`evaluate_deployment`).
    """
    obs, _ = env.reset(seed=seed)
    reward, steps, violations, intervention_steps, interventions = 0.0, 0, 0, [], 0
    state: Any = None
    done, terminated, start = False, False, np.array([True])
    with own_shield_off(model):
        while not done:
            policy_obs = obs if vec_normalize is None else vec_normalize.normalize_obs(obs)
            action, state = model.predict(policy_obs, state=state, episode_start=start, deterministic=deterministic)
            obs, step_reward, terminated, truncated, info = env.step(action)
            start, steps = np.array([False]), steps + 1
            reward += float(step_reward)
            violations += costly_steps(info)
            interventions += intervention_count(info)
            if info.get(INTERVENED_KEY, False):
                intervention_steps.append(steps)
            done = terminated or truncated
    return Episode(reward, steps, bool(terminated), violations, intervention_steps, interventions)


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
    :return: mean return, mean violations (env steps with a cost) per episode, safe-episode rate (% of episodes
        without a violation) and mean shield interventions (env steps) per episode.
    """
    if n_eval_episodes < 1:
        raise ValueError(f"n_eval_episodes must be >= 1, got {n_eval_episodes}.")
    env = make_env()
    rule, repeat = deployment_rule(model), deployment_action_repeat(model)
    if shielded and rule is not None:
        env = ShieldWrapper(env, rule, action_repeat=repeat)
    elif repeat > 1:
        env = ActionRepeat(env, repeat)
    episodes = [
        run_episode(model, env, seed if episode == 0 else None, deterministic, vec_normalize)
        for episode in range(n_eval_episodes)
    ]
    env.close()
    violations = np.array([episode.violations for episode in episodes])
    return {
        "mean_reward": float(np.mean([episode.reward for episode in episodes])),
        "mean_violations": float(np.mean(violations)),
        "safe_episode_rate": 100.0 * float(np.mean(violations == 0)),
        "mean_interventions": float(np.mean([episode.interventions for episode in episodes])),
    }
