"""The shield's inputs of a real training run: the observations it saw and the actions it was asked to shield, in order.

The benchmarks score shields on these pairs, the state distribution a learner really visits
(``scripts/bench_shield.py``'s replays, ``scripts/learned_shield.py``'s training-run pairs).
"""

from __future__ import annotations

import numpy as np

from sppo_sb3.shield.base import ShieldDecision, ShieldingRule


class RecordingRule(ShieldingRule):
    """A rule that keeps every observation and proposed action it shields, and lets ``rule`` decide.

    :param rule: the rule that decides.
    """

    def __init__(self, rule: ShieldingRule) -> None:
        super().__init__(eta=rule.eta)
        self.rule = rule
        self.gamma = getattr(rule, "gamma", 0.99)
        self.observations: list[np.ndarray] = []
        self.proposals: list[np.ndarray] = []

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return self.rule.cost_value(obs, actions)

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return self.rule.backup_action(obs)

    def shield(self, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        self.observations.append(np.array(obs, dtype=np.float64).reshape(len(obs), -1))
        self.proposals.append(np.array(actions, dtype=np.float64).reshape(len(obs), -1))
        return self.rule.shield(obs, actions)

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(N, obs_dim)`` observations and ``(N, act_dim)`` proposals, in the order shielded."""
        return np.concatenate(self.observations), np.concatenate(self.proposals)
