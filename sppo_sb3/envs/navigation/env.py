"""The gymnasium env of a navigation task: ``sppo_sb3/Safety<Robot><Task><Level>-v0``.

One step, as Safety-Gymnasium 1.0.0's ``Builder.step``: the action is clipped to the actuators' ranges; the
simulation advances ``FRAME_SKIP`` MuJoCo steps (gremlins moved before each); then the reward (clipped to ±10), the
cost terms of every constrained group, the task's clock, and, when the goal is achieved, ``info["goal_met"]`` and a
new goal (an episode whose goal cannot be re-placed ends, ``terminated``). The registration's TimeLimit truncates
after the task's episode length (1000 steps, Circle 500).

``info["cost"]`` is 1.0 on a step with any positive cost term, else 0.0 (Safety-Gymnasium's indicator), and the
terms themselves are in ``info`` under Safety-Gymnasium's names (``cost_hazards``, ``cost_vases_contact``, …), each
an indicator too. ``info["shaped_cost"]`` is eq. 18's ``max(0, 1 − dist/α)`` of the distance to the nearest
constrained object (see :meth:`ObjectGroup.distance_to_unsafe`).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY, SHAPED_COST_KEY
from sppo_sb3.envs.navigation.layout import ResamplingError, random_rotation
from sppo_sb3.envs.navigation.lidar import NUM_BINS, pseudo_lidar
from sppo_sb3.envs.navigation.objects import Gremlins
from sppo_sb3.envs.navigation.robots import ROBOTS
from sppo_sb3.envs.navigation.tasks import TASKS, NavigationTask
from sppo_sb3.envs.navigation.world import FRAME_SKIP, World

if TYPE_CHECKING:
    from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

#: the reward's clip (Safety-Gymnasium's last resort against physics spikes)
REWARD_CLIP = 10.0
#: ``info`` key of a step that achieved the goal
GOAL_MET_KEY = "goal_met"
#: every navigation env alive in this process: a shield finds the simulator state of an observation among them
LIVE_ENVS: weakref.WeakSet[SafetyNavigationEnv] = weakref.WeakSet()


@dataclass
class NavigationState:
    """Everything a step of a navigation env depends on, within an episode (its layout of static objects aside).

    :param time: the simulation's time.
    :param qpos: MuJoCo's positions.
    :param qvel: MuJoCo's velocities.
    :param qacc_warmstart: the constraint solver's warm start (a step from the same state with another warm start
        agrees up to the solver's tolerance).
    :param mocap_pos: the mocap bodies' positions (gremlins).
    :param mocap_quat: the mocap bodies' orientations.
    :param goal_xy: where the goal is.
    :param task: the task's own state (:meth:`NavigationTask.state`: distances of the last step, the buttons' timer).
    """

    time: float
    qpos: np.ndarray
    qvel: np.ndarray
    qacc_warmstart: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    goal_xy: np.ndarray
    task: dict[str, float] = field(default_factory=dict)


class SafetyNavigationEnv(gym.Env[np.ndarray, np.ndarray], EzPickle):
    """A Safety-Gymnasium navigation task on gymnasium 1.x and MuJoCo 3+ (see the module).

    The observation is the robot's sensors (accelerometer, velocimeter, gyro, magnetometer; the Car adds its rear
    ball's angular velocity and rotation matrix) followed by a 16-bin pseudo-lidar per kind of object the task has, in
    Safety-Gymnasium's order; ``observation_keys`` names its slices.

    :param robot: ``"Point"`` or ``"Car"``.
    :param task: ``"Goal"``, ``"Button"``, ``"Push"`` or ``"Circle"``.
    :param level: 0, 1 or 2.
    :param alpha: the width of the shaped cost's band (eq. 18), in metres.
    :param render_mode: ``"human"``, ``"rgb_array"`` or ``"depth_array"``.
    :param width: rendered width in pixels.
    :param height: rendered height in pixels.
    :param camera_name: the camera that renders (``"fixednear"``, ``"fixedfar"`` or ``"track"``).
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array"], "render_fps": 30}  # noqa: RUF012

    def __init__(
        self,
        robot: str = "Point",
        task: str = "Goal",
        level: int = 1,
        alpha: float = 0.1,
        render_mode: str | None = None,
        width: int = 256,
        height: int = 256,
        camera_name: str = "fixedfar",
    ) -> None:
        EzPickle.__init__(self, robot, task, level, alpha, render_mode, width, height, camera_name)
        if robot not in ROBOTS:
            raise ValueError(f"unknown robot {robot!r}: the navigation robots are {', '.join(ROBOTS)}")
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}: the navigation tasks are {', '.join(TASKS)}")
        if alpha <= 0:
            raise ValueError(f"alpha (the shaped cost's band, eq. 18) must be > 0 metres, got {alpha}")
        self.task: NavigationTask = TASKS[task](level, ROBOTS[robot])
        self.world = World(ROBOTS[robot], self.task.groups)
        self.alpha = float(alpha)
        self.render_mode = render_mode
        self._gremlins = next((group for group in self.task.groups if isinstance(group, Gremlins)), None)
        self._rng: np.random.RandomState | None = None
        self.layout: dict[str, np.ndarray] = {}
        self._observation_layout()
        self.observation_keys = self._observation_keys()
        self.observation_space = self._observation_space()
        ctrlrange = self.world.model.actuator_ctrlrange
        self.action_space = spaces.Box(
            ctrlrange[:, 0].astype(np.float32), ctrlrange[:, 1].astype(np.float32), dtype=np.float32
        )
        self._renderer: MujocoRenderer | None = None
        self._render_size, self._camera_name = (width, height), camera_name
        self.last_obs: np.ndarray | None = None
        LIVE_ENVS.add(self)

    @classmethod
    def producing(cls, obs: np.ndarray, tolerance: float = 1e-6) -> SafetyNavigationEnv | None:
        """The live env of this process whose latest observation is ``obs`` (within ``tolerance`` per entry), if any.

        How a shield reads the simulator state behind an observation: the agent sees lidar, the shield the state of
        the env that produced it (the envs must run in this process: a ``DummyVecEnv``, not a ``SubprocVecEnv``).
        """
        obs = np.asarray(obs, dtype=np.float64).ravel()
        for env in list(LIVE_ENVS):
            last = env.last_obs
            if last is not None and last.shape == obs.shape and np.max(np.abs(last - obs)) <= tolerance:
                return env
        return None

    @property
    def model(self) -> mujoco.MjModel:
        """The MuJoCo model (compiled once; resets move its bodies)."""
        return self.world.model

    @property
    def data(self) -> mujoco.MjData:
        """The MuJoCo data."""
        return self.world.data

    # ------------------------------------------------------------------------------------------------- observation
    def _observation_keys(self) -> list[tuple[str, int]]:
        sensors = [
            (name, 9 if self._is_quat(name) else int(self.model.sensor(name).dim[0]))
            for name in self.world.robot.observed_sensors
        ]
        return sensors + [(f"{group.name}_lidar", NUM_BINS) for group in self.task.groups if group.lidar]

    def _observation_space(self) -> spaces.Box:
        bounds = [(0.0, 1.0) if key.endswith("_lidar") else (-np.inf, np.inf) for key, _ in self.observation_keys]
        sizes = [size for _, size in self.observation_keys]
        low, high = (np.repeat([bound[i] for bound in bounds], sizes) for i in (0, 1))
        return spaces.Box(low, high, dtype=np.float64)

    def _is_quat(self, name: str) -> bool:
        return bool(self.model.sensor(name).type[0] == mujoco.mjtSensor.mjSENS_BALLQUAT)

    def _observation_layout(self) -> None:
        """Where each sensor reads in ``sensordata``, and which bodies each lidar sees (cached for :meth:`observe`)."""
        self._sensors = [
            (int(self.model.sensor(name).adr[0]), int(self.model.sensor(name).dim[0]), self._is_quat(name))
            for name in self.world.robot.observed_sensors
        ]
        self._lidar_groups = [group for group in self.task.groups if group.lidar]
        self._lidar_bodies = np.array([self.model.body(body).id for group in self._lidar_groups for body in group.bodies])
        self._lidar_kinds = np.repeat(np.arange(len(self._lidar_groups)), [len(group.bodies) for group in self._lidar_groups])

    def observe(self) -> np.ndarray:
        """The observation of the current state."""
        sensordata = self.data.sensordata
        parts = []
        for adr, dim, is_quat in self._sensors:
            if is_quat:
                matrix = np.empty(9)
                mujoco.mju_quat2Mat(matrix, sensordata[adr : adr + dim])
                parts.append(matrix)
            else:
                parts.append(sensordata[adr : adr + dim])
        lidar = pseudo_lidar(
            self.data.xpos[self._lidar_bodies],
            self.world.agent_xpos(),
            self.world.agent_xmat(),
            self.task.lidar_max_dist,
            kinds=self._lidar_kinds,
            num_kinds=len(self._lidar_groups),
        )
        for row, group in enumerate(self._lidar_groups):
            if not self.task.observes(group):
                lidar[row] = 0.0
        return np.concatenate([*parts, lidar.ravel()])

    # ------------------------------------------------------------------------------------------------- reset, step
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None or self._rng is None:
            self._rng = np.random.RandomState(seed)
        rng = self._rng
        self.layout = self.task.sampler.sample(rng)
        agent_rot = random_rotation(rng)
        rotations = {group.name: [random_rotation(rng) for _ in group.names] for group in self.task.groups}
        self.world.place(self.layout, agent_rot, rotations)
        self.task.next_goal(self.world, rng, self.layout)
        self.task.after_reset()
        if self.render_mode == "human":
            self.render()
        self.last_obs = self.observe()
        return self.last_obs.copy(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._rng is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape:
            raise ValueError(f"action of shape {action.shape}, expected {self.action_space.shape}")
        substeps = int(self._rng.binomial(FRAME_SKIP, 1.0))  # always FRAME_SKIP; drawn to keep the RNG's stream
        self.world.step(action, substeps, self._gremlins)
        reward = float(np.clip(self.task.reward(self.world), -REWARD_CLIP, REWARD_CLIP))
        info = self.cost_info()
        self.task.tick()
        terminated = False
        if self.task.goal_achieved(self.world):
            info[GOAL_MET_KEY] = True
            self._update_layout()
            try:
                self.task.next_goal(self.world, self._rng, self.layout)
            except ResamplingError:
                terminated = True
        if self.render_mode == "human":
            self.render()
        self.last_obs = self.observe()
        return self.last_obs.copy(), reward, terminated, False, info

    def cost_terms(self) -> dict[str, float]:
        """Every constrained group's cost terms in the current state, before the indicator."""
        terms: dict[str, float] = {}
        for group in self.task.groups:
            terms.update(group.cost_terms(self.world, self.task.constrained_goal_button()))
        return terms

    def distance_to_unsafe(self) -> float:
        """The distance to the nearest constrained object in the current state (``inf``: nothing constrained)."""
        goal_button = self.task.constrained_goal_button()
        return min((group.distance_to_unsafe(self.world, goal_button) for group in self.task.groups), default=float("inf"))

    def cost_info(self) -> dict[str, Any]:
        """``info``'s cost entries: each term's indicator, ``cost`` (any term positive) and ``shaped_cost``."""
        terms = {key: float(value > 0) for key, value in self.cost_terms().items()}
        distance = self.distance_to_unsafe()
        shaped = 0.0 if np.isinf(distance) else float(shaped_cost(np.asarray(max(distance, 0.0)), self.alpha))
        return {**terms, COST_KEY: float(any(terms.values())), SHAPED_COST_KEY: max(shaped, float(any(terms.values())))}

    def _update_layout(self) -> None:
        """After a goal: the layout follows the objects that moved (all but gremlins), so a new goal keeps clear."""
        for name in self.layout:
            if not name.startswith("gremlin"):
                self.layout[name] = self.world.body_xpos((name,))[0, :2].copy()

    # ------------------------------------------------------------------------------------------------- state
    def get_state(self) -> NavigationState:
        """A copy of the state the next step depends on (see :class:`NavigationState`)."""
        data = self.data
        return NavigationState(
            float(data.time),
            data.qpos.copy(),
            data.qvel.copy(),
            data.qacc_warmstart.copy(),
            data.mocap_pos.copy(),
            data.mocap_quat.copy(),
            self.world.body_xpos(("goal",))[0, :2].copy() if self.task.has("goal") else np.zeros(2),
            self.task.state(),
        )

    def rng_state(self) -> tuple[list[int], int] | None:
        """The layout's random stream as it is now, its 624 keys and position (``None`` before the first reset): what
        :meth:`set_rng_state` restores."""
        if self._rng is None:
            return None
        _, keys, position, _, _ = self._rng.get_state()
        return [int(key) for key in keys], int(position)

    def set_rng_state(self, keys: np.ndarray, position: int) -> None:
        """Set the layout's random stream (a Mersenne Twister, as Safety-Gymnasium's ``RandomState``) to a recorded
        state: its 624 keys and position."""
        if self._rng is None:
            self._rng = np.random.RandomState()
        self._rng.set_state(("MT19937", np.asarray(keys, dtype=np.uint32), int(position), 0, 0.0))

    def set_state(self, state: NavigationState) -> None:
        """Restore a state of the current episode (the static objects stay where this episode's layout put them)."""
        data = self.data
        data.time = state.time
        data.qpos[:], data.qvel[:], data.qacc_warmstart[:] = state.qpos, state.qvel, state.qacc_warmstart
        data.mocap_pos[:], data.mocap_quat[:] = state.mocap_pos, state.mocap_quat
        if self.task.has("goal"):
            self.model.body_pos[self.model.body("goal").id, :2] = state.goal_xy
        self.task.set_state(state.task)
        mujoco.mj_forward(self.model, self.data)
        self.last_obs = self.observe()

    # ------------------------------------------------------------------------------------------------- rendering
    def render(self) -> np.ndarray | None:  # type: ignore[override]
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: pass render_mode='rgb_array' (or 'human') to gym.make")
            return None
        if self._renderer is None:
            from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

            width, height = self._render_size
            self._renderer = MujocoRenderer(self.model, self.data, width=width, height=height, camera_name=self._camera_name)
        return self._renderer.render(self.render_mode)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
