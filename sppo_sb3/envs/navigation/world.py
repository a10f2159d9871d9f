"""The simulation of a navigation task: one MuJoCo model per env, its objects moved to each new layout at reset.

Safety-Gymnasium rebuilds the model from XML at every reset. Here the model is compiled once, with every body at the
origin, and a reset writes the layout into it: static bodies through ``body_pos`` / ``body_quat``, free bodies
through ``qpos``, gremlins through their marker's ``geom_pos`` and their weld's relative pose. The model's body,
joint and geom order is Safety-Gymnasium's (robot, free bodies, mocap bodies, static bodies), so ``qpos`` and
``qvel`` index the same coordinates as there.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from sppo_sb3.envs.navigation.objects import Gremlins, ObjectGroup, rot2quat
from sppo_sb3.envs.navigation.robots import Robot

#: MuJoCo steps per env step (Safety-Gymnasium's ``frameskip_binom_n``, drawn with ``p = 1``)
FRAME_SKIP = 10
#: the floor's half sides (for rendering; the plane is infinite for contacts)
FLOOR_SIZE = (3.5, 3.5, 0.1)


def world_xml(robot: Robot, groups: Sequence[ObjectGroup], shield_model: bool = False) -> str:
    """The MJCF of a task's world: floor, robot, then free, mocap and static bodies, in Safety-Gymnasium's order.

    :param shield_model: the model a shield rolls for every layout: every object is a mocap body, its position part
        of the state; the movable ones (vases, the push box, gremlins) are markers without geoms, as if the robot
        pushed them away without effort (they weigh 0.2-1.3% of the Point).
    """
    if shield_model:
        static = [group.body_xml(name, mocap=True) for group in groups if group.mount == "static" for name in group.names]
        markers = [
            f'<body name="{body}" mocap="true"/>' for group in groups if group.mount != "static" for body in moved(group)
        ]
        free, mocaps, welds = markers, [], []
    else:
        free = [group.body_xml(name) for group in groups if group.mount in ("free", "mocap") for name in group.names]
        gremlins = [group for group in groups if isinstance(group, Gremlins)]
        mocaps = [group.mocap_xml(name) for group in gremlins for name in group.names]
        welds = [group.weld_xml(name) for group in gremlins for name in group.names]
        static = [group.body_xml(name) for group in groups if group.mount == "static" for name in group.names]
    return f"""
<mujoco model="navigation">
  <option timestep="{robot.timestep}"/>
  <default>{robot.defaults}</default>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.9 0.9 0.9" rgb2="0.8 0.8 0.8" width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="8 8"/>
  </asset>
  <worldbody>
    <light directional="true" pos="0 0 0.5" dir="0 0 -1" diffuse="1 1 1" specular="0 0 0" castshadow="false"/>
    <geom name="floor" type="plane" size="{" ".join(map(str, FLOOR_SIZE))}" condim="6" material="grid" rgba="1 1 1 1"/>
    <camera name="fixednear" pos="0 -2 2" zaxis="0 -1 1"/>
    <camera name="fixedfar" pos="0 -5 5" zaxis="0 -1 1"/>
    {robot.body}
    {"".join(free + mocaps + static)}
  </worldbody>
  <equality>{"".join(welds)}</equality>
  <sensor>{robot.sensors}</sensor>
  <actuator>{robot.actuators}</actuator>
</mujoco>"""


def moved(group: ObjectGroup) -> list[str]:
    """The names of the bodies of a movable group (a gremlin's is its free body's, ``gremlin0obj``)."""
    return [group.object_name(name) for name in group.names] if isinstance(group, Gremlins) else group.names


class World:
    """A navigation task's MuJoCo model and data, with the queries its rewards, costs and observations need.

    :param robot: the robot.
    :param groups: the task's objects, in Safety-Gymnasium's order (static kinds, then free, then mocap).
    """

    def __init__(self, robot: Robot, groups: Sequence[ObjectGroup]) -> None:
        self.robot = robot
        self.groups = tuple(groups)
        self.model = mujoco.MjModel.from_xml_string(world_xml(robot, groups))
        self.data = mujoco.MjData(self.model)
        self.agent_id = self.model.body("agent").id
        self._agent_geoms = self.model.body_rootid[self.model.geom_bodyid] == self.agent_id  # the Car's wheels too
        self._geom_names = [self.model.geom(i).name for i in range(self.model.ngeom)]
        self._masks: dict[tuple[str, bool], np.ndarray] = {}
        self._ids: dict[tuple[str, ...], np.ndarray] = {}
        self._jacobian = np.zeros((3, self.model.nv))

    # ------------------------------------------------------------------------------------------------- placement
    def place(self, layout: dict[str, np.ndarray], agent_rot: float, rotations: dict[str, list[float]]) -> None:
        """Reset the simulation to a new layout.

        :param layout: every object's ``(x, y)`` by layout name, ``"agent"`` included.
        :param agent_rot: the robot's heading.
        :param rotations: each group's objects' headings, by the group's name.
        """
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        pose = np.r_[layout["agent"], self.robot.z_height, rot2quat(agent_rot)]
        if self.robot.free_joint:
            self._set_free_joint("agent", pose)
        else:
            model.body_pos[self.agent_id], model.body_quat[self.agent_id] = pose[:3], pose[3:]
        for group in self.groups:
            for index, (name, rot) in enumerate(zip(group.names, rotations[group.name], strict=True)):
                self._place_object(group, index, name, np.r_[layout[name], group.height()], rot)
        data.qpos[:] = model.qpos0
        mujoco.mj_forward(model, data)

    def _place_object(self, group: ObjectGroup, index: int, name: str, pos: np.ndarray, rot: float) -> None:
        model = self.model
        quat = rot2quat(group.rotation(index, rot))
        if isinstance(group, Gremlins):
            obj, mocap = group.object_name(name), group.mocap_name(name)
            self._set_free_joint(obj, np.r_[pos, quat])
            marker = model.geom(mocap).id
            model.geom_pos[marker], model.geom_quat[marker] = pos, quat
            model.eq_data[model.equality(mocap).id, 3:10] = np.r_[pos, quat]  # the weld's pose of obj in mocap's frame
        elif group.mount == "free":
            self._set_free_joint(name, np.r_[pos, quat])
        else:
            body = model.body(name).id
            model.body_pos[body], model.body_quat[body] = pos, quat

    def _set_free_joint(self, joint: str, pose: np.ndarray) -> None:
        address = self.model.jnt_qposadr[self.model.joint(joint).id]
        self.model.qpos0[address : address + 7] = pose

    def move_goal(self, xy: np.ndarray) -> None:
        """Move the goal's body to ``xy`` (its height unchanged)."""
        self.model.body_pos[self.model.body("goal").id, :2] = xy
        mujoco.mj_forward(self.model, self.data)

    # ------------------------------------------------------------------------------------------------- simulation
    def step(self, ctrl: np.ndarray, substeps: int, gremlins: Gremlins | None) -> None:
        """``substeps`` MuJoCo steps under ``ctrl`` (clipped to the actuators' ranges), gremlins moved before each."""
        model, data = self.model, self.data
        data.ctrl[:] = np.clip(ctrl, model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1])
        if gremlins is None:
            mujoco.mj_step(model, data, nstep=substeps)
        else:
            for _ in range(substeps):
                data.mocap_pos[:] = gremlins.mocap_target(data.time)
                mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)

    # ------------------------------------------------------------------------------------------------- queries
    def agent_xpos(self) -> np.ndarray:
        """The robot body's position."""
        return self.data.xpos[self.agent_id]

    def agent_xmat(self) -> np.ndarray:
        """The robot body's orientation, as a 3×3 rotation matrix."""
        return self.data.xmat[self.agent_id].reshape(3, 3)

    def agent_velocity(self) -> np.ndarray:
        """The linear velocity of the robot body's origin, in the world frame."""
        return self.body_linear_velocities(("agent",))[0]

    def body_xpos(self, names: Sequence[str]) -> np.ndarray:
        """The positions of the named bodies, ``(n, 3)``."""
        return self.data.xpos[self._body_ids(tuple(names))]

    def agent_planar_distances(self, positions: np.ndarray) -> np.ndarray:
        """The xy distances from the robot body to ``positions`` (``(n, 2)`` or ``(n, 3)``)."""
        delta = np.asarray(positions)[:, :2] - self.agent_xpos()[:2]
        return np.sqrt(delta[:, 0] ** 2 + delta[:, 1] ** 2)  # Safety-Gymnasium's sum of the two squares, in its order

    def body_linear_velocities(self, names: Sequence[str]) -> np.ndarray:
        """The linear velocities of the named bodies' origins in the world frame (their translational Jacobians
        times ``qvel``), ``(n, 3)``."""
        velocities = np.empty((len(names), 3))
        for row, body in enumerate(self._body_ids(tuple(names))):
            mujoco.mj_jacBody(self.model, self.data, self._jacobian, None, body)
            velocities[row] = self._jacobian @ self.data.qvel
        return velocities

    def agent_contacts(self, prefix: str, exact: bool = False) -> int:
        """How many of this step's contacts are between the robot and a geom named ``prefix…`` (or ``prefix``)."""
        pair = self.data.contact.geom[: self.data.ncon]
        if not len(pair):
            return 0
        other = self._named(prefix, exact)
        agent = self._agent_geoms
        touching = (agent[pair[:, 0]] & other[pair[:, 1]]) | (agent[pair[:, 1]] & other[pair[:, 0]])
        return int(np.count_nonzero(touching))

    def _named(self, prefix: str, exact: bool) -> np.ndarray:
        key = (prefix, exact)
        if key not in self._masks:
            self._masks[key] = np.array([(n == prefix) if exact else n.startswith(prefix) for n in self._geom_names])
        return self._masks[key]

    def _body_ids(self, names: tuple[str, ...]) -> np.ndarray:
        if names not in self._ids:
            self._ids[names] = np.array([self.model.body(name).id for name in names], dtype=np.int64)
        return self._ids[names]
