"""Safety bookkeeping, kept the same way by every algorithm of the package.

- :class:`SafetyMetrics`: the figures of the paper's Section V-B (Tables I and II). Per episode: return, cost sum,
  violations, shield interventions. Over training: cumulative violations, safety rate (episodes without a violation
  / all episodes, in %) and cumulative interventions. Logged under ``safety/``.
- :class:`EpisodeCostTracker`: the measured episode cost ``J_C`` that the constrained algorithms compare with their
  cost limit ``d``.
- :class:`SafetyTrackingMixin`: both, fed every env step of an SB3 algorithm (on- or off-policy) and saved with the
  model, so a resumed run keeps counting.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sppo_sb3.common.costs import costly_steps, costs_from_infos, edit_count, intervention_count
from sppo_sb3.common.keys import ENV_STEPS_KEY, EPISODE_COST_ESTIMATE_LOG_KEY, SAFETY_LOG_PREFIX

#: the final summary also gives the mean return of this many last episodes: where a short run has got to
FINAL_EPISODES = 5


class SafetyMetrics:
    """Accumulates per-episode and cumulative safety figures over a VecEnv's steps.

    :param n_envs: number of parallel envs whose steps are fed to :meth:`update`.
    :param window: number of recent episodes averaged in the logged ``safety/ep_*_mean`` values.
    """

    def __init__(self, n_envs: int, window: int = 100) -> None:
        self.episodes = 0
        self.unsafe_episodes = 0
        self.violations = 0
        self.interventions = 0
        self.edits = 0  # interventions whose replacement was a permissive shield's edit, not the backup's action
        self.steps = 0
        self.recent: deque[dict[str, float]] = deque(maxlen=window)
        self.n_envs = n_envs
        self.restart_episodes()

    def restart_episodes(self, n_envs: int | None = None) -> None:
        """Drop the running episodes' partial sums (the envs were reset), optionally for a new number of envs.

        Cumulative counts and the finished episodes are kept.
        """
        self.n_envs = n_envs or self.n_envs
        self._ep_return = np.zeros(self.n_envs)
        self._ep_cost = np.zeros(self.n_envs)
        self._ep_violations = np.zeros(self.n_envs, dtype=np.int64)
        self._ep_interventions = np.zeros(self.n_envs, dtype=np.int64)

    def resize(self, n_envs: int) -> None:
        """Match a new number of envs (their running episodes start over; cumulative counts are kept)."""
        if n_envs != self.n_envs:
            self.restart_episodes(n_envs)

    def update(
        self,
        rewards: np.ndarray,
        costs: np.ndarray,
        dones: np.ndarray,
        intervened: np.ndarray | None = None,
        violations: np.ndarray | None = None,
        env_steps: np.ndarray | None = None,
    ) -> None:
        """Feed one VecEnv step.

        :param rewards: ``(n_envs,)`` rewards of the step.
        :param costs: ``(n_envs,)`` violation indicators ``info["cost"]`` (under an action repeat, their sums).
        :param dones: ``(n_envs,)`` episode ends (termination or truncation).
        :param intervened: ``(n_envs,)`` whether the shield replaced the proposed action, or on how many env steps
            (under an action repeat).
        :param violations: ``(n_envs,)`` env steps with a cost (``None``: ``costs > 0``, one env step per VecEnv step).
        :param env_steps: ``(n_envs,)`` env steps the VecEnv step ran (``None``: one each).
        """
        violated = (np.asarray(costs) > 0).astype(np.int64) if violations is None else np.asarray(violations, np.int64)
        shielded = np.zeros(self.n_envs, dtype=np.int64) if intervened is None else np.asarray(intervened, np.int64)
        self.steps += self.n_envs if env_steps is None else int(np.sum(env_steps))
        self.violations += int(violated.sum())
        self.interventions += int(shielded.sum())
        self._ep_return += rewards
        self._ep_cost += costs
        self._ep_violations += violated
        self._ep_interventions += shielded
        for env_idx in np.flatnonzero(dones):
            self._close_episode(int(env_idx))

    def update_from_infos(
        self,
        rewards: np.ndarray,
        dones: np.ndarray,
        infos: Sequence[dict[str, Any]],
        intervened: np.ndarray | None = None,
        required: bool = True,
    ) -> np.ndarray:
        """Feed one VecEnv step from its ``infos`` (``info["cost"]``, and ``info["shield_intervened"]`` if set).

        :param intervened: ``(n_envs,)`` interventions known besides the infos' (CSC's rejected samples).
        :param required: raise where an env reports no ``info["cost"]``; otherwise count 0 there.
        :return: the costs read from the infos.
        """
        costs = costs_from_infos(infos, required)
        counts = np.array([intervention_count(info) for info in infos], dtype=np.int64)
        if intervened is not None:
            counts = np.maximum(counts, np.asarray(intervened, dtype=np.int64))
        violations = np.array([costly_steps(info) for info in infos])
        env_steps = np.array([int(info.get(ENV_STEPS_KEY, 1)) for info in infos])
        self.edits += sum(edit_count(info) for info in infos)
        self.update(np.asarray(rewards, dtype=np.float64), costs, np.asarray(dones, dtype=bool), counts, violations, env_steps)
        return costs

    def _close_episode(self, env_idx: int) -> None:
        self.episodes += 1
        self.unsafe_episodes += int(self._ep_violations[env_idx] > 0)
        self.recent.append(
            {
                "return": float(self._ep_return[env_idx]),
                "cost": float(self._ep_cost[env_idx]),
                "violations": float(self._ep_violations[env_idx]),
                "interventions": float(self._ep_interventions[env_idx]),
            }
        )
        self._ep_return[env_idx] = self._ep_cost[env_idx] = 0.0
        self._ep_violations[env_idx] = self._ep_interventions[env_idx] = 0

    @property
    def safety_rate(self) -> float:
        """Episodes without a violation / all finished episodes, in % (100 before the first episode ends)."""
        return 100.0 * (self.episodes - self.unsafe_episodes) / self.episodes if self.episodes else 100.0

    def summary(self) -> dict[str, float]:
        """The figures of the paper's Tables I/II, plus the recent mean episode return and cost."""
        out = {
            "episodes": float(self.episodes),
            "cumulative_violations": float(self.violations),
            "safety_rate": self.safety_rate,
            "cumulative_interventions": float(self.interventions),
            "intervention_rate": self.interventions / max(self.steps, 1),
        }
        if self.edits:  # a permissive shield's: of the interventions, the edits (the rest executed the backup's action)
            out["cumulative_edits"] = float(self.edits)
        for key in ("return", "cost", "violations", "interventions"):
            out[f"ep_{key}_mean"] = float(np.mean([ep[key] for ep in self.recent])) if self.recent else float("nan")
        return out

    def record(self, logger: Logger) -> None:
        """Write the summary to an SB3 logger under ``safety/``."""
        for key, value in self.summary().items():
            if not np.isnan(value):
                logger.record(f"{SAFETY_LOG_PREFIX}{key}", value)

    def format_summary(self) -> str:
        """One human-readable line, printed at the end of training."""
        s = self.summary()
        last = list(self.recent)[-FINAL_EPISODES:]
        final = f" (last {len(last)}: {np.mean([ep['return'] for ep in last]):.2f})" if last else ""
        return (
            f"episodes={int(s['episodes'])}  mean return (last {len(self.recent)})={s['ep_return_mean']:.2f}{final}  "
            f"cumulative violations={int(s['cumulative_violations'])}  safety rate={s['safety_rate']:.2f}%  "
            f"shield interventions={int(s['cumulative_interventions'])}"
            + (
                f" (edits {int(s['cumulative_edits'])}, backups {int(s['cumulative_interventions'] - s['cumulative_edits'])})"
                if self.edits
                else ""
            )
        )


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
        self,
        rewards: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
        intervened: np.ndarray | None = None,
        required: bool = True,
    ) -> np.ndarray:
        """Feed one env step to the safety metrics, with the env's original rewards, and to the cost tracker.

        :param rewards: ``(n_envs,)`` the rewards the VecEnv returned (normalised under ``VecNormalize``).
        :param dones: ``(n_envs,)`` episode ends.
        :param infos: the step's infos.
        :param intervened: interventions besides the shield's ``info["shield_intervened"]`` (CSC's rejected samples).
        :param required: raise where an env reports no ``info["cost"]``; otherwise count 0 there (an unshielded SPPO
            on a plain task).
        :return: the step's costs ``info["cost"]``.
        :raises MissingCostError: when ``required`` and an env does not report ``info["cost"]``.
        """
        if self._vec_normalize_env is not None:
            rewards = self._vec_normalize_env.get_original_reward()
        costs = self.safety_metrics.update_from_infos(rewards, dones, infos, intervened, required)
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
