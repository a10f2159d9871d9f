"""Goal: reach the goal; it then moves elsewhere. Safety-Gymnasium's ``tasks/safe_navigation/goal/``.

Reward: the step's decrease of the xy distance to the goal, plus 1 on reaching it (within its radius 0.3).
Level 0: the goal only, in ±1 m. Level 1: ±1.5 m, 8 hazards and one vase that does not cost. Level 2: ±2 m, 10 hazards
and 10 vases that cost when touched or moved.
"""

from __future__ import annotations

import numpy as np

from sppo_sb3.envs.navigation.layout import Rect
from sppo_sb3.envs.navigation.objects import Goal, Hazards, ObjectGroup, Vases
from sppo_sb3.envs.navigation.robots import Robot
from sppo_sb3.envs.navigation.tasks.base import NavigationTask, goal_distance
from sppo_sb3.envs.navigation.world import World


class GoalTask(NavigationTask):
    """The Goal task (see the module)."""

    name = "Goal"
    #: reward for reaching the goal, and per metre moved towards it
    reward_goal, reward_distance = 1.0, 1.0

    def objects(self, level: int, robot: Robot) -> tuple[Rect, list[ObjectGroup]]:
        goal = Goal(keepout=0.305)
        if level == 0:
            return (-1, -1, 1, 1), [goal]
        if level == 1:
            return (-1.5, -1.5, 1.5, 1.5), [goal, Hazards(num=8, keepout=0.18), Vases(num=1, constrained=False)]
        return (-2, -2, 2, 2), [goal, Hazards(num=10, keepout=0.18), Vases(num=10)]

    def next_goal(self, world: World, rng: np.random.RandomState, layout: dict[str, np.ndarray]) -> None:
        self.sampler.resample_goal(rng, layout)
        world.move_goal(layout["goal"])
        self.last_dist_goal = goal_distance(world)

    def reward(self, world: World) -> float:
        distance = goal_distance(world)
        reward = (self.last_dist_goal - distance) * self.reward_distance
        self.last_dist_goal = distance
        return reward + self.reward_goal * (distance <= self.group("goal").size)

    def goal_achieved(self, world: World) -> bool:
        return goal_distance(world) <= self.group("goal").size
