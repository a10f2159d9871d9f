"""``ShieldWrapper``: shield any gymnasium env — and so any SB3 algorithm — with a :class:`ShieldingRule`."""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from sppo_sb3.common.safety import INTERVENED_KEY
from sppo_sb3.shield.base import ShieldingRule

PROPOSED_ACTION_KEY = "proposed_action"
ADVANTAGE_KEY = "shield_advantage"


class ShieldWrapper(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """Pass every action through the rule's shield (eq. 12) before the env executes it.

    The step's info carries ``info["shield_intervened"]`` (whether the backup replaced the action),
    ``info["proposed_action"]`` (what the agent asked for) and ``info["shield_advantage"]`` (``Ā(s, a)``).
    The executed action is the safe one.

    :param env: the env to protect; its observations are what the rule reads.
    :param rule: the shielding rule.
    """

    def __init__(self, env: gym.Env, rule: ShieldingRule) -> None:
        super().__init__(env)
        if not isinstance(env.action_space, gym.spaces.Box):
            raise TypeError(f"ShieldWrapper needs a Box action space, got {env.action_space}.")
        self.rule = rule
        self._box: gym.spaces.Box = env.action_space
        self._obs: np.ndarray | None = None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._obs = np.asarray(obs)
        self.rule.check_action_space(self.env.action_space, self._obs[None])
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        if self._obs is None:
            raise RuntimeError("ShieldWrapper.step called before reset().")
        proposed = np.clip(np.asarray(action, dtype=np.float64), self._box.low, self._box.high)
        decision = self.rule.shield(self._obs[None], proposed[None])
        safe = decision.actions[0].astype(self._box.dtype)
        obs, reward, terminated, truncated, info = self.env.step(safe)
        info[INTERVENED_KEY] = bool(decision.intervened[0])
        info[PROPOSED_ACTION_KEY] = proposed
        info[ADVANTAGE_KEY] = float(decision.advantage[0])
        self._obs = np.asarray(obs)
        return obs, reward, terminated, truncated, info
