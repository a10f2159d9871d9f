"""Button: press the goal button among four; a new one is chosen then. Safety-Gymnasium's ``…/button/``.

Reward: the step's decrease of the xy distance to the goal button, plus 1 on touching it. After a press the buttons
are neither seen (their lidar reads 0) nor constrained for 10 steps. Level 0: the buttons only, in ±1 m, pressing a
wrong one is free. Level 1: ±1.5 m, 4 hazards and 4 gremlins, and pressing a wrong button costs. Level 2: ±1.8 m,
8 hazards and 6 gremlins.
"""

from __future__ import annotations

import numpy as np

from sppo_sb3.envs.navigation.layout import Rect
from sppo_sb3.envs.navigation.objects import Buttons, Goal, Gremlins, Hazards, ObjectGroup
from sppo_sb3.envs.navigation.robots import Robot
from sppo_sb3.envs.navigation.tasks.base import NavigationTask, goal_distance
from sppo_sb3.envs.navigation.world import World


class ButtonTask(NavigationTask):
    """The Button task (see the module)."""

    name = "Button"
    reward_goal, reward_distance = 1.0, 1.0

    def __init__(self, level: int, robot: Robot) -> None:
        super().__init__(level, robot)
        self.goal_button = 0
        self.timer = 0

    def objects(self, level: int, robot: Robot) -> tuple[Rect, list[ObjectGroup]]:
        buttons, goal = Buttons(num=4, constrained=level > 0), Goal(size=0.2)
        if level == 0:
            return (-1, -1, 1, 1), [buttons, goal]
        hazards, gremlins = (4, 4) if level == 1 else (8, 6)
        extents: Rect = (-1.5, -1.5, 1.5, 1.5) if level == 1 else (-1.8, -1.8, 1.8, 1.8)
        return extents, [buttons, goal, Hazards(num=hazards, keepout=0.18), Gremlins(num=gremlins, travel=0.35, keepout=0.4)]

    def next_goal(self, world: World, rng: np.random.RandomState, layout: dict[str, np.ndarray]) -> None:
        buttons = self.group("buttons")
        self.goal_button = int(rng.choice(len(buttons.names)))
        world.move_goal(world.body_xpos((buttons.names[self.goal_button],))[0, :2])
        self.last_dist_goal = goal_distance(world)
        self.timer = Buttons.resampling_delay

    def after_reset(self) -> None:
        self.timer = 0

    def reward(self, world: World) -> float:
        distance = goal_distance(world)
        reward = (self.last_dist_goal - distance) * self.reward_distance
        self.last_dist_goal = distance
        return reward + self.reward_goal * self.goal_achieved(world)

    def goal_achieved(self, world: World) -> bool:
        return world.agent_contacts(f"button{self.goal_button}", exact=True) > 0

    def tick(self) -> None:
        self.timer = max(0, self.timer - 1)

    def constrained_goal_button(self) -> int | None:
        return self.goal_button if self.timer == 0 else None

    def observes(self, group: ObjectGroup) -> bool:
        return group.name != "buttons" or self.timer == 0

    def state(self) -> dict[str, float]:
        return {**super().state(), "goal_button": self.goal_button, "timer": self.timer}
