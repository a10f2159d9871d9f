"""Test env wrappers and rules shared by several test modules."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from sppo_sb3.shield import ShieldingRule


class RecordExecuted(gym.Wrapper):
    """Below the shield: records the observation and the action the env actually received."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.log: list[tuple[np.ndarray, np.ndarray]] = []
        self._obs: np.ndarray | None = None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        self._obs = obs
        return obs, info

    def step(self, action: np.ndarray) -> tuple[Any, ...]:
        self.log.append((np.array(self._obs, dtype=np.float64), np.array(action, dtype=np.float64)))
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._obs = obs
        return obs, reward, terminated, truncated, info


class AcceptsAll(ShieldingRule):
    """A two-control rule that lets everything through: the costly episodes a broken rule would leave."""

    gamma = 0.99

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.zeros(len(obs))

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 2))
