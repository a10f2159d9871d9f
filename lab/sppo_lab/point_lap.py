"""The Point Robot's return ceiling: a scripted lap (:func:`~sppo_sb3.envs.point_circle.scripted_lap_action`) run with
and without a shield, to measure how much return a shielding rule's conservatism costs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sppo_sb3.envs.point_circle import (
    PointParams,
    point_is_unsafe,
    point_reward,
    point_step,
    scripted_lap_action,
)
from sppo_sb3.shield.base import ShieldingRule

#: the ``|x|`` the scripted laps aim at, from the paper rule's band edge to the wall
LAP_TARGETS = (2.0, 2.2, 2.3, 2.4, 2.45, 2.48)


@dataclass(frozen=True)
class LapResult:
    """One scripted episode.

    :param x_target: the ``|x|`` the lap aimed at.
    :param episode_return: the return over the episode (0-based: ends at the first violation).
    :param interventions: steps on which the shield replaced the lap's action.
    :param max_abs_x: the largest ``|x|`` reached.
    :param violated: whether the episode ended in the unsafe set.
    """

    x_target: float
    episode_return: float
    interventions: int
    max_abs_x: float
    violated: bool


def run_scripted_lap(
    x_target: float, rule: ShieldingRule | None = None, steps: int = 500, params: PointParams | None = None
) -> LapResult:
    """One episode of the scripted lap from the origin at rest, its actions shielded by ``rule`` (``None``: unshielded).

    :param x_target: the ``|x|`` the lap aims at along the walls.
    :param rule: the shielding rule, or ``None``.
    :param steps: the episode length (the task's time limit).
    :param params: the task constants (``None``: the task's defaults).
    """
    params = params or PointParams()
    state, total, interventions, max_abs_x = np.zeros(4), 0.0, 0, 0.0
    for _ in range(steps):
        action = scripted_lap_action(state, x_target, params)
        if rule is not None:
            decision = rule.shield(state[None], action[None])
            interventions += int(decision.intervened[0])
            action = decision.actions[0]
        total += float(point_reward(state, params))
        state = point_step(state, np.clip(action, -1.0, 1.0), params)
        max_abs_x = max(max_abs_x, abs(float(state[0])))
        if point_is_unsafe(state, params):
            return LapResult(x_target, total, interventions, max_abs_x, True)
    return LapResult(x_target, total, interventions, max_abs_x, False)


def lap_ceiling(rule: ShieldingRule | None, targets: Sequence[float] = LAP_TARGETS) -> LapResult:
    """The best safe scripted lap over ``targets``: the return ceiling under ``rule`` (``None``: unshielded)."""
    laps = [run_scripted_lap(target, rule) for target in targets]
    safe = [lap for lap in laps if not lap.violated]
    return max(safe, key=lambda lap: lap.episode_return)
