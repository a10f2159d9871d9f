"""Circle: run along the circle of radius 1.5 about the origin, for 500 steps. Safety-Gymnasium's ``…/circle/``.

Reward: ``0.1 · ((−u·y + v·x) / r) / (1 + |r − 1.5|)``, the robot's angular speed about the origin (from its position
``(x, y)``, ``r = √(x² + y²)``, and its velocity ``(u, v)``), discounted by its distance from the circle. The robot
starts in ±0.8 m; the lidar reaches 6 m. Level 0: no constraint. Level 1: ``|x| > 1.125`` costs (two walls).
Level 2: ``|y| > 1.125`` costs too (four walls).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from sppo_sb3.envs.navigation.layout import Rect
from sppo_sb3.envs.navigation.objects import CircleZone, ObjectGroup, Sigwalls
from sppo_sb3.envs.navigation.robots import Robot
from sppo_sb3.envs.navigation.tasks.base import NavigationTask
from sppo_sb3.envs.navigation.world import World


class CircleTask(NavigationTask):
    """The Circle task (see the module)."""

    name = "Circle"
    episode_steps = 500
    lidar_max_dist = 6.0
    agent_rects: ClassVar[tuple[Rect, ...] | None] = ((-0.8, -0.8, 0.8, 0.8),)
    agent_keepout: ClassVar[float | None] = 0.0
    reward_factor = 0.1

    def objects(self, level: int, robot: Robot) -> tuple[Rect, list[ObjectGroup]]:
        circle: list[ObjectGroup] = [CircleZone()]
        return (-2, -2, 2, 2), circle if level == 0 else [*circle, Sigwalls(num=2 * level)]

    def reward(self, world: World) -> float:
        x, y, _ = world.agent_xpos()
        u, v, _ = world.agent_velocity()
        radius = np.sqrt(x**2 + y**2)
        along = (-u * y + v * x) / radius
        return float(along / (1 + np.abs(radius - self.group("circle").size)) * self.reward_factor)
