"""The safety bookkeeping of a cost-aware SB3 algorithm, on- or off-policy: fed every env step, kept across ``learn``s.

:class:`SafetyTrackingMixin` holds the two things every constrained algorithm of the package keeps beside SB3's own
state: ``safety_metrics`` (:class:`~sppo_sb3.common.safety.SafetyMetrics`, the figures of the paper's Tables I-II,
logged under ``safety/``) and ``cost_tracker`` (:class:`~sppo_sb3.common.cost_tracker.EpisodeCostTracker`, the
measured episode cost ``J_C`` that a cost limit is compared with). The on-policy loop
(:class:`~sppo_sb3.common.on_policy.SafeOnPolicyMixin`) and SACLag's off-policy one both use it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sppo_sb3.common.cost_tracker import EpisodeCostTracker
from sppo_sb3.common.keys import EPISODE_COST_ESTIMATE_LOG_KEY
from sppo_sb3.common.safety import SafetyMetrics

__all__ = ["SafetyTrackingMixin"]


class SafetyTrackingMixin:
    """Safety metrics and the measured episode cost of an SB3 algorithm. Put it before the SB3 algorithm in the bases.

    The subclass calls :meth:`_init_safety` in its ``__init__`` (after the SB3 base ``__init__``, before
    ``_setup_model``), :meth:`_record_safety` on every env step and :meth:`_record_safety_logs` in its ``dump_logs``.
    Both objects are plain attributes, saved with the model, so a resumed run keeps counting; ``learn`` matches them
    to the number of envs and, when it resets the envs, restarts their running episodes.
    """

    # provided by SB3's BaseAlgorithm
    env: VecEnv | None
    n_envs: int
    logger: Any
    _last_obs: Any
    _vec_normalize_env: VecNormalize | None

    def _init_safety(self, metrics_window: int = 100, cost_window: int = 100) -> None:
        """Create the safety metrics and the episode-cost tracker (kept as they are when a saved model is loaded).

        :param metrics_window: episodes averaged in the logged ``safety/ep_*_mean`` values.
        :param cost_window: finished episodes the tracker keeps for its windowed estimate of ``J_C``.
        """
        n_envs = self.n_envs if getattr(self, "env", None) is not None else 1
        self.safety_metrics = SafetyMetrics(n_envs, window=metrics_window)
        self.cost_tracker = EpisodeCostTracker(n_envs, window=cost_window)

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        env_reset = reset_num_timesteps or self._last_obs is None
        out = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)  # type: ignore[misc]
        assert self.env is not None
        self.safety_metrics.resize(self.env.num_envs)
        self.cost_tracker.resize(self.env.num_envs)
        if env_reset:
            self._on_env_reset()
        return out

    def _on_env_reset(self) -> None:
        """Called when ``learn`` resets the envs: running episodes start over."""
        self.safety_metrics.restart_episodes()
        self.cost_tracker.reset_running()

    def _record_safety(
        self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]], intervened: np.ndarray | None = None
    ) -> np.ndarray:
        """Feed one env step to the safety metrics, with the env's original rewards, and to the cost tracker.

        :param rewards: ``(n_envs,)`` the rewards the VecEnv returned (normalised under ``VecNormalize``).
        :param dones: ``(n_envs,)`` episode ends.
        :param infos: the step's infos.
        :param intervened: interventions besides the shield's ``info["shield_intervened"]`` (CSC's rejected samples).
        :return: the step's costs ``info["cost"]``.
        :raises MissingCostError: when an env does not report ``info["cost"]``.
        """
        if self._vec_normalize_env is not None:
            rewards = self._vec_normalize_env.get_original_reward()
        costs = self.safety_metrics.update_from_infos(rewards, dones, infos, intervened)
        self.cost_tracker.update(costs, dones)
        return costs

    def measured_episode_cost(self) -> float:
        """The measured mean episode cost ``J_C`` the algorithm compares with its limit (logged beside ``safety/``).

        The default is the tracker's estimate over the latest rollout (:meth:`EpisodeCostTracker.estimate`).
        """
        return self.cost_tracker.estimate()

    def _record_safety_logs(self) -> None:
        """Write the ``safety/`` figures and the measured episode cost to the logger (before SB3 dumps it)."""
        self.safety_metrics.record(self.logger)
        self.logger.record(EPISODE_COST_ESTIMATE_LOG_KEY, self.measured_episode_cost())
