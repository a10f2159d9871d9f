"""The robots of the navigation tasks, by the name in ``Safety<Robot><Task><Level>-v0``."""

from sppo_sb3.envs.navigation.robots.base import Robot
from sppo_sb3.envs.navigation.robots.car import CAR
from sppo_sb3.envs.navigation.robots.point import POINT

#: every robot, by its name
ROBOTS: dict[str, Robot] = {robot.name: robot for robot in (POINT, CAR)}

__all__ = ["CAR", "POINT", "ROBOTS", "Robot"]
