"""``SafePointCircle-v0``: SAILR's Point Robot task (paper Section V-A-1, the constrained task of Table I).

A point mass is rewarded for running fast around the circle of radius 5 but must keep ``|x| <= 2.5``: the optimal
safe behaviour runs along the wall segments of the circle's inscribed strip. The violation indicator ``c(s, a)`` is
that of Definition 1 and the shaped cost that of eq. 18.

The module holds the physics only; the task's shielding rule (:class:`sppo_sb3.shield.PointCircleShieldingRule`) is
built on it by the shield registry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY, SHAPED_COST_KEY


@dataclass(frozen=True)
class PointParams:
    """Physical constants and the safe set of the Point Robot.

    :param mass: point mass ``m``.
    :param dt: integration step.
    :param max_speed: the speed is clipped to this norm after every step.
    :param x_limit: unsafe iff ``|x| > x_limit``.
    :param y_limit: unsafe iff ``|y| > y_limit``.
    :param radius: radius of the circle the reward asks to track.
    """

    mass: float = 1.0
    dt: float = 0.1
    max_speed: float = 2.0
    x_limit: float = 2.5
    y_limit: float = 15.0
    radius: float = 5.0


def point_step(state: np.ndarray, action: np.ndarray, params: PointParams) -> np.ndarray:
    """One step of the point-mass dynamics on a batch: ``p += v·dt + a·dt²/(2m)``, ``v += a·dt/m``, speed clipped.

    :param state: ``(..., 4)`` states ``[x, y, vx, vy]``.
    :param action: ``(..., 2)`` forces, already clipped to [-1, 1].
    :param params: the task constants.
    :return: the next states, same shape as ``state``.
    """
    pos, vel = state[..., :2], state[..., 2:]
    new_pos = pos + vel * params.dt + action * params.dt**2 / (2.0 * params.mass)
    new_vel = vel + action * params.dt / params.mass
    speed = np.linalg.norm(new_vel, axis=-1, keepdims=True)
    new_vel = new_vel * np.minimum(1.0, params.max_speed / np.maximum(speed, 1e-12))
    return np.concatenate([new_pos, new_vel], axis=-1)


def point_reward(state: np.ndarray, params: PointParams) -> np.ndarray:
    """Circle-tracking reward on the pre-step state: ``v·[-y, x] / (1 + |‖p‖ - r|) / 10``."""
    x, y, vx, vy = state[..., 0], state[..., 1], state[..., 2], state[..., 3]
    return (vx * -y + vy * x) / (1.0 + np.abs(np.hypot(x, y) - params.radius)) / 10.0


def point_distance_to_unsafe(state: np.ndarray, params: PointParams) -> np.ndarray:
    """Distance from each state to the unsafe set (0 inside it)."""
    margin_x = params.x_limit - np.abs(state[..., 0])
    margin_y = params.y_limit - np.abs(state[..., 1])
    return np.maximum(0.0, np.minimum(margin_x, margin_y))


def point_is_unsafe(state: np.ndarray, params: PointParams) -> np.ndarray:
    """Whether each state lies in the unsafe set ``|x| > x_limit or |y| > y_limit``."""
    return (np.abs(state[..., 0]) > params.x_limit) | (np.abs(state[..., 1]) > params.y_limit)


class SafePointCircleEnv(gym.Env[np.ndarray, np.ndarray]):
    """Point Robot circle task with the violation indicator in ``info["cost"]``.

    Observation ``[x, y, vx, vy]``; action: a 2-D force in [-1, 1]. The episode terminates when the robot enters the
    unsafe set (``info["cost"] = 1.0`` on that step); it is truncated after 500 steps by the registered TimeLimit.

    The velocity bounds of the observation space are ``±max_speed`` (= 2): SAILR's code declares ±1, but the
    speed is clipped to 2, so ±1 would put reachable observations outside the declared space.

    :param alpha: width of the shaped-cost band of eq. 18, reported as ``info["shaped_cost"]``.
    :param render_mode: only ``None`` and ``"rgb_array"`` are supported.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}  # noqa: RUF012
    observation_space: gym.spaces.Box

    def __init__(self, alpha: float = 0.05, render_mode: str | None = None) -> None:
        self.params = PointParams()
        self.alpha = alpha
        self.render_mode = render_mode
        high = np.array([15.0, 15.0, self.params.max_speed, self.params.max_speed], dtype=np.float32)
        self.observation_space = gym.spaces.Box(-high, high, dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.state = np.zeros(4)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.state = np.zeros(4)
        self.state[:2] = self.np_random.uniform(-0.1, 0.1, size=2)
        return self.state.astype(np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        reward = float(point_reward(self.state, self.params))
        self.state = point_step(self.state, action, self.params)
        unsafe = bool(point_is_unsafe(self.state, self.params))
        dist = point_distance_to_unsafe(self.state, self.params)
        info = {COST_KEY: float(unsafe), SHAPED_COST_KEY: float(shaped_cost(dist, self.alpha))}
        obs = np.clip(self.state, self.observation_space.low, self.observation_space.high).astype(np.float32)
        return obs, reward, unsafe, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        size, scale = 200, 200 / 30.0
        img = np.full((size, size, 3), 255, dtype=np.uint8)
        wall = int((15 - self.params.x_limit) * scale), int((15 + self.params.x_limit) * scale)
        img[:, wall[0]] = img[:, wall[1]] = (200, 0, 0)
        ang = np.linspace(0, 2 * np.pi, 400)
        ring = ((15 + self.params.radius * np.stack([np.cos(ang), np.sin(ang)], 1)) * scale).astype(int).clip(0, size - 1)
        img[size - 1 - ring[:, 1], ring[:, 0]] = (0, 160, 0)
        px, py = ((15 + self.state[:2]) * scale).astype(int).clip(2, size - 3)
        img[size - 1 - py - 2 : size - py + 1, px - 2 : px + 3] = 0
        return img


def scripted_lap_action(state: np.ndarray, x_target: float, params: PointParams) -> np.ndarray:
    """A scripted lap: run anticlockwise at full speed around the circle, cut to the strip ``|x| <= x_target``.

    The desired velocity follows the circle's tangent with a radial pull back to it; towards the wall its ``x`` part is
    capped by the speed that a braking of 90% force still stops at ``x_target``, and the speed freed is put along the
    wall. The force is what reaches the desired velocity in one step, clipped to the action box. A reference for what
    the task's return allows, with and without a shield, not a policy to learn from.

    :param state: one state ``[x, y, vx, vy]``.
    :param x_target: the ``|x|`` the lap runs along the walls at.
    :param params: the task constants.
    :return: the action, in [-1, 1]².
    """
    x, y, velocity = state[0], state[1], state[2:4]
    r = math.hypot(x, y)
    out = np.array([x, y]) / r if r > 1e-6 else np.array([0.0, 1.0])
    tangent = np.array([-out[1], out[0]])
    desired = params.max_speed * tangent + (params.radius - r) * out
    cap = max(math.sqrt(2.0 * 0.9 * max(x_target - abs(x), 0.0)) - 0.05, 0.0)
    if desired[0] * x > 0 and abs(desired[0]) > cap:
        desired[0] = math.copysign(cap, x)
        desired[1] = math.copysign(math.sqrt(max(params.max_speed**2 - cap**2, 0.0)), tangent[1])
    speed = float(np.linalg.norm(desired))
    if speed > params.max_speed:
        desired *= params.max_speed / speed
    return np.clip(params.mass * (desired - velocity) / params.dt, -1.0, 1.0)
