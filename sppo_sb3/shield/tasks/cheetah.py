"""The Half-Cheetah's shielding rule (Section V-A-2): the general MuJoCo rule on the front thigh's height.

The height is read per physics step by a ``framepos`` sensor added to the model on the body frame
(``objtype="xbody"``, i.e. ``data.xpos``, the quantity of the env; ``"body"`` would measure the inertial frame
``data.xipos``). Everything else, the MPPI backup, ``Q̄`` and the certificates, is
:class:`~sppo_sb3.shield.mujoco.rule.MujocoShieldingRule`'s.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from sppo_sb3.envs.half_cheetah_height import HEIGHT_BODY, height_distance_to_unsafe, height_is_unsafe
from sppo_sb3.shield.mujoco.model import ConstraintSteps, StateConstraint
from sppo_sb3.shield.mujoco.rule import MujocoShieldingRule

ENV_ID = "SafeHalfCheetahHeight-v1"


class FthighHeightConstraint(StateConstraint):
    """Unsafe iff the z of ``fthigh``'s body frame origin leaves ``[0.4, 1.0]``; distance ``min(h - 0.4, 1.0 - h)``."""

    uses_states = False

    def add_sensors(self, spec: mujoco.MjSpec) -> None:
        spec.add_sensor(
            name="fthigh_frame", type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_XBODY, objname=HEIGHT_BODY
        )

    def height(self, steps: ConstraintSteps) -> np.ndarray:
        """``(..., T)`` heights after each step: the z of the framepos sensor, added last."""
        return steps.sensors_after[..., -1]

    def is_unsafe(self, steps: ConstraintSteps) -> np.ndarray:
        return height_is_unsafe(self.height(steps))

    def distance(self, steps: ConstraintSteps) -> np.ndarray:
        return height_distance_to_unsafe(self.height(steps))


class HalfCheetahHeightShieldingRule(MujocoShieldingRule):
    """SAILR's MPC intervention on ``SafeHalfCheetahHeight-v1``: :class:`MujocoShieldingRule` with
    :class:`FthighHeightConstraint`, SAILR's MPPI settings (64 particles, ``λ = 0.2``, ``H = 15``) and the paper's
    ``α = 0.05``, ``η = 0.2``.

    :param alpha: shaped-cost band width of eq. 18 (paper: 0.05).
    :param eta: advantage threshold (paper: 0.2).
    :param kwargs: the other settings of :class:`MujocoShieldingRule`.
    """

    def __init__(self, alpha: float = 0.05, eta: float = 0.2, **kwargs: Any) -> None:
        super().__init__(ENV_ID, FthighHeightConstraint(), alpha=alpha, eta=eta, **kwargs)

    def rollout_heights(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """``(M, T)`` front-thigh heights after each env step of open-loop rollouts (one :mod:`mujoco.rollout` call)."""
        return FthighHeightConstraint().height(self.rollout_steps(states, controls))


def rollout_heights_python(
    model: mujoco.MjModel, data: mujoco.MjData, states: np.ndarray, controls: np.ndarray, frame_skip: int = 5
) -> np.ndarray:
    """Reference implementation of :meth:`HalfCheetahHeightShieldingRule.rollout_heights`: a Python ``mj_step`` loop.

    :param states: ``(M, nstate)`` full physics states.
    :param controls: ``(M, T, nu)`` controls, one per env step.
    :return: ``(M, T)`` front-thigh heights (body frame) after each env step.
    """
    body = model.body(HEIGHT_BODY).id
    heights = np.empty(controls.shape[:2])
    for i in range(len(states)):
        mujoco.mj_setState(model, data, states[i], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        data.qacc_warmstart[:] = 0.0  # as the native rollouts' initial warm start
        for t in range(controls.shape[1]):
            data.ctrl[:] = controls[i, t]
            mujoco.mj_step(model, data, nstep=frame_skip)
            mujoco.mj_kinematics(model, data)
            heights[i, t] = data.xpos[body, 2]
    return heights
