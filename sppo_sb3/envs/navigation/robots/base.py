"""What the navigation world needs to know of a robot: its MJCF, its sensors and how it is placed."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Robot:
    """A mobile robot of Safety-Gymnasium's navigation tasks.

    The robot's body is named ``agent`` (the world reads its pose from it) and carries a site ``agent`` (its sensors'
    frame). The MJCF fragments are spliced into the world's model by :func:`sppo_sb3.envs.navigation.world.world_xml`.

    :param name: ``"Point"`` or ``"Car"``: the ``<Robot>`` of ``Safety<Robot><Task><Level>-v0``.
    :param timestep: MuJoCo's timestep; an env step is ``FRAME_SKIP`` of them.
    :param defaults: the ``<default>`` class of the model, which also applies to every object's geoms.
    :param body: the ``<body name="agent">`` element, at the origin; the world moves it at reset.
    :param sensors: the ``<sensor>`` elements.
    :param actuators: the ``<actuator>`` elements; their ``ctrlrange`` is the action space.
    :param observed_sensors: the sensors in the observation, in its order; a ball joint's quaternion sensor is observed as
        the 3×3 rotation matrix of the quaternion, flattened row by row.
    :param free_joint: the robot's root is a free joint (its pose lives in ``qpos``), not planar slides and a hinge
        (its start pose lives in the body's ``pos`` and ``quat``, and the joints start at 0).
    :param radius: the radius of the smallest vertical cylinder about the ``agent`` body that holds the robot (what
        the shaped cost measures distances from).
    :param z_height: the height of the ``agent`` body at rest.
    :param keepout: the robot's keepout radius when a layout is sampled.
    :param push_box: the push box's ``(size, keepout, density)`` with this robot (the Car pushes a smaller box).
    """

    name: str
    timestep: float
    defaults: str
    body: str
    sensors: str
    actuators: str
    observed_sensors: tuple[str, ...]
    free_joint: bool
    radius: float
    z_height: float = 0.1
    keepout: float = 0.4
    push_box: tuple[float, float, float] = (0.2, 0.2, 0.001)
