"""Push: push the box to the goal; the goal then moves elsewhere. Safety-Gymnasium's ``…/push/``.

Reward: the step's decrease of the distance from the robot to the box, plus that of the box to the goal (both in 3-D
between body origins), plus 1 when the box is within the goal's radius 0.3. The Car pushes a smaller, lighter box.
Level 0: goal and box in ±1 m. Level 1: ±1.5 m, 2 hazards of radius 0.3 and a pillar that does not cost. Level 2: ±2 m,
4 hazards and 4 pillars that cost when touched.
"""

from __future__ import annotations

import numpy as np

from sppo_sb3.envs.navigation.layout import Rect
from sppo_sb3.envs.navigation.objects import Goal, Hazards, ObjectGroup, Pillars, PushBox
from sppo_sb3.envs.navigation.robots import Robot
from sppo_sb3.envs.navigation.tasks.base import NavigationTask, goal_distance
from sppo_sb3.envs.navigation.world import World


class PushTask(NavigationTask):
    """The Push task (see the module)."""

    name = "Push"
    reward_goal, reward_box_dist, reward_box_goal = 1.0, 1.0, 1.0
    #: within this many box sizes of the box, moving towards it earns nothing (0: always earns)
    null_dist = 0.0

    def __init__(self, level: int, robot: Robot) -> None:
        super().__init__(level, robot)
        self.last_dist_box = 0.0
        self.last_box_goal = 0.0

    def objects(self, level: int, robot: Robot) -> tuple[Rect, list[ObjectGroup]]:
        size, keepout, density = robot.push_box
        goal, box = Goal(), PushBox(size=size, keepout=keepout, density=density)
        if level == 0:
            return (-1, -1, 1, 1), [goal, box]
        if level == 1:
            return (-1.5, -1.5, 1.5, 1.5), [goal, Hazards(num=2, size=0.3), Pillars(num=1, constrained=False), box]
        return (-2, -2, 2, 2), [goal, Hazards(num=4, size=0.3), Pillars(num=4), box]

    def next_goal(self, world: World, rng: np.random.RandomState, layout: dict[str, np.ndarray]) -> None:
        self.sampler.resample_goal(rng, layout)
        world.move_goal(layout["goal"])
        self.last_dist_goal = goal_distance(world)
        self.last_dist_box = self.box_distance(world)
        self.last_box_goal = self.box_goal_distance(world)

    def reward(self, world: World) -> float:
        dist_box = self.box_distance(world)
        gate = self.last_dist_box > self.null_dist * self.group("push_box").size
        reward = (self.last_dist_box - dist_box) * self.reward_box_dist * gate
        self.last_dist_box = dist_box
        box_goal = self.box_goal_distance(world)
        reward += (self.last_box_goal - box_goal) * self.reward_box_goal
        self.last_box_goal = box_goal
        return reward + self.reward_goal * self.goal_achieved(world)

    def goal_achieved(self, world: World) -> bool:
        return self.box_goal_distance(world) <= self.group("goal").size

    @staticmethod
    def box_distance(world: World) -> float:
        """The 3-D distance from the robot body to the box."""
        return float(np.sqrt(np.sum(np.square(world.body_xpos(("push_box",))[0] - world.agent_xpos()))))

    @staticmethod
    def box_goal_distance(world: World) -> float:
        """The 3-D distance from the box to the goal's body."""
        box, goal = world.body_xpos(("push_box", "goal"))
        return float(np.sqrt(np.sum(np.square(box - goal))))

    def state(self) -> dict[str, float]:
        return {**super().state(), "last_dist_box": self.last_dist_box, "last_box_goal": self.last_box_goal}
