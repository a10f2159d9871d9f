"""What every navigation task shares: its objects by level, its layout's placements, and the hooks of a step."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from sppo_sb3.envs.navigation.layout import LayoutSampler, Placement, Rect, fixed_location
from sppo_sb3.envs.navigation.objects import ObjectGroup
from sppo_sb3.envs.navigation.robots import Robot
from sppo_sb3.envs.navigation.world import World

#: the levels of every task
LEVELS = (0, 1, 2)


class NavigationTask:
    """A task of Safety-Gymnasium's navigation suite at one level, for one robot; it holds the task's own state.

    A subclass restates one ``tasks/safe_navigation/<task>/<task>_level{0,1,2}.py``: :meth:`objects` (the level's
    extents and object groups, in Safety-Gymnasium's order), the reward of a step, when its goal is achieved, and what
    happens then (:meth:`next_goal`, also run at reset).

    :param level: 0, 1 or 2.
    :param robot: the robot.
    """

    #: the task's name in ``Safety<Robot><Task><Level>-v0``
    name: ClassVar[str]
    #: steps of an episode
    episode_steps: ClassVar[int] = 1000
    #: the pseudo-lidar's range
    lidar_max_dist: ClassVar[float] = 3.0
    #: where the robot may start (``None``: the task's extents) and the radius it keeps free (``None``: the robot's)
    agent_rects: ClassVar[tuple[Rect, ...] | None] = None
    agent_keepout: ClassVar[float | None] = None

    def __init__(self, level: int, robot: Robot) -> None:
        if level not in LEVELS:
            raise ValueError(f"unknown level {level!r} of the {self.name} task: the levels are {', '.join(map(str, LEVELS))}")
        self.level = level
        self.robot = robot
        self.extents, groups = self.objects(level, robot)
        self.groups: tuple[ObjectGroup, ...] = tuple(groups)
        self.sampler = LayoutSampler(self.placements(), self.extents)
        self.last_dist_goal = 0.0

    def objects(self, level: int, robot: Robot) -> tuple[Rect, list[ObjectGroup]]:
        """The level's placement extents and object groups (static kinds first, then free, then mocap)."""
        raise NotImplementedError

    def group(self, name: str) -> ObjectGroup:
        """The group of kind ``name`` (``"hazards"``)."""
        return next(group for group in self.groups if group.name == name)

    def has(self, name: str) -> bool:
        """Whether the level has objects of kind ``name``."""
        return any(group.name == name for group in self.groups)

    def placements(self) -> dict[str, Placement]:
        """Every object's placement, in drawing order: the robot, then each group's objects."""
        keepout = self.robot.keepout if self.agent_keepout is None else self.agent_keepout
        placements = {"agent": Placement(self.agent_rects, keepout)}
        for group in self.groups:
            for index, name in enumerate(group.names):
                located = index < len(group.locations)
                placements[name] = (
                    fixed_location(group.locations[index], group.keepout)
                    if located
                    else Placement(group.placements, group.keepout)
                )
        return placements

    # ------------------------------------------------------------------------------------------------- step hooks
    def next_goal(self, world: World, rng: np.random.RandomState, layout: dict[str, np.ndarray]) -> None:
        """Set up the (next) goal: at reset, and after the goal was achieved (Safety-Gymnasium's ``update_world``).

        :raises ResamplingError: when no new goal position keeps the keepouts (the episode then ends).
        """

    def after_reset(self) -> None:
        """Reset the task's own state after :meth:`next_goal` at reset (``specific_reset``)."""

    def reward(self, world: World) -> float:
        """The step's reward (before clipping to ±10); it may update the task's distances."""
        raise NotImplementedError

    def goal_achieved(self, world: World) -> bool:
        """Whether the goal is achieved after this step."""
        return False

    def tick(self) -> None:
        """Advance the task's own clock after the cost of a step (``specific_step``)."""

    def constrained_goal_button(self) -> int | None:
        """The goal button's index while pressing another one costs (Button, timer at 0), else ``None``."""
        return None

    def observes(self, group: ObjectGroup) -> bool:
        """Whether the lidar of ``group`` reads this step (else it reads zeros)."""
        return True

    # ------------------------------------------------------------------------------------------------- state
    def state(self) -> dict[str, float]:
        """The task's own state (what :meth:`set_state` restores)."""
        return {"last_dist_goal": self.last_dist_goal}

    def set_state(self, state: dict[str, float]) -> None:
        """Restore what :meth:`state` returned."""
        for key, value in state.items():
            setattr(self, key, type(getattr(self, key))(value))


def goal_distance(world: World) -> float:
    """The xy distance from the robot to the goal."""
    return float(world.agent_planar_distances(world.body_xpos(("goal",)))[0])
