"""The paper's tasks, registered with gymnasium on ``import sppo_sb3``: the constrained ones and Fig. 7's dm_control
suite tasks (``DMC-<domain>-<task>-v0``, :mod:`sppo_sb3.envs.dmc`; they need the ``dmc`` extra to be made)."""

from gymnasium.envs.registration import register, registry

from sppo_sb3.envs.dmc import register_dmc_tasks
from sppo_sb3.envs.point_circle import PointParams, SafePointCircleEnv

if "SafePointCircle-v0" not in registry:
    register(id="SafePointCircle-v0", entry_point="sppo_sb3.envs.point_circle:SafePointCircleEnv", max_episode_steps=500)
if "SafeHalfCheetahHeight-v1" not in registry:
    register(
        id="SafeHalfCheetahHeight-v1",
        entry_point="sppo_sb3.envs.half_cheetah_height:SafeHalfCheetahHeightEnv",
        max_episode_steps=1000,
    )
register_dmc_tasks()

__all__ = ["PointParams", "SafePointCircleEnv"]
