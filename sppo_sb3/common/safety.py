"""Safety metrics of the paper's Section V-B (Tables I and II), kept the same way by every algorithm of the package.

Per episode: return, cost sum, violations, shield interventions. Over training: cumulative violations, safety
rate (episodes without a violation / all episodes, in %) and cumulative interventions — the quantities of the
paper's Tables I and II. Logged under ``safety/`` and saved with the model, so a resumed run keeps counting.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.logger import Logger

from sppo_sb3.common.costs import costs_from_infos
from sppo_sb3.common.keys import INTERVENED_KEY, SAFETY_LOG_PREFIX

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

    def update(self, rewards: np.ndarray, costs: np.ndarray, dones: np.ndarray, intervened: np.ndarray | None = None) -> None:
        """Feed one VecEnv step.

        :param rewards: ``(n_envs,)`` rewards of the step.
        :param costs: ``(n_envs,)`` violation indicators ``info["cost"]``.
        :param dones: ``(n_envs,)`` episode ends (termination or truncation).
        :param intervened: ``(n_envs,)`` whether the shield replaced the proposed action.
        """
        violated = np.asarray(costs) > 0
        shielded = np.zeros(self.n_envs, dtype=bool) if intervened is None else np.asarray(intervened, dtype=bool)
        self.steps += self.n_envs
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
    ) -> np.ndarray:
        """Feed one VecEnv step from its ``infos`` (``info["cost"]``, and ``info["shield_intervened"]`` if set).

        :param intervened: ``(n_envs,)`` interventions known besides the infos' (CSC's rejected samples).
        :return: the costs read from the infos.
        """
        costs = costs_from_infos(infos)
        intervened_infos = np.array([bool(info.get(INTERVENED_KEY, False)) for info in infos])
        if intervened is not None:
            intervened_infos |= np.asarray(intervened, dtype=bool)
        self.update(np.asarray(rewards, dtype=np.float64), costs, np.asarray(dones, dtype=bool), intervened_infos)
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
        )
