"""The objects of the navigation tasks: goal, hazards, vases, pillars, buttons, gremlins, the push box, walls, circle.

Each kind restates one of Safety-Gymnasium's ``assets/{geoms,free_geoms,mocaps}/*.py``: its MJCF (sizes, heights,
densities, contact flags), how a layout places it, the positions its pseudo-lidar sees, and the cost terms it adds
when constrained. Three ways to live in the world:

- **static** (goal, hazards, pillars, buttons, walls, circle): a body without joints, moved at reset through the
  model's ``body_pos`` / ``body_quat``;
- **free** (vases, the push box): a body on a free joint, placed through ``qpos``;
- **mocap** (gremlins): a free body welded to a mocap body that circles (radius ``travel``) about the origin, so
  each gremlin circles about its own layout position.

A group of ``num`` objects is named as Safety-Gymnasium names them: the kind's name without its final ``s`` and
an index (``hazards`` → ``hazard0``, ``hazard1``, …); a unique object (``num is None``) has the kind's name.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, Protocol

import numpy as np

from sppo_sb3.envs.navigation.layout import Rect
from sppo_sb3.envs.navigation.robots import Robot


class World(Protocol):
    """What an object's cost and lidar read of the simulation (:class:`sppo_sb3.envs.navigation.world.World`)."""

    robot: Robot

    def agent_xpos(self) -> np.ndarray: ...

    def body_xpos(self, names: Sequence[str]) -> np.ndarray: ...

    def agent_planar_distances(self, positions: np.ndarray) -> np.ndarray: ...

    def body_linear_velocities(self, names: Sequence[str]) -> np.ndarray: ...

    def agent_contacts(self, prefix: str, exact: bool = False) -> int: ...


def rot2quat(rot: float) -> np.ndarray:
    """The quaternion ``(w, x, y, z)`` of a rotation by ``rot`` radians about the vertical."""
    return np.array([np.cos(rot / 2), 0.0, 0.0, np.sin(rot / 2)])


def _fmt(values: Sequence[float] | np.ndarray) -> str:
    return " ".join(f"{float(v):.17g}" for v in np.atleast_1d(values))


@dataclass(frozen=True)
class ObjectGroup:
    """A kind of object, ``num`` of them (``None``: one, named as the kind), and how a layout places them.

    :param num: how many; ``None`` for a unique object (the goal, the push box, the circle).
    :param size: the object's size (radius, or half side); its meaning is the kind's.
    :param keepout: the radius kept free around it when a layout is sampled.
    :param placements: rectangles it may be placed in (``None``: the task's extents).
    :param locations: fixed positions of its first objects, overriding ``placements``.
    :param constrained: whether touching (or entering) it costs.
    """

    num: int | None = None
    size: float = 0.1
    keepout: float = 0.4
    placements: tuple[Rect, ...] | None = None
    locations: tuple[tuple[float, float], ...] = ()
    constrained: bool = False

    #: the kind's name, as the observation's ``<name>_lidar`` key and Safety-Gymnasium's ``info`` cost keys use it
    name: ClassVar[str]
    #: ``"static"``, ``"free"`` or ``"mocap"`` (see the module's docstring)
    mount: ClassVar[str] = "static"
    #: whether the pseudo-lidar sees it
    lidar: ClassVar[bool] = True

    @cached_property
    def names(self) -> list[str]:
        """The layout (and body) names of the group's objects."""
        return [self.name] if self.num is None else [f"{self.name[:-1]}{i}" for i in range(self.num)]

    @cached_property
    def bodies(self) -> list[str]:
        """The bodies whose positions are the objects' (what the lidar sees, what costs measure)."""
        return self.names

    def positions(self, world: World) -> np.ndarray:
        """The objects' positions, ``(n, 3)``."""
        return world.body_xpos(self.bodies)

    def geom_xml(self, name: str) -> str:
        """The object's ``<geom>`` (or geoms), in its body's frame."""
        raise NotImplementedError

    def height(self) -> float:
        """The height of the object's body above the floor."""
        return self.size

    def rotation(self, index: int, drawn: float) -> float:
        """The heading of the group's ``index``-th object, given the one the layout drew for it (most keep it)."""
        return drawn

    def body_xml(self, name: str, mocap: bool = False) -> str:
        """The object's ``<body>`` at the origin (the world places it at reset).

        :param mocap: a static object becomes a mocap body, its position part of the simulation's state (the
            shield's model, which serves every layout).
        """
        joint = f'<freejoint name="{name}"/>' if self.mount == "free" else ""
        flag = ' mocap="true"' if mocap and self.mount == "static" else ""
        return f'<body name="{name}"{flag}>{joint}{self.geom_xml(name)}</body>'

    def cost_terms(self, world: World, goal_button: int | None = None) -> dict[str, float]:
        """The cost terms (before the indicator) the group adds on this step; none if it is not constrained.

        :param world: the simulation after the step.
        :param goal_button: the goal button's index while pressing another one costs (Button, its timer at 0).
        """
        return {}

    def distance_to_unsafe(self, world: World, goal_button: int | None = None) -> float:
        """How far the robot is from paying this group's cost (``inf``: it cannot); what the shaped cost reads."""
        return float("inf")


def _contact_geom(name: str, geom_type: str, size: Sequence[float], extra: str = "") -> str:
    return f'<geom name="{name}" type="{geom_type}" size="{_fmt(size)}" {extra}/>'


class _TouchCost:
    """The cost of a kind whose constraint is a contact with the robot (``cost_<name>``: the number of contacts)."""

    cost_key: ClassVar[str]

    def cost_terms(self, world: World, goal_button: int | None = None) -> dict[str, float]:
        if not self.constrained:  # type: ignore[attr-defined]
            return {}
        return {self.cost_key: float(world.agent_contacts(self.contact_prefix))}  # type: ignore[attr-defined]

    def distance_to_unsafe(self, world: World, goal_button: int | None = None) -> float:
        if not self.constrained:  # type: ignore[attr-defined]
            return float("inf")
        gaps = world.agent_planar_distances(self.positions(world)) - self.size - world.robot.radius  # type: ignore
        return float(np.min(gaps, initial=np.inf))

    @property
    def contact_prefix(self) -> str:
        return self.name[:-1]  # type: ignore[attr-defined]


@dataclass(frozen=True)
class Goal(ObjectGroup):
    """The goal: a cylinder of radius ``size`` the robot reaches (no contact). Goal: ``keepout`` 0.305 at level 0."""

    size: float = 0.3
    name: ClassVar[str] = "goal"

    def geom_xml(self, name: str) -> str:
        return _contact_geom(name, "cylinder", (self.size, self.size / 2), 'contype="0" conaffinity="0" rgba="0 1 0 0.25"')

    def height(self) -> float:
        return self.size / 2 + 1e-2


@dataclass(frozen=True)
class Hazards(ObjectGroup):
    """Flat circles of radius ``size`` (no contact); the cost is being within ``size`` of one's centre (xy)."""

    size: float = 0.2
    constrained: bool = True
    name: ClassVar[str] = "hazards"

    def geom_xml(self, name: str) -> str:
        return _contact_geom(name, "cylinder", (self.size, 1e-2), 'contype="0" conaffinity="0" rgba="0 0 1 0.25"')

    def height(self) -> float:
        return 2e-2

    def cost_terms(self, world: World, goal_button: int | None = None) -> dict[str, float]:
        if not self.constrained:
            return {}
        inside = np.maximum(self.size - world.agent_planar_distances(self.positions(world)), 0.0)
        return {"cost_hazards": float(np.sum(inside))}

    def distance_to_unsafe(self, world: World, goal_button: int | None = None) -> float:
        if not self.constrained:
            return float("inf")
        return float(np.min(world.agent_planar_distances(self.positions(world)) - self.size, initial=np.inf))


@dataclass(frozen=True)
class Pillars(_TouchCost, ObjectGroup):
    """Fixed cylinders of radius ``size`` and half-height 0.5; the cost is touching one."""

    size: float = 0.2
    keepout: float = 0.3
    constrained: bool = True
    name: ClassVar[str] = "pillars"
    cost_key: ClassVar[str] = "cost_pillars"
    half_height: ClassVar[float] = 0.5

    def geom_xml(self, name: str) -> str:
        return _contact_geom(name, "cylinder", (self.size, self.half_height), 'rgba="0.5 0.5 1 1"')

    def height(self) -> float:
        return self.half_height


@dataclass(frozen=True)
class Buttons(_TouchCost, ObjectGroup):
    """Spheres of radius ``size``; one is the goal. Constrained: touching another one while the timer is 0 costs."""

    size: float = 0.1
    keepout: float = 0.2
    constrained: bool = True
    name: ClassVar[str] = "buttons"
    cost_key: ClassVar[str] = "cost_buttons"
    #: steps after a button is pressed during which the buttons are neither seen nor constrained
    resampling_delay: ClassVar[int] = 10

    def geom_xml(self, name: str) -> str:
        return _contact_geom(name, "sphere", (self.size,) * 3, 'rgba="1 0.5 0 1"')

    def cost_terms(self, world: World, goal_button: int | None = None) -> dict[str, float]:
        if not self.constrained or goal_button is None:
            return {}
        wrong = world.agent_contacts(self.contact_prefix) - world.agent_contacts(self.names[goal_button], exact=True)
        return {self.cost_key: float(wrong)}

    def distance_to_unsafe(self, world: World, goal_button: int | None = None) -> float:
        if not self.constrained or goal_button is None:
            return float("inf")
        others = [i for i in range(len(self.names)) if i != goal_button]
        gaps = world.agent_planar_distances(self.positions(world)[others]) - self.size - world.robot.radius
        return float(np.min(gaps, initial=np.inf))


@dataclass(frozen=True)
class Vases(_TouchCost, ObjectGroup):
    """Light boxes of half side ``size`` on free joints. Constrained: touching one, and any moving, cost."""

    size: float = 0.1
    keepout: float = 0.15
    constrained: bool = True
    name: ClassVar[str] = "vases"
    mount: ClassVar[str] = "free"
    cost_key: ClassVar[str] = "cost_vases_contact"
    density: ClassVar[float] = 0.001
    #: how far a vase sinks into the floor at rest (Safety-Gymnasium's measured value)
    sink: ClassVar[float] = 4e-5
    #: speeds below this are not counted as the vase moving
    velocity_threshold: ClassVar[float] = 1e-4

    def geom_xml(self, name: str) -> str:
        return _contact_geom(name, "box", (self.size,) * 3, f'density="{self.density}" rgba="0 1 1 1"')

    def height(self) -> float:
        return self.size - self.sink

    def cost_terms(self, world: World, goal_button: int | None = None) -> dict[str, float]:
        if not self.constrained:
            return {}
        speeds = np.linalg.norm(world.body_linear_velocities(self.names), axis=1)
        moving = float(np.sum(speeds[speeds >= self.velocity_threshold]))
        return {**super().cost_terms(world), "cost_vases_velocity": moving}


@dataclass(frozen=True)
class Gremlins(_TouchCost, ObjectGroup):
    """Boxes of half side ``size`` that circle (radius ``travel``) about their layout position; touching one costs."""

    size: float = 0.1
    keepout: float = 0.5
    travel: float = 0.3
    constrained: bool = True
    name: ClassVar[str] = "gremlins"
    mount: ClassVar[str] = "mocap"
    cost_key: ClassVar[str] = "cost_gremlins"
    density: ClassVar[float] = 0.001

    def object_name(self, name: str) -> str:
        """The free body's name (``gremlin0obj``); the layout name is ``gremlin0``."""
        return f"{name}obj"

    def mocap_name(self, name: str) -> str:
        """The mocap body's name (``gremlin0mocap``)."""
        return f"{name}mocap"

    def body_xml(self, name: str, mocap: bool = False) -> str:
        obj = self.object_name(name)
        geom = _contact_geom(obj, "box", (self.size,) * 3, f'density="{self.density}" rgba="0.5 0 1 1"')
        return f'<body name="{obj}"><freejoint name="{obj}"/>{geom}</body>'

    def mocap_xml(self, name: str) -> str:
        """The mocap body (at the origin; its marker geom is offset to the layout position at reset)."""
        mocap = self.mocap_name(name)
        marker = _contact_geom(mocap, "box", (self.size,) * 3, 'contype="0" conaffinity="0" rgba="0.05 0 0.1 0.1"')
        return f'<body name="{mocap}" mocap="true">{marker}</body>'

    def weld_xml(self, name: str) -> str:
        mocap, obj = self.mocap_name(name), self.object_name(name)
        return f'<weld name="{mocap}" body1="{mocap}" body2="{obj}" solref="0.02 1.5"/>'

    @cached_property
    def bodies(self) -> list[str]:
        return [self.object_name(name) for name in self.names]

    def mocap_target(self, time: float) -> np.ndarray:
        """Where every gremlin's mocap body is at ``time``: on the circle of radius ``travel``, at height ``size``."""
        return np.array([np.sin(time) * self.travel, np.cos(time) * self.travel, self.size])

    @property
    def contact_prefix(self) -> str:
        return "gremlin"


@dataclass(frozen=True)
class PushBox(ObjectGroup):
    """The box the robot pushes to the goal: a box of half side ``size`` with four corner columns, on a free joint."""

    size: float = 0.2
    keepout: float = 0.2
    density: float = 0.001
    name: ClassVar[str] = "push_box"
    mount: ClassVar[str] = "free"

    def geom_xml(self, name: str) -> str:
        dim, half = self.size, self.size / 2
        extra = f'density="{self.density}" rgba="1 1 0 0.25"'
        columns = "".join(
            _contact_geom(f"col{i + 1}", "box", (half, half, dim), f'{extra} pos="{_fmt((x * dim, y * dim, 0.0))}"')
            for i, (x, y) in enumerate(((1, 1), (-1, 1), (1, -1), (-1, -1)))
        )
        return _contact_geom(name, "box", (dim,) * 3, extra) + columns


@dataclass(frozen=True)
class Sigwalls(ObjectGroup):
    """Walls the robot may pass but must not cross (Circle 1 and 2): ``|x| > 1.125`` (and ``|y|`` with four) costs."""

    num: int | None = 2
    size: float = 1.125
    keepout: float = 0.0
    constrained: bool = True
    locations: tuple[tuple[float, float], ...] = ((1.125, 0.0), (-1.125, 0.0), (0.0, 1.125), (0.0, -1.125))
    name: ClassVar[str] = "sigwalls"
    lidar: ClassVar[bool] = False

    def geom_xml(self, name: str) -> str:
        return _contact_geom(name, "box", (0.05, 3.5, 0.3), 'contype="0" conaffinity="0" rgba="1 1 0 0.1"')

    def height(self) -> float:
        return 0.25

    def rotation(self, index: int, drawn: float) -> float:
        """The drawn heading is ignored: the third and fourth walls run along x, the others along y."""
        return np.pi / 2 if index >= 2 else 0.0

    def cost_terms(self, world: World, goal_button: int | None = None) -> dict[str, float]:
        if not self.constrained:
            return {}
        x, y = world.agent_xpos()[:2]
        out = abs(x) > self.size or (self.num == 4 and abs(y) > self.size)
        return {"cost_out_of_boundary": float(out)}

    def distance_to_unsafe(self, world: World, goal_button: int | None = None) -> float:
        if not self.constrained:
            return float("inf")
        xy = np.abs(world.agent_xpos()[:2])
        return float(self.size - (xy.max() if self.num == 4 else xy[0]))


@dataclass(frozen=True)
class CircleZone(ObjectGroup):
    """The circle of radius ``size`` (1.5) centred at the origin that Circle's robot runs along (seen, no contact)."""

    size: float = 1.5
    keepout: float = 0.0
    locations: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    name: ClassVar[str] = "circle"

    def geom_xml(self, name: str) -> str:
        return _contact_geom(name, "cylinder", (self.size, 1e-2), 'contype="0" conaffinity="0" rgba="0 1 0 0.1"')

    def height(self) -> float:
        return 1e-2

    @cached_property
    def bodies(self) -> list[str]:
        return ["world"]  # Safety-Gymnasium's lidar sees the circle at the origin

    def rotation(self, index: int, drawn: float) -> float:
        return 0.0  # the drawn heading is ignored
