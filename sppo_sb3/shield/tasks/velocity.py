"""The velocity constraint of Safety-Gymnasium's velocity tasks, for :class:`~sppo_sb3.shield.mujoco.rule.MujocoShieldingRule`.

A step violates when the robot's velocity over it, ``Δx / dt`` (or the planar speed ``|Δ(x, y)| / dt``), exceeds a
threshold. The velocity depends only on the change of position, so the unobserved ``x`` (and ``y``) that the rule
sets to 0 when it rebuilds the state does not matter.

The constraint measures the displacement between the exact states at the start and the end of the step. Where a
task measures a body's position (Ant's torso) or the centre of mass (Humanoid), gymnasium's envs read ``data.xpos`` /
``data.xipos`` after ``mj_step``, which with their RK4 integrator hold the kinematics of the integrator's last stage,
not of the new state: their velocity differs from the exact one by a small part of one physics step's motion. The
shaped-cost band ``α`` is the margin that covers it (see ``docs/guide/custom_tasks.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from sppo_sb3.envs.velocity import VelocityTask, velocity_distance_to_unsafe, velocity_is_unsafe
from sppo_sb3.shield.mujoco.model import ConstraintSteps, MujocoLayout, StateConstraint
from sppo_sb3.shield.mujoco.rule import MujocoShieldingRule, lookahead_horizon

#: where each velocity task measures its robot, when not at the root's ``qpos``
MEASURED_AT: dict[str, dict[str, Any]] = {"Ant": {"body": "torso"}, "Humanoid": {"mass_centre": True}}


@dataclass(frozen=True)
class VelocityConstraint(StateConstraint):
    """Unsafe iff the step's velocity exceeds ``threshold``; distance ``max(0, threshold - velocity)``.

    :param threshold: the largest safe velocity (m/s).
    :param planar: measure the speed in the ``(x, y)`` plane (Ant, Humanoid) instead of the ``x`` velocity.
    :param body: measure the frame origin of this body (``data.xpos``; Ant: ``"torso"``) instead of the root's position
        ``qpos[0]`` (``qpos[:2]`` when planar).
    :param mass_centre: measure the model's centre of mass (a ``subtreecom`` sensor on the world body: Humanoid's
        ``mass_center``).
    """

    threshold: float
    planar: bool = False
    body: str | None = None
    mass_centre: bool = False

    def __post_init__(self) -> None:
        if not self.threshold > 0:
            raise ValueError(f"The velocity threshold must be > 0, got {self.threshold}.")
        if self.body is not None and self.mass_centre:
            raise ValueError("Measure either a body (body=...) or the centre of mass (mass_centre=True), not both.")

    @property
    def uses_states(self) -> bool:  # type: ignore[override]
        return self.body is None and not self.mass_centre

    def add_sensors(self, spec: mujoco.MjSpec) -> None:
        if self.mass_centre:
            spec.add_sensor(
                name="mass_centre", type=mujoco.mjtSensor.mjSENS_SUBTREECOM, objtype=mujoco.mjtObj.mjOBJ_BODY, objname="world"
            )
        elif self.body is not None:
            if spec.body(self.body) is None:
                raise ValueError(f"VelocityConstraint(body={self.body!r}): the model has no body of that name.")
            spec.add_sensor(
                name=f"{self.body}_frame",
                type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
                objtype=mujoco.mjtObj.mjOBJ_XBODY,
                objname=self.body,
            )

    def positions(self, steps: ConstraintSteps) -> tuple[np.ndarray, np.ndarray]:
        """``(..., T, ·)`` the measured position at the start and at the end of each step."""
        if self.uses_states:
            return steps.qpos(steps.before), steps.qpos(steps.after)
        return steps.sensors_before[..., -3:], steps.sensors_after[..., -3:]

    def velocity(self, steps: ConstraintSteps) -> np.ndarray:
        """``(..., T)`` velocity of each step: ``Δx / dt``, or the planar speed."""
        dims = 2 if self.planar else 1
        before, after = self.positions(steps)
        delta = (after[..., :dims] - before[..., :dims]) / steps.dt
        return np.linalg.norm(delta, axis=-1) if self.planar else delta[..., 0]

    def is_unsafe(self, steps: ConstraintSteps) -> np.ndarray:
        return velocity_is_unsafe(self.velocity(steps), self.threshold)

    def distance(self, steps: ConstraintSteps) -> np.ndarray:
        return velocity_distance_to_unsafe(self.velocity(steps), self.threshold)

    def depth(self, steps: ConstraintSteps) -> np.ndarray:
        return np.maximum(self.velocity(steps) - self.threshold, 0.0)


def velocity_constraint(task: VelocityTask) -> VelocityConstraint:
    """The constraint of a Safety-Gymnasium velocity task (:data:`sppo_sb3.envs.velocity.VELOCITY_TASKS`)."""
    return VelocityConstraint(task.threshold, planar=task.planar, **MEASURED_AT.get(task.robot, {}))


#: the least time ahead the registered velocity rules look (``horizon`` = this many seconds, and at least 15 steps). A
#: Walker2d that starts to fall forward crosses its velocity threshold about 0.2 s later, where 15 of its 8 ms steps
#: (0.12 s) saw it too late for the backup to catch it (docs/guide/tasks.md: "Falls and the velocity shield").
LOOKAHEAD_SECONDS = 0.24


def velocity_shielding_rule(task: VelocityTask, alpha: float, **kwargs: Any) -> MujocoShieldingRule:
    """The registered rule of a velocity task: :class:`MujocoShieldingRule` on the task's own model.

    Its horizon looks :data:`LOOKAHEAD_SECONDS` ahead (:func:`lookahead_horizon`, at least 15 steps): 30 steps on
    Hopper and Walker2d (8 ms steps), 16 on Humanoid, 15 on the others.

    :param task: the task.
    :param alpha: the env's shaped-cost band (its ``alpha``, which the registry passes).
    :param kwargs: further settings of :class:`MujocoShieldingRule` (``eta``, ``horizon``, ...).
    """
    env = gym.make(task.env_id)
    try:
        layout = MujocoLayout.of(env)
        kwargs.setdefault("horizon", lookahead_horizon(float(env.unwrapped.dt), LOOKAHEAD_SECONDS, least=15))  # type: ignore[attr-defined]
    finally:
        env.close()
    return MujocoShieldingRule(layout, velocity_constraint(task), alpha=alpha, **kwargs)
