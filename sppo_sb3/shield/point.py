"""The Point Robot's shielding rule (Section V-A-2): a braking backup and ``Q̄`` rolled out on the known dynamics."""

from __future__ import annotations

import math

import numpy as np

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.envs.point_circle import PointParams, point_distance_to_unsafe, point_is_unsafe, point_step
from sppo_sb3.shield.base import ShieldingRule


class PointCircleShieldingRule(ShieldingRule):
    """Brake to a stop; ``Q̄(s, a) = Σ_t γ^(t+1) ĉ(s_(t+1))`` along "take ``a``, then brake" (eq. 18 shaped cost).

    Every rollout runs the same fixed number of steps, enough to stop from full speed; once at rest the robot stays
    there under the backup, so the rest of the sum is the geometric tail ``γ^(H+1) ĉ / (1 - γ)``. Entering the unsafe
    set is absorbing (``ĉ = 1`` forever: ``γ^(t+1) / (1 - γ)``). Two rollouts whose shaped costs agree step by step
    (a proposal that moves ``x`` as braking does) are summed in the same order, so their ``Q̄`` are equal to the last
    bit and ``Ā = 0`` exactly: rounding never shields an action (eq. 12 tests ``Ā > η`` with ``η = 0``).

    :param params: the task constants (must match the env).
    :param alpha: shaped-cost band width of eq. 18 (paper: 0.5).
    :param gamma: discount of ``Q̄`` (paper: 0.99).
    :param eta: advantage threshold (paper: 0).
    :param penalty: absorbing reward ``R̃``.
    """

    def __init__(
        self,
        params: PointParams | None = None,
        alpha: float = 0.5,
        gamma: float = 0.99,
        eta: float = 0.0,
        penalty: float = -1.0,
    ) -> None:
        super().__init__(eta=eta, penalty=penalty)
        self.params = params or PointParams()
        self.alpha = alpha
        self.gamma = gamma
        # braking removes dt/m of speed per step on each axis: this many steps stop the robot from any speed
        self.horizon = math.ceil(self.params.max_speed * self.params.mass / self.params.dt) + 2

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """Braking force ``clip(-m·v/dt, -1, 1)``: brings the velocity exactly to zero once it is small enough."""
        return np.clip(-self.params.mass * obs[:, 2:4] / self.params.dt, -1.0, 1.0)

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` by rolling "take ``a``, then brake" through the known dynamics, batched over ``obs``."""
        state = point_step(obs[:, :4].astype(np.float64), np.clip(actions, -1.0, 1.0), self.params)
        q = np.zeros(len(obs))
        running = np.ones(len(obs), dtype=bool)  # not yet absorbed in the unsafe set
        tail = 1.0 / (1.0 - self.gamma)
        for t in range(self.horizon + 1):
            discount = self.gamma ** (t + 1)
            cost = shaped_cost(point_distance_to_unsafe(state, self.params), self.alpha)
            unsafe = point_is_unsafe(state, self.params)
            at_rest_tail = t == self.horizon  # stopped by now: ĉ stays, the rest of the sum is its tail
            q += running * discount * np.where(unsafe, tail, cost * tail if at_rest_tail else cost)
            running &= ~unsafe
            state = point_step(state, self.backup_action(state), self.params)
        return q
