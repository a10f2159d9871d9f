"""The measured episode cost ``J_C`` that the constrained algorithms compare with their cost limit ``d``."""

from __future__ import annotations

from collections import deque

import numpy as np


class EpisodeCostTracker:
    """Measured episode cost ``J_C`` (undiscounted sum of ``info["cost"]`` per episode), compared with the limit ``d``.

    PDO's and CSC's dual ascent and CPO's constraint value ``c = J_C - d`` read :meth:`estimate`: the mean cost of the
    episodes that ended during the latest rollout; if none ended, the mean over the last ``window`` finished
    episodes; if none ever ended, the mean cost so far of the running episodes (a lower bound). An off-policy
    algorithm, which has no rollouts to speak of, reads the windowed mean alone (:meth:`recent_estimate`).

    :param n_envs: number of parallel envs.
    :param window: number of finished episodes kept for the fallback estimate.
    """

    def __init__(self, n_envs: int, window: int = 100) -> None:
        self.n_envs = n_envs
        self.window = window
        self.running_cost = np.zeros(n_envs)
        self.running_length = np.zeros(n_envs, dtype=np.int64)
        self.recent_costs: deque[float] = deque(maxlen=window)
        self.recent_lengths: deque[int] = deque(maxlen=window)
        self.rollout_costs: list[float] = []
        self.rollout_lengths: list[int] = []

    def resize(self, n_envs: int) -> None:
        """Follow a change in the number of envs (running episodes restart; finished ones are kept)."""
        if n_envs != self.n_envs:
            self.n_envs = n_envs
            self.reset_running()

    def reset_running(self) -> None:
        """Forget the running episodes (the envs were reset)."""
        self.running_cost = np.zeros(self.n_envs)
        self.running_length = np.zeros(self.n_envs, dtype=np.int64)

    def start_rollout(self) -> None:
        """Start counting the episodes of a new rollout."""
        self.rollout_costs = []
        self.rollout_lengths = []

    def update(self, costs: np.ndarray, dones: np.ndarray) -> None:
        """Feed one VecEnv step: ``(n_envs,)`` costs and episode ends."""
        self.running_cost += costs
        self.running_length += 1
        for idx in np.flatnonzero(dones):
            cost, length = float(self.running_cost[idx]), int(self.running_length[idx])
            self.rollout_costs.append(cost)
            self.rollout_lengths.append(length)
            self.recent_costs.append(cost)
            self.recent_lengths.append(length)
            self.running_cost[idx] = 0.0
            self.running_length[idx] = 0

    def estimate(self) -> float:
        """The measured mean episode cost ``J_C`` (see the class docstring for the fallbacks)."""
        if self.rollout_costs:
            return float(np.mean(self.rollout_costs))
        return self.recent_estimate()

    def recent_estimate(self) -> float:
        """``J_C`` over the last ``window`` finished episodes, whatever the rollouts (SACLag's dual step, which runs
        every few env steps); if none ever ended, the mean cost so far of the running episodes (a lower bound)."""
        if self.recent_costs:
            return float(np.mean(self.recent_costs))
        return float(np.mean(self.running_cost))

    def mean_length(self) -> float:
        """Mean episode length matching :meth:`estimate` (at least 1)."""
        if self.rollout_lengths:
            return max(float(np.mean(self.rollout_lengths)), 1.0)
        if self.recent_lengths:
            return max(float(np.mean(self.recent_lengths)), 1.0)
        return max(float(np.mean(self.running_length)), 1.0)
