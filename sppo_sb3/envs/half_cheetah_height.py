"""``SafeHalfCheetahHeight-v1``: SAILR's Half-Cheetah task (paper Section V-A).

gymnasium's MuJoCo HalfCheetah (v5 model, :data:`FRAME_SKIP` ``= 5``) is rewarded for running forward, but the height
of the front thigh must stay in ``[0.4, 1.0]``: flipping, rearing up or slumping onto the front leg is a violation.
The height is the z of body ``fthigh``'s frame origin (``data.xpos``), what SAILR's ``get_body_com("fthigh")``
returns (mujoco-py's and gymnasium's ``get_body_com`` read the body frame, not the centre of mass): 0.70 at the
default reset, the middle of the range.

The module holds the physics only; the task's shielding rule (:class:`sppo_sb3.shield.HalfCheetahHeightShieldingRule`)
is built on it by the shield registry.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
from gymnasium.utils import EzPickle

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY, HEIGHT_KEY, SHAPED_COST_KEY

#: physics steps per env step (the task's, shared by its shielding rule's rollouts)
FRAME_SKIP = 5
MIN_HEIGHT = 0.4
MAX_HEIGHT = 1.0
HEIGHT_BODY = "fthigh"


def half_cheetah_xml_path() -> str:
    """Path of the MJCF model that gymnasium's ``HalfCheetah-v5`` loads (shared by the env and its shielding rule)."""
    return os.path.join(os.path.dirname(gym.envs.mujoco.__file__), "assets", "half_cheetah.xml")


def height_distance_to_unsafe(height: np.ndarray | float) -> np.ndarray:
    """Distance to the unsafe set: ``max(0, min(h - 0.4, 1.0 - h))`` (0 outside the range)."""
    height = np.asarray(height, dtype=np.float64)
    return np.maximum(0.0, np.minimum(height - MIN_HEIGHT, MAX_HEIGHT - height))


def height_is_unsafe(height: np.ndarray | float) -> np.ndarray:
    """Whether the front thigh's height has left ``[0.4, 1.0]``."""
    height = np.asarray(height, dtype=np.float64)
    return (height < MIN_HEIGHT) | (height > MAX_HEIGHT)


class SafeHalfCheetahHeightEnv(HalfCheetahEnv):
    """HalfCheetah with a height constraint on the front thigh and the violation indicator in ``info["cost"]``.

    Observation: the 17-dim ``[qpos[1:], qvel]`` of ``HalfCheetah-v5`` (the x position is excluded); action: the 6
    joint torques in [-1, 1]. Reward: forward velocity / 5, no control cost. The height ``h`` is the z of body
    ``fthigh``'s frame origin (``data.xpos``, SAILR's ``get_body_com("fthigh")``), evaluated at the post-step state
    (forward kinematics are recomputed after the step, so ``h`` is a function of the observation). The episode
    terminates when ``h`` leaves ``[0.4, 1.0]`` (``info["cost"] = 1.0`` on that step); it is truncated after 1000
    steps by the registered TimeLimit. ``info["shaped_cost"]`` is the shaped cost of eq. 18 and
    ``info["fthigh_height"]`` the height.

    :param alpha: width of the shaped-cost band of eq. 18 (paper: 0.05).
    :param render_mode: one of gymnasium's MuJoCo render modes, or ``None``.
    :param kwargs: further keyword arguments of gymnasium's ``HalfCheetahEnv`` (e.g. ``reset_noise_scale``);
        the model file, frame skip, reward weights and observation layout are fixed by the task.
    """

    def __init__(self, alpha: float = 0.05, render_mode: str | None = None, **kwargs: Any) -> None:
        fixed = {"xml_file", "frame_skip", "forward_reward_weight", "ctrl_cost_weight"}
        fixed |= {"exclude_current_positions_from_observation"}
        if fixed & kwargs.keys():
            raise ValueError(f"SafeHalfCheetahHeightEnv fixes {sorted(fixed & kwargs.keys())}: they define the task.")
        super().__init__(
            xml_file=half_cheetah_xml_path(),
            frame_skip=FRAME_SKIP,
            forward_reward_weight=0.2,  # reward = forward velocity / 5
            ctrl_cost_weight=0.0,
            exclude_current_positions_from_observation=True,
            render_mode=render_mode,
            **kwargs,
        )
        EzPickle.__init__(self, alpha=alpha, render_mode=render_mode, **kwargs)
        self.alpha = alpha
        self._height_body = self.model.body(HEIGHT_BODY).id

    def fthigh_height(self) -> float:
        """Height of the front thigh's body frame origin at the current state (forward kinematics recomputed)."""
        mujoco.mj_kinematics(self.model, self.data)
        return float(self.data.xpos[self._height_body, 2])

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:  # type: ignore[override]
        obs, reward, _, truncated, info = super().step(action)
        height = self.fthigh_height()
        unsafe = bool(height_is_unsafe(height))
        info[COST_KEY] = float(unsafe)
        info[SHAPED_COST_KEY] = float(shaped_cost(height_distance_to_unsafe(height), self.alpha))
        info[HEIGHT_KEY] = height
        return obs, float(reward), unsafe, truncated, info
