"""Closed-loop replay of a recorded costly episode (:mod:`sppo_sb3.shield.records`): does the rule now hold?"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from sppo_sb3.common.keys import COST_KEY, EXECUTED_ACTION_KEY
from sppo_sb3.shield.records import CostlyEpisode, restore_randomness
from sppo_sb3.shield.wrapper import ShieldWrapper


@dataclass
class Replay:
    """What :func:`replay` found: the recorded and the replayed costly env steps, and the first step where the replay's
    executed action differs from the record's (``None``: none, the episode repeated step for step)."""

    recorded_costly: list[int]
    replayed_costly: list[int]
    first_divergence: int | None
    steps: int

    @property
    def holds(self) -> bool:
        """The rule replayed paid no cost on the recorded proposals."""
        return not self.replayed_costly

    def summary(self) -> str:
        same = "step for step" if self.first_divergence is None else f"until env step {self.first_divergence}"
        verdict = "the rule now holds" if self.holds else f"{len(self.replayed_costly)} costly env steps"
        return (
            f"recorded: {len(self.recorded_costly)} costly env steps (first at {self.recorded_costly[:1]}); replayed "
            f"{self.steps} env steps closed loop, executed as recorded {same}: {verdict}"
        )


def replay(record: CostlyEpisode, rule: Any = None, tolerance: float = 1e-9) -> Replay:
    """Replay ``record`` closed loop: its proposals, one per env step, through a fresh ``ShieldWrapper``.

    :param record: a :class:`CostlyEpisode`.
    :param rule: the rule to replay with (a :class:`~sppo_sb3.shield.ShieldingRule` or a registered name); ``None``: the
        recorded one, by its registered name.
    :param tolerance: how far an executed action may be from the record's and still count as the same.
    """
    rule = record.rule if rule is None else rule
    if rule is None:
        raise ValueError(
            f"The record's rule was an object ({record.rule_class}), not a registered name: pass the rule to replay with "
            "(replay(record, rule=...); scripts/replay_costly.py --rule NAME)."
        )
    env = gym.make(record.env_id, **record.env_kwargs)
    shielded = ShieldWrapper(env, rule)
    seed = restore_randomness(env, record.log.randomness)
    shielded.reset(seed=seed)
    replayed, divergence = [], None
    for t, proposal in enumerate(record.log.proposed):
        _, _, terminated, truncated, info = shielded.step(np.asarray(proposal).reshape(env.action_space.shape))
        executed = np.asarray(info[EXECUTED_ACTION_KEY], dtype=np.float64).ravel()
        if divergence is None and np.max(np.abs(executed - record.log.executed[t])) > tolerance:
            divergence = t
        if float(info.get(COST_KEY, 0.0)) > 0:
            replayed.append(t)
        if terminated or truncated:
            break
    env.close()
    return Replay(record.costly_steps, replayed, divergence, t + 1)
