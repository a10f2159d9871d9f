"""Cost conventions shared by every algorithm and task.

A safe task reports the violation indicator ``c(s, a)`` of Definition 1 in ``info["cost"]``: 1.0 on the step that
enters the unsafe set, else 0.0. The shaped cost ``ĉ`` of eq. 18 belongs to the shielding rules.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from sppo_sb3.common.keys import COST_KEY, COSTLY_STEPS_KEY, EDITS_KEY, INTERVENED_KEY, INTERVENTIONS_KEY


class MissingCostError(KeyError):
    """Raised when a safe algorithm runs on an environment that never reports ``info["cost"]``."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0])


def shaped_cost(dist: np.ndarray | float, alpha: float) -> np.ndarray:
    """Shaped cost of eq. 18: ``1[dist = 0]`` if ``alpha = 0``, else ``max(0, 1 - dist / alpha)``.

    :param dist: distance(s) from the state(s) to the unsafe set (0 inside it).
    :param alpha: width of the band in front of the unsafe set where the cost ramps up (``alpha >= 0``).
    :return: the shaped cost, in [0, 1], with the shape of ``dist``.
    """
    if alpha < 0:
        raise ValueError(f"alpha must be >= 0 (eq. 18), got {alpha}")
    dist = np.asarray(dist, dtype=np.float64)
    if alpha == 0:
        return (dist <= 0).astype(np.float64)
    return np.maximum(0.0, 1.0 - dist / alpha)


def costly_steps(info: dict[str, Any]) -> int:
    """How many env steps of a step had a cost: ``info["costly_steps"]`` under an action repeat, else 1 or 0 from
    ``info["cost"]`` (absent: 0)."""
    return int(info.get(COSTLY_STEPS_KEY, float(info.get(COST_KEY, 0.0)) > 0))


def intervention_count(info: dict[str, Any]) -> int:
    """On how many env steps a shield replaced the action: ``info["shield_interventions"]`` under an action repeat,
    else 1 or 0 from ``info["shield_intervened"]`` (0 where no shield reports)."""
    return int(info.get(INTERVENTIONS_KEY, bool(info.get(INTERVENED_KEY, False))))


def edit_count(info: dict[str, Any]) -> int:
    """On how many env steps a permissive shield replaced the action by an edit rather than the backup's (0 where no
    shield reports edits): ``info["shield_edits"]``, among :func:`intervention_count`'s."""
    return int(info.get(EDITS_KEY, 0))


def costs_from_infos(infos: Sequence[dict[str, Any]], required: bool = True) -> np.ndarray:
    """Read the violation indicator ``info["cost"]`` of every env of a VecEnv step.

    :param infos: the ``infos`` list returned by ``VecEnv.step``.
    :param required: raise when an env does not report it; otherwise count 0 there (e.g. an unshielded run on
        Pendulum-v1).
    :return: float32 array of shape ``(n_envs,)``.
    :raises MissingCostError: when ``required`` and an env does not report ``info["cost"]``.
    """
    if not required:
        return np.array([float(info.get(COST_KEY, 0.0)) for info in infos], dtype=np.float32)
    try:
        return np.array([float(info[COST_KEY]) for info in infos], dtype=np.float32)
    except KeyError:
        raise MissingCostError(
            f"The environment did not report info[{COST_KEY!r}]. Safe algorithms need the violation indicator "
            "c(s, a) (1.0 when the step enters the unsafe set, else 0.0) in the step info. Use a registered safe "
            "task (e.g. 'SafePointCircle-v0') or wrap your env with sppo_sb3.common.costs.CostInfoWrapper(env, cost_fn)."
        ) from None


class CostInfoWrapper(gym.Wrapper):
    """Adds ``info["cost"]`` to an env that does not report it, from a user-supplied indicator.

    :param env: the gymnasium env to wrap.
    :param cost_fn: ``cost_fn(obs, action, next_obs, info) -> float``, the violation indicator of the step.
    """

    def __init__(self, env: gym.Env, cost_fn: Callable[[Any, Any, Any, dict[str, Any]], float]) -> None:
        super().__init__(env)
        self.cost_fn = cost_fn
        self._last_obs: Any = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._last_obs = obs
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        info[COST_KEY] = float(self.cost_fn(self._last_obs, action, obs, info))
        self._last_obs = obs
        return obs, reward, terminated, truncated, info
