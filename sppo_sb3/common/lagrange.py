"""The Lagrange multiplier of the primal-dual baselines (PDO, CSC and SACLag), defined once, and the PID multiplier
SPPO prices its shield's interventions with.

They solve the constrained problem of the paper's Section II-B (the CMDP ``max_π J_R(π)  s.t.  J_C(π) <= d``) on its
Lagrangian ``L(π, λ) = J_R(π) - λ·(J_C(π) - d)``, ``λ >= 0``: a primal (policy) step on the advantage
``(A_R - λ·A_C) / (1 + λ)`` and a projected dual (gradient) step on ``λ`` driven by the measured episode cost ``J_C``
of :class:`~sppo_sb3.common.safety.EpisodeCostTracker`. The paper's baselines PDO [25] and CSC [28]
(Section V-A.3) are this scheme with two different cost advantages ``A_C``; SACLag's primal step is SAC's actor loss
with the penalty ``λ·Q_C``, also scaled by ``1 / (1 + λ)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from sppo_sb3.common.keys import LAGRANGE_MULTIPLIER_LOG_KEY

#: the cost limit ``d`` shared by the constrained baselines PDO, CPO and CSC: on the paper's tasks an episode ends at
#: its first violation, so ``J_C`` is the probability that an episode violates, and ``d = 0.01`` allows one episode
#: in a hundred. It is the limit SAILR's authors gave their PDO and CSC on these two tasks (the SPPO paper states
#: none), and the closest a CMDP comes to the "no violation" that the shielded methods are held to.
DEFAULT_COST_LIMIT = 0.01


def lagrange_update(lagrange_multiplier: float, episode_cost: float, cost_limit: float, lagrange_lr: float) -> float:
    """Projected dual ascent on the Lagrange multiplier: ``λ ← max(0, λ + η_λ·(J_C - d))``.

    ``∂L/∂λ = -(J_C(π) - d)`` for ``L(π, λ) = J_R(π) - λ·(J_C(π) - d)``: the dual problem ``min_λ≥0 max_π L`` moves ``λ``
    up while the measured cost exceeds the limit and down (to 0 at most) while it is below.

    :param lagrange_multiplier: current ``λ >= 0``.
    :param episode_cost: measured mean episode cost ``J_C``.
    :param cost_limit: the limit ``d``.
    :param lagrange_lr: dual step size ``η_λ >= 0``.
    :return: the new ``λ``.
    """
    return max(0.0, lagrange_multiplier + lagrange_lr * (episode_cost - cost_limit))


@dataclass
class PIDLagrangian:
    """A Lagrange multiplier ``λ >= 0`` that a PID controller moves to hold a measured rate at its target (Stooke,
    Achiam & Abbeel 2020, "Responsive Safety in RL by PID Lagrangian Methods"): with the error ``e = rate - target``,
    ``λ = max(0, k_p·e + k_i·I + k_d·Δe)`` and the integral ``I ← max(0, I + e)``. The integral alone is the dual
    ascent of :func:`lagrange_update`; the proportional term answers at once, without the integral's overshoot.

    :param target: the rate to hold (e.g. a share of steps).
    :param kp: proportional gain ``k_p``.
    :param ki: integral gain ``k_i``, per update.
    :param kd: derivative gain ``k_d``.
    """

    target: float
    kp: float = 1.0
    ki: float = 0.01
    kd: float = 0.0
    integral: float = 0.0
    last_error: float = 0.0
    multiplier: float = 0.0

    def __post_init__(self) -> None:
        if min(self.target, self.kp, self.ki, self.kd) < 0:
            raise ValueError(f"A PID Lagrangian needs a target and gains >= 0, got {self}.")

    @classmethod
    def starting_at(cls, target: float, multiplier: float) -> PIDLagrangian:
        """A controller whose ``λ`` starts at ``multiplier`` (its integral set so that ``k_i·I = multiplier``)."""
        pid = cls(target)
        pid.integral, pid.multiplier = multiplier / pid.ki, multiplier
        return pid

    def update(self, rate: float) -> float:
        """One step of the controller on the measured ``rate``; returns the new ``λ``."""
        error = rate - self.target
        self.integral = max(0.0, self.integral + error)
        derivative, self.last_error = error - self.last_error, error
        self.multiplier = max(0.0, self.kp * error + self.ki * self.integral + self.kd * derivative)
        return self.multiplier


def lagrangian_advantage(advantages: np.ndarray, cost_advantages: np.ndarray, lagrange_multiplier: float) -> np.ndarray:
    """The primal step's advantage ``(A_R - λ·A_C) / (1 + λ)``; the ``1 + λ`` keeps its scale as ``λ`` grows."""
    lam = lagrange_multiplier
    return ((advantages - lam * cost_advantages) / (1.0 + lam)).astype(np.float32)


class LagrangianMixin:
    """The multiplier ``λ`` of a primal-dual algorithm: its arguments, its dual step, its logs.

    Put it before :class:`~sppo_sb3.common.safety.SafetyTrackingMixin` (or
    :class:`~sppo_sb3.common.on_policy.SafeOnPolicyMixin`, which is one) in the bases
    (``class PDO(LagrangianMixin, SafeOnPolicyMixin, PPO)``), whose ``measured_episode_cost`` gives the measured
    episode cost ``J_C`` (on-policy: the tracker's estimate over the latest rollout; SACLag: over its recent window),
    and call :meth:`_init_lagrange` first thing in ``__init__``. The state is three plain attributes, saved with the
    model: ``cost_limit`` (``d``), ``lagrange_lr`` (``η_λ``) and ``lagrange_multiplier`` (``λ``).
    """

    cost_limit: float
    lagrange_lr: float
    lagrange_multiplier: float
    measured_episode_cost: Callable[[], float]
    logger: Any

    def _init_lagrange(self, cost_limit: float, lagrange_init: float, lagrange_lr: float) -> None:
        """Check and store the arguments of the multiplier.

        :param cost_limit: the limit ``d >= 0`` on the mean episode cost ``J_C``.
        :param lagrange_init: initial multiplier ``λ_0 >= 0``.
        :param lagrange_lr: dual step size ``η_λ >= 0`` (0 keeps ``λ`` at ``lagrange_init``).
        :raises ValueError: on a negative argument.
        """
        for name, value in (("cost_limit", cost_limit), ("lagrange_init", lagrange_init), ("lagrange_lr", lagrange_lr)):
            if value < 0:
                raise ValueError(f"{name} must be >= 0 (costs and the Lagrange multiplier are non-negative), got {value}.")
        self.cost_limit = cost_limit
        self.lagrange_lr = lagrange_lr
        self.lagrange_multiplier = float(lagrange_init)

    def update_lagrange_multiplier(self) -> float:
        """One dual step (:func:`lagrange_update`) on the measured mean episode cost ``J_C``.

        :return: the new ``λ``.
        """
        episode_cost = self.measured_episode_cost()
        self.lagrange_multiplier = lagrange_update(self.lagrange_multiplier, episode_cost, self.cost_limit, self.lagrange_lr)
        self.logger.record(LAGRANGE_MULTIPLIER_LOG_KEY, self.lagrange_multiplier)
        return self.lagrange_multiplier
