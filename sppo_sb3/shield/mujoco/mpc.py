"""What the MPC of :class:`~sppo_sb3.shield.mujoco.rule.MujocoShieldingRule` passes around: its controls per physics step,
its solutions, one shielded step, and the solves it counts."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


def physics_controls(controls: np.ndarray, frame_skip: int) -> np.ndarray:
    """Per-env-step controls ``(M, T, nu)`` → per-physics-step ``(M, T·frame_skip + 1, nu)`` (last step repeated)."""
    ctrl = np.repeat(controls, frame_skip, axis=1)
    return np.ascontiguousarray(np.concatenate([ctrl, ctrl[:, -1:]], axis=1))


class MPCSolution(NamedTuple):
    """An MPC solve per state: ``(M, L, nu)`` plans, ``(M,)`` their costs ``J``, whether each plan is a particle, and
    ``(M, N)`` the ``J`` of every particle."""

    plans: np.ndarray
    costs: np.ndarray
    is_particle: np.ndarray
    scores: np.ndarray


class ShieldStep(NamedTuple):
    """One shielded step per state: the actions executed where the proposal is rejected (the backup's, or an accepted
    edit), the decisions, the advantages, the plans to follow after the executed actions ``(M, H - 1, nu)``, how many
    states solved ``Q̄(s, a)``, ``ζ(s)`` and ``Q̄(s, ζ(s))``, and where the executed action is an edit."""

    backup: np.ndarray
    intervened: np.ndarray
    advantage: np.ndarray
    tails: np.ndarray
    q_solves: int
    backup_solves: int
    backup_value_solves: int
    edited: np.ndarray


@dataclass
class SolveCounts:
    """What :meth:`MujocoShieldingRule.shield` computed, summed over its calls.

    :param steps: env steps shielded (rows of the calls).
    :param q_solves: steps that solved ``Q̄(s, a)`` (the warm plan did not certify ``(s, a) ∉ I``).
    :param backup_solves: steps that also solved ``ζ(s)`` (``Q̄(s, a) > η``).
    :param backup_value_solves: steps that also solved ``Q̄(s, ζ(s))`` (its bounds left the decision open).
    """

    steps: int = 0
    q_solves: int = 0
    backup_solves: int = 0
    backup_value_solves: int = 0
