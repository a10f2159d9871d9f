"""The Point Robot's shielding rule (Section V-A-2): a braking backup and ``Q̄`` rolled out on the known dynamics."""

from __future__ import annotations

import copy
import math
from typing import Any, Literal

import numpy as np

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.envs.point_circle import PointParams, point_distance_to_unsafe, point_is_unsafe, point_step
from sppo_sb3.shield.base import ShieldingRule

PointBackup = Literal["wall", "sailr"]


def braking_distance(speed: float, params: PointParams) -> float:
    """Distance one axis travels from ``speed`` (>= 0) to rest under full braking ``clip(-m·v/dt, -1, 1)``.

    ``n`` steps at force 1 remove ``dt/m`` of speed each, each covering ``v·dt - dt²/(2m)``; the last step, from
    ``v_r <= dt/m``, brakes exactly to rest and covers ``v_r·dt/2``.
    """
    decrement = params.dt / params.mass
    n = max(math.ceil(speed / decrement) - 1, 0)
    rest = speed - n * decrement
    full = n * speed * params.dt - decrement * params.dt * n * (n - 1) / 2 - n * params.dt**2 / (2.0 * params.mass)
    return full + rest * params.dt / 2.0


def check_point_observations(obs: np.ndarray) -> None:
    """Reject a batch that is not the Point Robot's ``(B, 4)`` observations, saying which rule expects what."""
    if obs.ndim != 2 or obs.shape[1] != 4:
        raise ValueError(
            f"PointCircleShieldingRule reads the Point Robot's observations [x, y, vx, vy] (4 values), got a batch of "
            f"shape {obs.shape}. Is it the rule of this env? SafePointCircle-v0 registers it (shield='auto'); for "
            "another task pass its own rule."
        )


class PointCircleShieldingRule(ShieldingRule):
    """A braking backup; ``Q̄(s, a) = Σ_t γ^(t+1) ĉ(s_(t+1))`` along "take ``a``, then the backup" (eq. 18 shaped cost).

    **The backup** (``backup``):

    - ``"wall"`` (default) brakes what the constraint needs and keeps the rest: the ``x`` motion, always (the
      constrained axis: ``|x| <= 2.5``), and the ``y`` motion only where it must: within braking reach of the far
      ``|y|`` limit's band (:attr:`y_zone`), so that it stops outside the band. Running along a wall, the robot keeps
      its speed along it.
    - ``"sailr"``: the paper's and SAILR's backup, braking both axes to a stop (Section V-A-2). It stops the robot on
      every intervention.

    **Q̄.** Every rollout first runs the same fixed number of steps, enough to stop the ``x`` motion from full speed;
    from then on ``x`` stays put and, where the ``y`` motion cannot reach the ``y`` band any more, ``ĉ`` is constant,
    so the rest of the sum is the geometric tail ``γ^(H+1) ĉ / (1 - γ)``. The few rolls that are not settled there
    (in :attr:`y_zone`, where the backup brakes ``y`` to rest) run on until they are, at most another :attr:`horizon`
    steps. Entering the unsafe set is absorbing (``ĉ = 1`` forever:
    ``γ^(t+1) / (1 - γ)``). Two rollouts whose shaped costs agree step by step are summed in the same order, so their
    ``Q̄`` agree to the last bit.

    :param params: the task constants (must match the env).
    :param alpha: shaped-cost band width of eq. 18 (paper: 0.5): the margin from the wall that the shield keeps, and
        that a policy learned under it keeps when deployed without it.
    :param gamma: discount of ``Q̄`` (paper: 0.99).
    :param eta: advantage threshold (paper: 0).
    :param backup: ``"wall"`` (brake ``x``, and ``y`` near its limit) or ``"sailr"`` (the paper's: brake both axes).
    """

    def __init__(
        self,
        params: PointParams | None = None,
        alpha: float = 0.05,
        gamma: float = 0.99,
        eta: float = 0.0,
        backup: PointBackup = "wall",
    ) -> None:
        super().__init__(eta=eta)
        if backup not in ("wall", "sailr"):
            raise ValueError(f"backup must be 'wall' (brake x, and y near its limit) or 'sailr' (brake both), got {backup!r}.")
        self.params = params or PointParams()
        self.alpha = alpha
        self.gamma = gamma
        self.backup = backup
        # braking removes dt/m of speed per step on each axis: this many steps stop the robot from any speed
        self.horizon = math.ceil(self.params.max_speed * self.params.mass / self.params.dt) + 2
        # the wall backup brakes y beyond this |y|: entering at full speed, it stops a step's travel short of the band
        step = self.params.max_speed * self.params.dt
        self.y_zone = self.params.y_limit - alpha - braking_distance(self.params.max_speed, self.params) - 2.0 * step

    def band_free(self) -> PointCircleShieldingRule:
        """This rule with ``α = 0`` and the same backup: its ``Q̄`` is positive exactly where "``a``, then ``ζ``" enters
        the unsafe set (:func:`~sppo_sb3.shield.analysis.quality.violation_labels`)."""
        twin = copy.copy(self)
        twin.alpha = 0.0  # y_zone stays: the backup is this rule's
        return twin

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """Braking force ``clip(-m·v/dt, -1, 1)`` (exactly to rest once the speed is small), on the axes it brakes."""
        check_point_observations(obs)
        return self._brake(obs)

    def _brake(self, state: np.ndarray) -> np.ndarray:
        """The backup on checked ``(B, 4)`` states: the rollouts call it on every step."""
        brake = np.clip(-self.params.mass * state[:, 2:4] / self.params.dt, -1.0, 1.0)
        if self.backup == "wall":
            brake[:, 1] *= self._must_brake_y(state)
        return brake

    def _must_brake_y(self, state: np.ndarray) -> np.ndarray:
        """Whether the robot is inside :attr:`y_zone`, within braking reach of the ``y`` band."""
        return np.abs(state[:, 1]) >= self.y_zone

    def _settled(self, state: np.ndarray) -> np.ndarray:
        """Rows whose ``ĉ`` stays what it is under the backup: ``x`` at rest, and ``y`` at rest or out of its zone."""
        at_rest = np.abs(state[:, 2:4]) < 1e-9
        return at_rest[:, 0] & (at_rest[:, 1] | (np.abs(state[:, 1]) < self.y_zone))

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` by rolling "take ``a``, then the backup" through the known dynamics, batched over ``obs``."""
        check_point_observations(obs)
        state = point_step(obs[:, :4].astype(np.float64), np.clip(actions, -1.0, 1.0), self.params)
        q = np.zeros(len(obs))
        running = np.ones(len(obs), dtype=bool)  # not yet absorbed in the unsafe set
        for t in range(self.horizon):
            q += running * self._step_cost(state, t)
            running &= ~point_is_unsafe(state, self.params)
            state = point_step(state, self._brake(state), self.params)
        # x has stopped; a settled row's ĉ stays, the rest of its sum is the tail. The others run on, row by row.
        rows = np.flatnonzero(running)
        state = state[rows]
        for t in range(self.horizon, 2 * self.horizon + 1):
            done = self._settled(state) | point_is_unsafe(state, self.params)
            q[rows[done]] += self._step_cost(state[done], t, tail=True)
            rows, state = rows[~done], state[~done]
            if len(rows) == 0:
                return q
            q[rows] += self._step_cost(state, t)
            state = point_step(state, self._brake(state), self.params)
        q[rows] = np.nan  # not settled (no valid state gets here): fail closed
        return q

    def _step_cost(self, state: np.ndarray, t: int, tail: bool = False) -> np.ndarray:
        """``γ^(t+1) ĉ(s_(t+1))``, or with ``tail`` the sum of it over all steps from ``t`` on; unsafe is absorbing."""
        cost = shaped_cost(point_distance_to_unsafe(state, self.params), self.alpha)
        forever = 1.0 / (1.0 - self.gamma)
        return self.gamma ** (t + 1) * np.where(point_is_unsafe(state, self.params), forever, cost * forever if tail else cost)


def paper_point_rule(**kwargs: Any) -> PointCircleShieldingRule:
    """The paper's and SAILR's Point rule (Section V-A-2): both axes braked, band ``alpha = 0.5``; ``kwargs`` override."""
    return PointCircleShieldingRule(**{"alpha": 0.5, "backup": "sailr", **kwargs})
