"""The shield of the navigation tasks: :class:`MujocoShieldingRule` on the task's own model, from the simulator state.

The agent senses lidar, which does not say the state; the shield reads it from the env that produced the
observation (:meth:`SafetyNavigationEnv.producing`), as SAILR's intervention wrapper reads its simulator. The envs
must therefore live in the calling process (``DummyVecEnv``, ``ShieldWrapper``); an observation no live env produced
(a ``SubprocVecEnv``'s, a normalised one) raises :class:`~sppo_sb3.shield.ShieldFailure`: nothing is executed on a
state the shield could not read.

One model serves every layout: the robot, with the Point's slides aligned with the world (the env starts them in the
robot's start frame), among mocap bodies where the objects are, so that their positions travel in the rolled state (as
columns after MuJoCo's full physics state, fed to the rollouts as mocap controls). Static objects keep their geoms
(the robot is blocked by a pillar or a button as in the env); the movable ones (vases, the push box, gremlins) are
markers where they are now, as if the robot pushed them away without effort: they weigh 0.2-1.3% of the Point, so
the robot's motion changes by about that much when it pushes one. The constraint, on every rolled env step:

- **hazards** (exact): the robot body's ``(x, y)`` within a hazard's radius, Safety-Gymnasium's cost;
- **pillars** and **vases** where constrained (conservative): the robot within ``object radius + robot radius`` of
  one, a superset of touching it (a vase moves only when touched, so its velocity cost is covered too);
- **buttons** other than the goal (Button 1 and 2, conservative): the robot within ``button radius + robot radius``
  of one, also in the 10 steps after a press when the env charges none;
- **gremlins** (Button 1 and 2, predicted): the robot within ``gremlin reach + robot radius +``
  :data:`GREMLIN_MARGIN` of where one is or will be in the next :data:`GREMLIN_SWEEP` seconds. A gremlin's box is
  welded to a mocap body that circles on a clock (``Gremlins.mocap_target``), so each rolled step moves its marker by
  the circle's motion since the state's time, and the constraint keeps the robot off the arc the box sweeps from
  there: a plan that ends standing in a gremlin's path is unsafe, though the contact would come after the lookahead.
  The margin covers the weld's lag. The path ahead costs nothing yet: the constraint says which steps cost
  (:meth:`NavigationConstraint.costly`), so that the rule enters a path before it touches anything, and inside one
  leads the robot out ahead of the gremlin or outwards (:meth:`NavigationConstraint.keep_out_depth`), looking
  :data:`GREMLIN_LOOKAHEAD_SECONDS` ahead, with :data:`GREMLIN_HELD_PARTICLES` of its plans holding the controls at
  their bounds. Still a prediction: a robot held where the gremlin will come, with no way
  out within the lookahead, can be reached;
- **walls** (Circle 1 and 2, exact): ``|x|`` (and ``|y|``) beyond 1.125.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import mujoco
import numpy as np

from sppo_sb3.envs.navigation.env import SafetyNavigationEnv
from sppo_sb3.envs.navigation.objects import Buttons, Gremlins, Hazards, Pillars, Sigwalls, Vases
from sppo_sb3.envs.navigation.robots import ROBOTS
from sppo_sb3.envs.navigation.tasks import TASKS, NavigationTask
from sppo_sb3.envs.navigation.world import FRAME_SKIP, moved, world_xml
from sppo_sb3.shield.base import ShieldFailure
from sppo_sb3.shield.mujoco.model import FULL_STATE, ConstraintCosts, ConstraintSteps, MujocoLayout, StateConstraint
from sppo_sb3.shield.mujoco.rule import MujocoShieldingRule, lookahead_horizon

#: how far ahead the navigation rules look, one time for both robots: 15 of the Point's 20 ms steps (the horizon its
#: rule was first validated with), 8 of the Car's 40 ms steps, over the Car's braking from top speed (0.77 m/s, 0.2 s)
#: with margin, and at half the cost of 15 (docs/guide/tasks.md: "The navigation shield").
LOOKAHEAD_SECONDS = 0.3
#: how far ahead they look where gremlins move (Button 1 and 2): far enough for the backup to find the way out of a
#: gremlin's path before it comes, round what blocks the shortest (a hazard, a wrong button)
GREMLIN_LOOKAHEAD_SECONDS = 0.4
#: particles of each solve that hold a turn or a drive at full control where gremlins move (all 8 directions of the
#: robots' two controls): the way out of a gremlin's path round a hazard is a turn held, then a drive, which noise
#: around the warm plan rarely draws in time
GREMLIN_HELD_PARTICLES = 8
#: a button this close to the goal is the goal button (the env puts the goal on it; buttons keep 0.4 m apart)
GOAL_ON_BUTTON = 1e-3
#: metres added to a gremlin's reach for the lag of its box behind the circling mocap body it is welded to
GREMLIN_MARGIN = 0.05
#: seconds of a gremlin's path ahead of it that the robot keeps off, beyond the rule's lookahead (gremlins circle at
#: one radian per second, so this is also the arc's angle): a plan must not end where a gremlin will be this soon
GREMLIN_SWEEP = 1.0


class GremlinFrame(NamedTuple):
    """Each gremlin ``(..., n, ·)`` seen from the robot: :meth:`NavigationConstraint.gremlin_frame`."""

    agent: np.ndarray  #: ``(..., 2)`` the robot's (x, y)
    time: np.ndarray  #: ``(..., 1)`` the state's time
    boxes: np.ndarray  #: where each gremlin's box is
    centres: np.ndarray  #: its circle's centre
    offsets: np.ndarray  #: the robot's offset from the centre
    ahead: np.ndarray  #: the robot's angle ahead of the box along the circle


def navigation_task(robot: str, task: str, level: int) -> NavigationTask:
    """The task definition of ``Safety<robot><task><level>``."""
    return TASKS[task](level, ROBOTS[robot])


@dataclass(frozen=True)
class NavigationConstraint(StateConstraint):
    """The static constraints of a navigation task on the shield model's states (see the module).

    :param hazard_columns: ``(n, 2)`` state columns of each hazard's ``(x, y)``.
    :param hazard_size: the hazards' radius.
    :param contact_columns: ``(n, 2)`` state columns of each constrained pillar's or vase's ``(x, y)``.
    :param contact_reach: ``(n,)`` for each, the distance under which the robot may touch it.
    :param gremlin_columns: ``(n, 2)`` state columns of each gremlin box's ``(x, y)``.
    :param gremlin_reach: the distance under which the robot may touch a gremlin's box.
    :param gremlin_travel: the radius of the gremlins' circles.
    :param gremlin_sweep: seconds of each gremlin's path ahead of it that the robot keeps out of reach of.
    :param button_columns: ``(n, 2)`` state columns of each button's ``(x, y)`` where a wrong button costs.
    :param button_reach: the distance under which the robot may touch a button.
    :param goal_columns: the state columns of the goal's ``(x, y)``, which sits on the goal button: that one is free.
    :param wall: ``|x|`` beyond this is unsafe (``None``: no walls).
    :param wall_both_axes: ``|y|`` too.
    """

    hazard_columns: tuple[tuple[int, int], ...] = ()
    hazard_size: float = 0.0
    contact_columns: tuple[tuple[int, int], ...] = ()
    contact_reach: tuple[float, ...] = ()
    gremlin_columns: tuple[tuple[int, int], ...] = ()
    gremlin_reach: float = 0.0
    gremlin_travel: float = 0.0
    gremlin_sweep: float = GREMLIN_SWEEP
    button_columns: tuple[tuple[int, int], ...] = ()
    button_reach: float = 0.0
    goal_columns: tuple[int, int] | None = None
    wall: float | None = None
    wall_both_axes: bool = False

    @classmethod
    def of(cls, task: NavigationTask, model: mujoco.MjModel) -> NavigationConstraint:
        """The constraint of ``task`` on its shield ``model`` (:func:`shield_model`)."""
        hazards: tuple[tuple[int, int], ...] = ()
        hazard_size, reach = 0.0, []
        wall, both = None, False
        contacts: list[tuple[int, int]] = []
        gremlins: tuple[tuple[int, int], ...] = ()
        gremlin_reach, travel = 0.0, 0.0
        buttons: tuple[tuple[int, int], ...] = ()
        button_reach, goal = 0.0, None
        for group in task.groups:
            if not group.constrained:
                continue
            if isinstance(group, Hazards):
                hazards, hazard_size = tuple(mocap_columns(model, name) for name in group.names), group.size
            elif isinstance(group, Pillars):
                pillars = [mocap_columns(model, name) for name in group.names]
                contacts += pillars
                reach += [group.size + task.robot.radius] * len(pillars)
            elif isinstance(group, Vases):
                vases = [mocap_columns(model, name) for name in group.names]
                contacts += vases
                reach += [group.size * np.sqrt(2) + task.robot.radius] * len(vases)
            elif isinstance(group, Gremlins):
                gremlins = tuple(mocap_columns(model, body) for body in moved(group))
                gremlin_reach, travel = group.size * np.sqrt(2) + task.robot.radius + GREMLIN_MARGIN, group.travel
            elif isinstance(group, Buttons):
                buttons = tuple(mocap_columns(model, name) for name in group.names)
                button_reach, goal = group.size + task.robot.radius, mocap_columns(model, "goal")
            elif isinstance(group, Sigwalls):
                wall, both = group.size, group.num == 4
        return cls(
            hazard_columns=hazards,
            hazard_size=hazard_size,
            contact_columns=tuple(contacts),
            contact_reach=tuple(reach),
            gremlin_columns=gremlins,
            gremlin_reach=gremlin_reach,
            gremlin_travel=travel,
            button_columns=buttons,
            button_reach=button_reach,
            goal_columns=goal,
            wall=wall,
            wall_both_axes=both,
        )

    @property
    def empty(self) -> bool:
        """Whether nothing is constrained (the shield then never acts)."""
        objects = self.hazard_columns or self.contact_columns or self.gremlin_columns or self.button_columns
        return not objects and self.wall is None

    def margins(self, states: np.ndarray) -> np.ndarray:
        """``(..., k)`` the signed distance of each constraint that costs (``<= 0``: violated) in states ``(..., nstate)``:
        hazards, pillars and vases, gremlins where they are, wrong buttons, walls; the gremlins' paths ahead are
        :meth:`keep_out`."""
        agent = states[..., 1:3]  # qpos[0:2]: the robot body's (x, y) in the shield model
        parts = []
        for columns, reach in (
            (self.hazard_columns, self.hazard_size),
            (self.contact_columns, np.array(self.contact_reach)),
            (self.gremlin_columns, self.gremlin_reach),
        ):
            if columns:
                centres = states[..., np.array(columns)]  # (..., n, 2)
                parts.append(np.linalg.norm(centres - agent[..., None, :], axis=-1) - reach)
        if self.button_columns:
            parts.append(self.wrong_button_margins(states, agent))
        if self.wall is not None:
            extent = np.abs(agent) if self.wall_both_axes else np.abs(agent[..., :1])
            parts.append(self.wall - extent)
        return np.concatenate(parts, axis=-1) if parts else np.full((*states.shape[:-1], 1), np.inf)

    def keep_out(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The gremlins' paths ahead, kept out of as unsafe though the env charges nothing there yet: ``(..., n)`` the
        signed distance of each (:meth:`gremlin_margins`) and ``(...)`` how deep the robot is in them
        (:meth:`keep_out_depth`). Needs gremlins."""
        frame = self.gremlin_frame(states, states[..., 1:3])
        margins = self.gremlin_margins(frame)
        return margins, self.keep_out_depth(frame, margins)

    def keep_out_depth(self, frame: GremlinFrame, margins: np.ndarray) -> np.ndarray:
        """``(...)`` how deep the robot is in the gremlins' paths ahead (their ``margins``): the depth of the deepest,
        plus the arc the gremlin has left to travel before it can touch the robot short of the sweep
        (:meth:`gremlin_arrivals`), so that a robot inside leaves ahead of the gremlin or outwards, not only the shortest
        way (into a wrong button)."""
        early = self.gremlin_travel * np.maximum(self.gremlin_sweep - self.gremlin_arrivals(frame), 0.0)
        return np.max(np.where(margins <= 0, early - margins, 0.0), axis=-1)

    def gremlin_frame(self, states: np.ndarray, agent: np.ndarray) -> GremlinFrame:
        """Where each gremlin is, and its circle, seen from a robot at ``agent`` ``(..., 2)`` (:class:`GremlinFrame`).

        A gremlin at time ``t`` is at ``c + travel · (sin t, cos t)`` (``Gremlins.mocap_target``, one radian per
        second), so its centre ``c`` follows from where it is.
        """
        time = states[..., :1]  # (..., 1): column 0, the state's time
        boxes = states[..., np.array(self.gremlin_columns)]  # (..., n, 2)
        centres = boxes - self.gremlin_travel * np.stack([np.sin(time), np.cos(time)], axis=-1)
        offsets = agent[..., None, :] - centres
        ahead = np.mod(np.arctan2(offsets[..., 0], offsets[..., 1]) - time, 2 * np.pi)
        return GremlinFrame(agent, time, boxes, centres, offsets, ahead)

    def gremlin_margins(self, frame: GremlinFrame) -> np.ndarray:
        """``(..., n)`` the robot's distance to the reach of each gremlin's path over the next ``gremlin_sweep`` seconds:
        its distance to the circle where the robot's direction from the centre lies on the arc, else to the nearer
        end."""
        agent, end = frame.agent[..., None, :], frame.time + self.gremlin_sweep
        ends = frame.centres + self.gremlin_travel * np.stack([np.sin(end), np.cos(end)], axis=-1)
        to_ends = np.minimum(np.linalg.norm(frame.boxes - agent, axis=-1), np.linalg.norm(ends - agent, axis=-1))
        to_circle = np.abs(np.linalg.norm(frame.offsets, axis=-1) - self.gremlin_travel)
        return np.where(frame.ahead <= self.gremlin_sweep, to_circle, to_ends) - self.gremlin_reach

    def gremlin_arrivals(self, frame: GremlinFrame) -> np.ndarray:
        """``(..., n)`` seconds until each gremlin's box comes within reach of the robot where it is (0: it is;
        ``inf``: never, the robot being out of reach of the circle)."""
        radius, travel, ahead = np.linalg.norm(frame.offsets, axis=-1), self.gremlin_travel, frame.ahead
        cosine = (radius**2 + travel**2 - self.gremlin_reach**2) / np.maximum(2 * radius * travel, 1e-12)
        half_width = np.arccos(np.clip(cosine, -1.0, 1.0))  # the box is within reach this far either side of the robot
        within = (ahead <= half_width) | (ahead >= 2 * np.pi - half_width)
        return np.where(within, 0.0, np.where(cosine > 1.0, np.inf, ahead - half_width))

    def wrong_button_margins(self, states: np.ndarray, agent: np.ndarray) -> np.ndarray:
        """``(..., n)`` the robot's distance to touching each button, ``inf`` for the goal button (the goal sits on it)."""
        centres = states[..., np.array(self.button_columns)]  # (..., n, 2)
        goal = states[..., np.array(self.goal_columns)]  # (..., 2)
        margins = np.linalg.norm(centres - agent[..., None, :], axis=-1) - self.button_reach
        is_goal = np.linalg.norm(centres - goal[..., None, :], axis=-1) < GOAL_ON_BUTTON
        return np.where(is_goal, np.inf, margins)

    def violated(self, margins: np.ndarray) -> np.ndarray:
        """``(...)`` whether any of :meth:`margins`' constraints is violated."""
        hazards = len(self.hazard_columns)  # Safety-Gymnasium: a hazard costs strictly inside its radius
        inside = np.any(margins[..., :hazards] < 0, axis=-1) if hazards else np.zeros(margins.shape[:-1], dtype=bool)
        return inside | np.any(margins[..., hazards:] <= 0, axis=-1)

    def assess(self, steps: ConstraintSteps) -> ConstraintCosts:
        """Each margin once: hazards and the other objects that cost, then the gremlins' paths ahead, which do not yet
        (:meth:`costly`)."""
        states = steps.after
        margins = self.margins(states)
        nearest = np.min(margins, axis=-1)
        violated, depth = self.violated(margins), np.maximum(-nearest, 0.0)
        if not self.gremlin_columns:
            return ConstraintCosts(violated, np.maximum(nearest, 0.0), depth, None)
        keep_out, keep_out_depth = self.keep_out(states)
        return ConstraintCosts(
            unsafe=violated | np.any(keep_out <= 0, axis=-1),
            distance=np.maximum(np.minimum(nearest, np.min(keep_out, axis=-1)), 0.0),
            depth=np.maximum(depth, keep_out_depth),
            costly=(violated, depth),
        )

    def is_unsafe(self, steps: ConstraintSteps) -> np.ndarray:
        return self.assess(steps).unsafe

    def distance(self, steps: ConstraintSteps) -> np.ndarray:
        return self.assess(steps).distance

    def depth(self, steps: ConstraintSteps) -> np.ndarray | float:
        return self.assess(steps).depth

    def costly(self, steps: ConstraintSteps) -> tuple[np.ndarray, np.ndarray | float] | None:
        return self.assess(steps).costly


def shield_model(task: NavigationTask) -> mujoco.MjModel:
    """The task's world with static objects as mocap bodies and movable ones as markers (see the module)."""
    return mujoco.MjModel.from_xml_string(world_xml(task.robot, task.groups, shield_model=True))


def physics_size(model: mujoco.MjModel) -> int:
    """Columns of MuJoCo's full physics state; the mocap positions follow them in the shield's states."""
    return int(mujoco.mj_stateSize(model, FULL_STATE))


def mocap_columns(model: mujoco.MjModel, body: str) -> tuple[int, int]:
    """The state columns of a mocap body's ``(x, y)``."""
    index = physics_size(model) + 3 * int(model.body_mocapid[model.body(body).id])
    return index, index + 1


@dataclass(frozen=True)
class NavigationLayout(MujocoLayout):
    """How the shield sees a navigation task: its state read from the env that produced an observation.

    :param robot: ``"Point"`` or ``"Car"``.
    :param task: ``"Goal"``, ``"Button"``, ``"Push"`` or ``"Circle"``.
    :param level: 0, 1 or 2.
    """

    robot: str = "Point"
    task: str = "Goal"
    level: int = 1

    @classmethod
    def of_task(cls, robot: str, task: str, level: int) -> NavigationLayout:
        definition = navigation_task(robot, task, level)
        model = shield_model(definition)
        env_id = f"sppo_sb3/Safety{robot}{task}{level}-v0"
        obs_dim = SafetyNavigationEnv(robot, task, level).observation_space.shape[0]  # type: ignore[index]
        return cls("", FRAME_SKIP, 0, model.nq, model.nv, obs_dim, None, env_id, robot=robot, task=task, level=level)

    @property
    def state_obs_dim(self) -> int:
        return self.obs_dim

    def build_model(self, constraint: StateConstraint) -> mujoco.MjModel:
        return shield_model(navigation_task(self.robot, self.task, self.level))

    def at_origin(self, states: np.ndarray) -> np.ndarray:
        return np.array(states)

    def known_states(self, obs: np.ndarray) -> np.ndarray:
        return np.ones(len(obs), dtype=bool)

    def states_from_obs(self, model: mujoco.MjModel, obs: np.ndarray) -> np.ndarray:
        """The shield model's states of the envs that produced ``obs``.

        :raises ShieldFailure: no live env of this process produced one of them.
        """
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        states = np.empty((len(obs), physics_size(model) + 3 * model.nmocap))
        for row, observation in enumerate(obs):
            env = SafetyNavigationEnv.producing(observation)
            if env is None:
                raise ShieldFailure(
                    f"No navigation env in this process produced this observation, so the shield cannot read its state "
                    f"({self.env_id}). The navigation shield reads the simulator of the env that made the observation: "
                    "run the envs in this process (DummyVecEnv, not SubprocVecEnv) and shield raw observations "
                    "(no VecNormalize before the shield)."
                )
            states[row] = shield_state(env, model)
        return states

    def obs_from_states(self, states: np.ndarray) -> np.ndarray:
        """The warm starts' keys: ``qpos`` and ``qvel``."""
        return np.array(states[:, 1 : 1 + self.nq + self.nv])


def shield_state(env: SafetyNavigationEnv, model: mujoco.MjModel) -> np.ndarray:
    """``env``'s simulator state in the shield ``model``'s coordinates: the robot's physics state, then the mocap
    ``(x, y, z)`` of every object (where the env's bodies are now)."""
    robot = env.world.robot
    qpos, qvel = env.data.qpos[: model.nq].copy(), env.data.qvel[: model.nv].copy()  # the robot's joints come first
    if not robot.free_joint:  # the Point: slides in its start frame → world-aligned slides at the origin
        agent = env.world.agent_id
        w, z = env.model.body_quat[agent, 0], env.model.body_quat[agent, 3]
        heading = 2 * np.arctan2(z, w)
        rotation = np.array([[np.cos(heading), -np.sin(heading)], [np.sin(heading), np.cos(heading)]])
        qpos[:2] = env.model.body_pos[agent, :2] + rotation @ qpos[:2]
        qpos[2] += heading
        qvel[:2] = rotation @ qvel[:2]
    mocap = np.zeros((model.nmocap, 3))
    for body in np.flatnonzero(model.body_mocapid >= 0):
        mocap[model.body_mocapid[body]] = env.data.body(model.body(body).name).xpos
    return np.concatenate([[env.data.time], qpos, qvel, mocap.ravel()])


class NavigationShieldingRule(MujocoShieldingRule):
    """:class:`MujocoShieldingRule` for a navigation task, its state read from the env (see the module).

    :param robot: ``"Point"`` or ``"Car"``.
    :param task: ``"Goal"``, ``"Button"``, ``"Push"`` or ``"Circle"``.
    :param level: 0, 1 or 2.
    :param alpha: the shaped cost's band of eq. 18, in metres (the env's ``alpha``).
    :param n_particles: MPPI particles per solve (half :class:`MujocoShieldingRule`'s: the robots have two controls).
    :param horizon: ``H_m`` in env steps (``None``: :data:`LOOKAHEAD_SECONDS` of the robot's steps,
        :data:`GREMLIN_LOOKAHEAD_SECONDS` where gremlins move).
    :param kwargs: further settings of :class:`MujocoShieldingRule` (``eta``, ``noise_std``, ...;
        ``constant_particles`` defaults to :data:`GREMLIN_HELD_PARTICLES` where gremlins move).
    """

    def __init__(
        self,
        robot: str = "Point",
        task: str = "Goal",
        level: int = 1,
        alpha: float = 0.1,
        n_particles: int = 32,
        horizon: int | None = None,
        **kwargs: Any,
    ) -> None:
        layout = NavigationLayout.of_task(robot, task, level)
        definition = navigation_task(robot, task, level)
        constraint = NavigationConstraint.of(definition, shield_model(definition))
        if constraint.empty:
            raise ValueError(f"{layout.env_id} constrains nothing the shield covers: it needs no shield (use shield=None).")
        if horizon is None:
            seconds = GREMLIN_LOOKAHEAD_SECONDS if constraint.gremlin_columns else LOOKAHEAD_SECONDS
            horizon = lookahead_horizon(definition.robot.timestep * FRAME_SKIP, seconds)
        if constraint.gremlin_columns:  # a way out of a gremlin's path round a hazard: a turn held, then a drive
            kwargs.setdefault("constant_particles", GREMLIN_HELD_PARTICLES)
        super().__init__(layout, constraint, horizon=horizon, alpha=alpha, n_particles=n_particles, **kwargs)
        self._physics = physics_size(self.model)
        self._gremlins = next((g for g in definition.groups if isinstance(g, Gremlins) and g.constrained), None)
        columns = [mocap_columns(self.model, body) for body in moved(self._gremlins)] if self._gremlins else []
        self._gremlin_columns = np.array(columns, dtype=int).reshape(-1, 2) - self._physics  # (n, 2) in the mocap block

    def mocap_paths(self, states: np.ndarray, nstep: int) -> np.ndarray:
        """``(M, nstep, 3·nmocap)`` where every object's marker is after each of ``nstep`` physics steps: where it is
        now, the gremlins moved along their circles by the clock (the state's time, column 0)."""
        mocap = states[:, self._physics :]
        paths = np.broadcast_to(mocap[:, None], (len(states), nstep, mocap.shape[1]))
        if self._gremlins is not None:
            paths = paths.copy()  # only here: the rollouts' controls are a copy of it anyway
            times = states[:, :1] + self.model.opt.timestep * np.arange(1, nstep + 1)  # (M, nstep)
            now = np.stack([np.sin(states[:, 0]), np.cos(states[:, 0])], axis=-1)  # (M, 2)
            ahead = np.stack([np.sin(times), np.cos(times)], axis=-1)  # (M, nstep, 2)
            shift = self._gremlins.travel * (ahead - now[:, None])  # Gremlins.mocap_target's motion since now
            for x, y in self._gremlin_columns:
                paths[..., x] += shift[..., 0]
                paths[..., y] += shift[..., 1]
        return paths

    def _rollout(self, states: np.ndarray, ctrl: np.ndarray, **outputs: np.ndarray) -> None:
        """Roll the physics part of the states, the mocap columns fed as controls and copied to the outputs."""
        m, nstep = ctrl.shape[:2]
        physics, mocap = states[:, : self._physics], self.mocap_paths(states, nstep)
        control = np.concatenate([ctrl, mocap], axis=2)
        rolled: dict[str, np.ndarray] = {}
        if "state" in outputs:
            rolled["state"] = np.empty((m, nstep, self._physics))
        if "sensordata" in outputs:
            rolled["sensordata"] = outputs["sensordata"]
        self._pool.rollout(
            [self.model] * m,
            self._datas,
            np.ascontiguousarray(physics),
            np.ascontiguousarray(control),
            control_spec=mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS,
            skip_checks=True,
            nstep=nstep,
            initial_warmstart=np.zeros((m, self.model.nv)),
            **rolled,
        )
        if "state" in outputs:
            outputs["state"][..., : self._physics] = rolled["state"]
            outputs["state"][..., self._physics :] = mocap

    def tracked_states(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The states behind ``obs``, read once from their envs (always known), and the warm plans stored under them."""
        states = self.layout.states_from_obs(self.model, obs)
        warm, used, _ = self.warm_starts.lookup(self.layout.obs_from_states(states))
        return states, np.ones(len(states), dtype=bool), warm, used


def navigation_shielding_rule(robot: str, task: str, level: int, alpha: float = 0.1, **kwargs: Any) -> NavigationShieldingRule:
    """The registered rule of ``sppo_sb3/Safety<robot><task><level>-v0`` (the registry passes the env's ``alpha``)."""
    return NavigationShieldingRule(robot, task, level, alpha=alpha, **kwargs)
