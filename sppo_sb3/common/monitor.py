"""Episode cost in the outputs that SB3 and rl-zoo3 already write: ``monitor.csv`` and the evaluation callback.

- :class:`EpisodeCostInfo` (a gymnasium wrapper, placed *inside* SB3's ``Monitor``) adds the episode totals
  ``episode_cost`` (sum of ``info["cost"]``), ``episode_violations`` (steps with ``info["cost"] > 0``) and
  ``episode_interventions`` (steps where a :class:`~sppo_sb3.shield.ShieldWrapper` replaced the action; NaN without
  one) to the info of the step that ends an episode. ``Monitor(env, info_keywords=COST_INFO_KEYWORDS)`` then writes
  them as extra columns of ``monitor.csv`` and into ``info["episode"]``.
- :func:`cost_monitored_make_vec_env` is SB3's ``make_vec_env`` with that wrapper and those columns always added, and
  the user's ``wrapper_class`` inside ``Monitor``.
- :class:`CostEvalCallback` is SB3's ``EvalCallback`` that also measures the evaluation episodes' cost: logged as
  ``eval/mean_cost``, ``eval/mean_violations`` and ``eval/safe_episode_rate`` next to ``eval/mean_reward``, and saved as
  ``costs``/``violations`` in ``evaluations.npz``.

An env that does not report ``info["cost"]`` (e.g. ``Pendulum-v1``) gets zeros in these columns.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from sppo_sb3.common.costs import costly_steps, intervention_count
from sppo_sb3.common.keys import (
    COST_INFO_KEYWORDS,
    COST_KEY,
    EPISODE_COST_INFO_KEY,
    EPISODE_INTERVENTIONS_INFO_KEY,
    EPISODE_VIOLATIONS_INFO_KEY,
    EVAL_MEAN_COST_LOG_KEY,
    EVAL_MEAN_VIOLATIONS_LOG_KEY,
    EVAL_SAFE_EPISODE_RATE_LOG_KEY,
    INTERVENED_KEY,
)


class EpisodeCostInfo(gym.Wrapper):
    """Adds the episode's ``episode_cost``, ``episode_violations`` and ``episode_interventions`` to the info of its last step.

    Wrap the env with it *before* ``Monitor`` (``Monitor(EpisodeCostInfo(env), info_keywords=COST_INFO_KEYWORDS)``):
    ``Monitor`` reads the info keywords at the step that ends the episode.

    :param env: the env; its ``info["cost"]`` (absent: 0) is the violation indicator of the step, and its
        ``info["shield_intervened"]`` (absent: no shield) whether a shield replaced the action.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._cost = 0.0
        self._violations = 0
        self._interventions: int | None = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self._cost, self._violations, self._interventions = 0.0, 0, None
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        cost = float(info.get(COST_KEY, 0.0))
        self._cost += cost
        self._violations += costly_steps(info)  # env steps with a cost, under an action repeat too
        if INTERVENED_KEY in info:
            self._interventions = (self._interventions or 0) + intervention_count(info)
        if terminated or truncated:
            interventions = float("nan") if self._interventions is None else float(self._interventions)
            info = {
                **info,
                EPISODE_COST_INFO_KEY: self._cost,
                EPISODE_VIOLATIONS_INFO_KEY: self._violations,
                EPISODE_INTERVENTIONS_INFO_KEY: interventions,
            }
        return obs, reward, terminated, truncated, info


def with_episode_cost(
    env_id: str | Callable[..., gym.Env],
    wrapper_class: Callable[..., gym.Env] | None = None,
    wrapper_kwargs: dict[str, Any] | None = None,
) -> Callable[..., gym.Env]:
    """An env factory (``**env_kwargs -> env``): ``env_id``'s env, wrapped by ``wrapper_class``, then :class:`EpisodeCostInfo`.

    :param env_id: a registered id or a callable returning an env, as accepted by SB3's ``make_vec_env``.
    :param wrapper_class: a wrapper applied to the env first (rl-zoo3's ``env_wrapper``), ``None``: none.
    :param wrapper_kwargs: keyword arguments of ``wrapper_class``.
    """

    def make(**env_kwargs: Any) -> gym.Env:
        env = gym.make(env_id, **env_kwargs) if isinstance(env_id, str) else env_id(**env_kwargs)
        if wrapper_class is not None:
            env = wrapper_class(env, **(wrapper_kwargs or {}))
        return EpisodeCostInfo(env)

    return make


def cost_monitored_make_vec_env(
    env_id: str | Callable[..., gym.Env],
    n_envs: int = 1,
    *,
    monitor_kwargs: dict[str, Any] | None = None,
    wrapper_class: Callable[..., gym.Env] | None = None,
    wrapper_kwargs: dict[str, Any] | None = None,
    **kwargs: Any,
) -> VecEnv:
    """SB3's ``make_vec_env`` whose ``Monitor`` also writes ``episode_cost`` and ``episode_violations``.

    Same arguments as :func:`stable_baselines3.common.env_util.make_vec_env`; ``monitor_kwargs["info_keywords"]``
    is extended with :data:`COST_INFO_KEYWORDS` (keywords already there are kept). Unlike SB3's, ``wrapper_class``
    goes *inside* ``Monitor``, so that ``Monitor`` records the episodes the learner sees: a
    :class:`~sppo_sb3.shield.ShieldWrapper` that ends an episode at an intervention (``on_intervention="absorb"``)
    would otherwise end it above ``Monitor``, whose next ``reset`` drops the episode and its violations.

    :param env_id: a registered id or a callable returning an env.
    :param n_envs: number of envs.
    :param monitor_kwargs: keyword arguments of ``Monitor``.
    :param wrapper_class: a wrapper of each env, inside ``Monitor`` (rl-zoo3's ``env_wrapper``).
    :param wrapper_kwargs: keyword arguments of ``wrapper_class``.
    """
    monitor_kwargs = dict(monitor_kwargs or {})
    keywords = tuple(monitor_kwargs.get("info_keywords", ()))
    monitor_kwargs["info_keywords"] = keywords + tuple(k for k in COST_INFO_KEYWORDS if k not in keywords)
    factory = with_episode_cost(env_id, wrapper_class, wrapper_kwargs)
    return make_vec_env(factory, n_envs, monitor_kwargs=monitor_kwargs, **kwargs)


class CostEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` that also reports the cost of the evaluation episodes.

    Costs are read from the eval env's ``info["cost"]`` and summed per episode by the callback itself (no wrapper
    needed). Each evaluation logs ``eval/mean_cost``, ``eval/mean_violations`` and ``eval/safe_episode_rate`` (share
    of episodes without a violation, in %) with ``eval/mean_reward``, and, when ``log_path`` is set, adds
    ``costs`` and ``violations`` (one row of per-episode values per evaluation) to ``evaluations.npz``.
    Takes the arguments of ``EvalCallback``.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.evaluations_costs: list[list[float]] = []
        self.evaluations_violations: list[list[int]] = []
        self.last_mean_cost = float("nan")
        self.last_mean_violations = float("nan")
        self._episode_costs: list[float] = []
        self._episode_violations: list[int] = []
        self._running_cost = np.zeros(0)
        self._running_violations = np.zeros(0, dtype=np.int64)

    def _eval_due(self) -> bool:
        return self.eval_freq > 0 and self.n_calls % self.eval_freq == 0

    def _log_success_callback(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        super()._log_success_callback(locals_, globals_)
        info, idx = locals_["info"], int(locals_["i"])
        if self._running_cost.shape[0] != self.eval_env.num_envs:
            self._running_cost = np.zeros(self.eval_env.num_envs)
            self._running_violations = np.zeros(self.eval_env.num_envs, dtype=np.int64)
        cost = float(info.get(COST_KEY, 0.0))
        self._running_cost[idx] += cost
        self._running_violations[idx] += costly_steps(info)
        # evaluate_policy counts an episode at a done that carries Monitor's "episode" (or at any done without Monitor)
        if locals_["done"] and ("episode" in info or not locals_.get("is_monitor_wrapped", False)):
            self._episode_costs.append(float(self._running_cost[idx]))
            self._episode_violations.append(int(self._running_violations[idx]))
            self._running_cost[idx], self._running_violations[idx] = 0.0, 0
            # recorded at every episode end: the logger keeps the last value, the mean over the whole evaluation,
            # and EvalCallback dumps it with eval/mean_reward
            self.last_mean_cost = float(np.mean(self._episode_costs))
            self.last_mean_violations = float(np.mean(self._episode_violations))
            self.logger.record(EVAL_MEAN_COST_LOG_KEY, self.last_mean_cost)
            self.logger.record(EVAL_MEAN_VIOLATIONS_LOG_KEY, self.last_mean_violations)
            safe = 100.0 * float(np.mean(np.asarray(self._episode_violations) == 0))
            self.logger.record(EVAL_SAFE_EPISODE_RATE_LOG_KEY, safe)

    def _on_step(self) -> bool:
        due = self._eval_due()
        if due:
            self._episode_costs, self._episode_violations = [], []
            self._running_cost = np.zeros(self.eval_env.num_envs)
            self._running_violations = np.zeros(self.eval_env.num_envs, dtype=np.int64)
        continue_training = super()._on_step()
        if due:
            self.evaluations_costs.append(list(self._episode_costs))
            self.evaluations_violations.append(list(self._episode_violations))
            if self.verbose >= 1:
                print(f"Episode cost: {self.last_mean_cost:.2f}  violations: {self.last_mean_violations:.2f}")
            if self.log_path is not None:
                self._save_evaluations()
        return continue_training

    def _save_evaluations(self) -> None:
        """Rewrite ``evaluations.npz`` with the cost arrays beside the ones ``EvalCallback`` saved."""
        assert self.log_path is not None
        extra: dict[str, Any] = {}
        if self.evaluations_successes:
            extra["successes"] = self.evaluations_successes
        np.savez(
            self.log_path,
            timesteps=self.evaluations_timesteps,
            results=self.evaluations_results,
            ep_lengths=self.evaluations_length,
            costs=np.array(self.evaluations_costs, dtype=np.float64),
            violations=np.array(self.evaluations_violations, dtype=np.int64),
            **extra,
        )


class VecCostReporter(VecEnvWrapper):
    """Prints each finished episode's cost and violations (for watching an agent: ``sppo-enjoy``), and keeps totals.

    :param venv: the VecEnv; its infos' ``"cost"`` (absent: 0) are summed per episode.
    :param verbose: print a line per finished episode when ``>= 1``.
    """

    def __init__(self, venv: VecEnv, verbose: int = 1) -> None:
        super().__init__(venv)
        self.verbose = verbose
        self._cost = np.zeros(venv.num_envs)
        self._violations = np.zeros(venv.num_envs, dtype=np.int64)
        self.episode_costs: list[float] = []
        self.episode_violations: list[int] = []

    def reset(self) -> Any:
        self._cost[:] = 0.0
        self._violations[:] = 0
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        costs = np.array([float(info.get(COST_KEY, 0.0)) for info in infos])
        self._cost += costs
        self._violations += np.array([costly_steps(info) for info in infos])
        for idx in np.flatnonzero(dones):
            self.episode_costs.append(float(self._cost[idx]))
            self.episode_violations.append(int(self._violations[idx]))
            if self.verbose >= 1:
                print(f"Episode cost: {self._cost[idx]:.2f}  violations: {int(self._violations[idx])}")
            self._cost[idx], self._violations[idx] = 0.0, 0
        return obs, rewards, dones, infos

    def close(self) -> None:
        if self.verbose >= 1 and self.episode_costs:
            unsafe = sum(v > 0 for v in self.episode_violations)
            print(
                f"{len(self.episode_costs)} episodes: mean cost {np.mean(self.episode_costs):.2f}, "
                f"violations {sum(self.episode_violations)}, "
                f"safety rate {100.0 * (1 - unsafe / len(self.episode_costs)):.2f}%"
            )
        super().close()
