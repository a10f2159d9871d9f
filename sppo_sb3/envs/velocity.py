"""Safety-Gymnasium's velocity tasks (``Safety<Robot>Velocity-v1``) on gymnasium 1.x, as ``sppo_sb3/...`` envs.

Safety-Gymnasium (PKU-Alignment/safety-gymnasium) does not import on gymnasium 1.x, but its velocity tasks are thin
definitions on gymnasium's MuJoCo ``<Robot>-v4`` envs, which gymnasium 1.x still ships. This module restates them
(``safety_gymnasium/tasks/safe_velocity/safety_*_velocity_v{0,1}.py``, registered in ``safety_gymnasium/__init__.py``):

- the robot is gymnasium's ``<Robot>-v4`` env with its default constructor arguments (Safety-Gymnasium registers the
  tasks without ``kwargs``), so the observation, reward and termination are that env's;
- the velocity of a step is the one the v4 env computes for its forward reward: ``Δx / dt`` over the frame skip, of
  ``data.qpos[0]`` (HalfCheetah, Hopper, Walker2d, Swimmer), of the ``torso`` body's ``xpos`` (Ant) or of the
  mass-weighted centre of ``data.xipos`` (Humanoid), read before and after ``do_simulation``; the velocity compared
  with the threshold is the planar speed ``sqrt(vx² + vy²)`` for Ant and Humanoid and the signed x velocity for the
  others (v1's Swimmer constrains x only: it oscillates sideways to swim);
- ``info["cost"] = 1.0`` on a step whose velocity exceeds the threshold (strictly), else ``0.0``; a violation does
  not end the episode (a CMDP with a cost limit); the registered TimeLimit truncates after 1000 steps.

The env reads the velocity from the v4 env's own ``info["x_velocity"]`` (and ``info["y_velocity"]``), so the cost is
measured on exactly the positions that the reward is: ``tests/envs/test_velocity_tasks.py`` recomputes it from ``env.data``.

The module holds the physics only; shielding rules belong to :mod:`sppo_sb3.shield`, one per ``task.env_id`` of
:data:`VELOCITY_TASKS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.envs.mujoco.ant_v4 import AntEnv
from gymnasium.envs.mujoco.half_cheetah_v4 import HalfCheetahEnv
from gymnasium.envs.mujoco.hopper_v4 import HopperEnv
from gymnasium.envs.mujoco.humanoid_v4 import HumanoidEnv
from gymnasium.envs.mujoco.swimmer_v4 import SwimmerEnv
from gymnasium.envs.mujoco.walker2d_v4 import Walker2dEnv
from gymnasium.utils import EzPickle

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY, SHAPED_COST_KEY, VELOCITY_KEY

#: the gymnasium namespace of the package's own ids (``gym.make("sppo_sb3/SafetyHopperVelocity-v1")``)
NAMESPACE = "sppo_sb3"
#: Safety-Gymnasium's episode length of every velocity task (the TimeLimit of the registration)
MAX_EPISODE_STEPS = 1000
#: default shaped-cost band of eq. 18, as a fraction of the task's threshold (see :class:`SafetyVelocityEnv`)
DEFAULT_ALPHA_FRACTION = 0.1


@dataclass(frozen=True)
class VelocityTask:
    """One velocity task: a gymnasium v4 robot and the speed it must not exceed.

    :param robot: gymnasium's name of the robot (``"Hopper"``): the base env is ``Hopper-v4``, the task
        ``sppo_sb3/SafetyHopperVelocity-v1``, its class ``SafetyHopperVelocityEnv`` of this module.
    :param base: gymnasium's v4 env class of the robot.
    :param threshold: the velocity limit of Safety-Gymnasium's v1 task (its ``_velocity_threshold``; 50% of the top
        speed PPO reached after 1e7 steps, per its docs).
    :param planar: the constrained velocity is the speed in the xy plane ``sqrt(vx² + vy²)`` (Ant, Humanoid), not the
        signed x velocity ``vx``.
    :param reward_threshold: the ``reward_threshold`` Safety-Gymnasium registers the task with (``None``: none).
    """

    robot: str
    base: type[MujocoEnv]
    threshold: float
    planar: bool
    reward_threshold: float | None = None

    @property
    def env_id(self) -> str:
        """The task's gymnasium id, ``sppo_sb3/Safety<Robot>Velocity-v1``."""
        return f"{NAMESPACE}/Safety{self.robot}Velocity-v1"

    @property
    def base_id(self) -> str:
        """gymnasium's id of the robot's env, ``<Robot>-v4``."""
        return f"{self.robot}-v4"

    @property
    def entry_point(self) -> str:
        """The entry point the task is registered with."""
        return f"{__name__}:Safety{self.robot}VelocityEnv"

    def velocity(self, info: Mapping[str, Any]) -> float:
        """The constrained velocity of a step, from the ``info`` of the base env's step.

        :param info: the info dict of the v4 env's ``step`` (its ``x_velocity`` and, for planar tasks, ``y_velocity``).
        :return: ``sqrt(vx² + vy²)`` if :attr:`planar`, else ``vx``.
        """
        x_velocity = float(info["x_velocity"])
        if not self.planar:
            return x_velocity
        y_velocity = float(info["y_velocity"])
        return float(np.sqrt(x_velocity**2 + y_velocity**2))  # Safety-Gymnasium's formula, bit for bit


HALF_CHEETAH = VelocityTask("HalfCheetah", HalfCheetahEnv, 3.2096, planar=False, reward_threshold=4800.0)
HOPPER = VelocityTask("Hopper", HopperEnv, 0.7402, planar=False, reward_threshold=3800.0)
WALKER2D = VelocityTask("Walker2d", Walker2dEnv, 2.3415, planar=False)
ANT = VelocityTask("Ant", AntEnv, 2.6222, planar=True, reward_threshold=6000.0)
SWIMMER = VelocityTask("Swimmer", SwimmerEnv, 0.2282, planar=False, reward_threshold=360.0)
HUMANOID = VelocityTask("Humanoid", HumanoidEnv, 1.4149, planar=True)
#: the six tasks, in Safety-Gymnasium's table order; ``task.env_id`` is each one's gymnasium id
VELOCITY_TASKS: tuple[VelocityTask, ...] = (HALF_CHEETAH, HOPPER, WALKER2D, ANT, SWIMMER, HUMANOID)


def velocity_distance_to_unsafe(velocity: np.ndarray | float, threshold: float) -> np.ndarray:
    """Distance to the unsafe set ``{v > threshold}``: ``max(0, threshold - v)``."""
    return np.maximum(0.0, threshold - np.asarray(velocity, dtype=np.float64))


def velocity_is_unsafe(velocity: np.ndarray | float, threshold: float) -> np.ndarray:
    """Whether the velocity exceeds the threshold (strictly, as Safety-Gymnasium's ``float(v > threshold)``)."""
    return np.asarray(velocity, dtype=np.float64) > threshold


class SafetyVelocityEnv(MujocoEnv, EzPickle):
    """A gymnasium v4 robot with Safety-Gymnasium's velocity constraint; each task's class sets :attr:`task`.

    ``step`` is the v4 env's (observation, reward, ``terminated``, info unchanged) plus ``info["cost"]`` (1.0 when the
    step's velocity exceeds :attr:`velocity_threshold`), ``info["shaped_cost"]`` (eq. 18's ``max(0, 1 - dist/α)``
    with ``dist = max(0, threshold - velocity)``: 0 below ``threshold - α``, rising through the band, 1 at and above
    the threshold) and ``info["velocity"]``. A violation does not terminate the episode.

    :param alpha: width of the shaped-cost band of eq. 18, in the velocity's units; ``None``: 10% of the threshold, so
        the shaped cost starts to rise at 90% of the limit. The thresholds span 0.23 (Swimmer) to 3.2 (HalfCheetah),
        so one band in absolute units would be a wide margin on one robot and none on another; a band proportional
        to the limit is the same relative warning on each.
    :param kwargs: keyword arguments of the robot's v4 env (e.g. ``render_mode``); Safety-Gymnasium's v1 tasks use
        its defaults.
    """

    #: the task of the class (set by each robot's subclass)
    task: ClassVar[VelocityTask]

    def __init__(self, alpha: float | None = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        EzPickle.__init__(self, alpha=alpha, **kwargs)
        self.velocity_threshold = self.task.threshold
        self.alpha = DEFAULT_ALPHA_FRACTION * self.velocity_threshold if alpha is None else float(alpha)
        if self.alpha < 0:
            raise ValueError(f"alpha must be >= 0 (eq. 18), got {alpha}")
        if self.model.nlight:
            self.model.light(0).castshadow = False  # as Safety-Gymnasium's renders (no effect on the physics)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:  # type: ignore[override]
        obs, reward, terminated, truncated, info = super().step(action)
        velocity = self.task.velocity(info)
        extra = {
            COST_KEY: float(velocity_is_unsafe(velocity, self.velocity_threshold)),
            SHAPED_COST_KEY: float(shaped_cost(velocity_distance_to_unsafe(velocity, self.velocity_threshold), self.alpha)),
            VELOCITY_KEY: velocity,
        }
        return obs, float(reward), bool(terminated), bool(truncated), {**info, **extra}


class SafetyHalfCheetahVelocityEnv(SafetyVelocityEnv, HalfCheetahEnv):
    """``sppo_sb3/SafetyHalfCheetahVelocity-v1``: ``HalfCheetah-v4``, x velocity of ``qpos[0]`` at most 3.2096.

    Safety-Gymnasium: ``safety_half_cheetah_velocity_v1.py`` (threshold) on ``safety_half_cheetah_velocity_v0.py``.
    The arguments are those of :class:`SafetyVelocityEnv`.
    """

    task = HALF_CHEETAH


class SafetyHopperVelocityEnv(SafetyVelocityEnv, HopperEnv):
    """``sppo_sb3/SafetyHopperVelocity-v1``: ``Hopper-v4``, x velocity of ``qpos[0]`` at most 0.7402.

    Safety-Gymnasium: ``safety_hopper_velocity_v1.py`` (threshold) on ``safety_hopper_velocity_v0.py``.
    The arguments are those of :class:`SafetyVelocityEnv`.
    """

    task = HOPPER


class SafetyWalker2dVelocityEnv(SafetyVelocityEnv, Walker2dEnv):
    """``sppo_sb3/SafetyWalker2dVelocity-v1``: ``Walker2d-v4``, x velocity of ``qpos[0]`` at most 2.3415.

    Safety-Gymnasium: ``safety_walker2d_velocity_v1.py`` (threshold) on ``safety_walker2d_velocity_v0.py``.
    The arguments are those of :class:`SafetyVelocityEnv`.
    """

    task = WALKER2D


class SafetyAntVelocityEnv(SafetyVelocityEnv, AntEnv):
    """``sppo_sb3/SafetyAntVelocity-v1``: ``Ant-v4``, xy speed of the ``torso`` body's ``xpos`` at most 2.6222.

    Safety-Gymnasium: ``safety_ant_velocity_v1.py`` (threshold) on ``safety_ant_velocity_v0.py``; ``Ant-v4``'s
    defaults (``use_contact_forces=False``, ``healthy_z_range=(0.2, 1.0)``), as their registration passes none.
    The arguments are those of :class:`SafetyVelocityEnv`.
    """

    task = ANT


class SafetySwimmerVelocityEnv(SafetyVelocityEnv, SwimmerEnv):
    """``sppo_sb3/SafetySwimmerVelocity-v1``: ``Swimmer-v4``, x velocity of ``qpos[0]`` at most 0.2282.

    Safety-Gymnasium: ``safety_swimmer_velocity_v1.py`` (threshold, and the x velocity instead of v0's xy speed).
    The arguments are those of :class:`SafetyVelocityEnv`.
    """

    task = SWIMMER


class SafetyHumanoidVelocityEnv(SafetyVelocityEnv, HumanoidEnv):
    """``sppo_sb3/SafetyHumanoidVelocity-v1``: ``Humanoid-v4``, xy speed of the centre of mass at most 1.4149.

    Safety-Gymnasium: ``safety_humanoid_velocity_v1.py`` (threshold) on ``safety_humanoid_velocity_v0.py``; the
    centre of mass is ``Humanoid-v4``'s ``mass_center`` (mass-weighted ``data.xipos``).
    The arguments are those of :class:`SafetyVelocityEnv`.
    """

    task = HUMANOID
