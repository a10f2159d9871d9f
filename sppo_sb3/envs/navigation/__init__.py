"""Safety-Gymnasium's navigation tasks on gymnasium 1.x: ``sppo_sb3/Safety<Robot><Task><Level>-v0``.

Point and Car robots × Goal, Button, Push and Circle × levels 0, 1 and 2, restated from Safety-Gymnasium 1.0.0
(``safety_gymnasium/tasks/safe_navigation/``, ``bases/``, ``assets/``, ``builder.py``, ``world.py``): the same
observations, rewards, costs, layouts (a seed draws Safety-Gymnasium's layout), episode lengths and goal resampling.
``tests/envs/navigation/`` compares them, step by step, with recorded runs of the original.

A robot is a module of :mod:`.robots`, a task one of :mod:`.tasks`; :mod:`.objects` holds the kinds of object,
:mod:`.layout` the placements, :mod:`.world` the MuJoCo model, :mod:`.lidar` the pseudo-lidar and :mod:`.env` the
gymnasium env.
"""

from __future__ import annotations

from dataclasses import dataclass

from sppo_sb3.envs.navigation.env import SafetyNavigationEnv
from sppo_sb3.envs.navigation.robots import ROBOTS
from sppo_sb3.envs.navigation.tasks import LEVELS, TASKS

#: the gymnasium namespace of the package's own ids
NAMESPACE = "sppo_sb3"


@dataclass(frozen=True)
class NavigationTaskId:
    """One registered navigation task: a robot, a task and a level."""

    robot: str
    task: str
    level: int

    @property
    def env_id(self) -> str:
        """The gymnasium id, ``sppo_sb3/Safety<Robot><Task><Level>-v0``."""
        return f"{NAMESPACE}/Safety{self.robot}{self.task}{self.level}-v0"

    @property
    def episode_steps(self) -> int:
        """The episode length (the registration's TimeLimit)."""
        return TASKS[self.task].episode_steps


#: the 24 tasks, robot by robot, task by task, level by level
NAVIGATION_TASKS: tuple[NavigationTaskId, ...] = tuple(
    NavigationTaskId(robot, task, level) for robot in ROBOTS for task in TASKS for level in LEVELS
)

__all__ = ["NAVIGATION_TASKS", "NavigationTaskId", "SafetyNavigationEnv"]
