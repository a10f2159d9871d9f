"""The paper's tasks, registered with gymnasium on ``import sppo_sb3``: the constrained ones, Fig. 7's dm_control
suite tasks (``DMC-<domain>-<task>-v0``, :mod:`sppo_sb3.envs.dmc`; they need the ``dmc`` extra to be made) and
Safety-Gymnasium's velocity tasks (``sppo_sb3/Safety<Robot>Velocity-v1``, :mod:`sppo_sb3.envs.velocity`) and navigation
tasks (``sppo_sb3/Safety<Robot><Task><Level>-v0``, :mod:`sppo_sb3.envs.navigation`)."""

from gymnasium.envs.registration import register, registry

from sppo_sb3.envs.dmc import register_dmc_tasks
from sppo_sb3.envs.navigation import NAVIGATION_TASKS
from sppo_sb3.envs.point_circle import PointParams, SafePointCircleEnv
from sppo_sb3.envs.velocity import MAX_EPISODE_STEPS, VELOCITY_TASKS

if "SafePointCircle-v0" not in registry:
    register(id="SafePointCircle-v0", entry_point="sppo_sb3.envs.point_circle:SafePointCircleEnv", max_episode_steps=500)
if "SafeHalfCheetahHeight-v1" not in registry:
    register(
        id="SafeHalfCheetahHeight-v1",
        entry_point="sppo_sb3.envs.half_cheetah_height:SafeHalfCheetahHeightEnv",
        max_episode_steps=1000,
    )
for _task in VELOCITY_TASKS:
    if _task.env_id not in registry:
        register(
            id=_task.env_id,
            entry_point=_task.entry_point,
            max_episode_steps=MAX_EPISODE_STEPS,
            reward_threshold=_task.reward_threshold,
        )
for _nav in NAVIGATION_TASKS:
    if _nav.env_id not in registry:
        register(
            id=_nav.env_id,
            entry_point="sppo_sb3.envs.navigation:SafetyNavigationEnv",
            kwargs={"robot": _nav.robot, "task": _nav.task, "level": _nav.level},
            max_episode_steps=_nav.episode_steps,
        )
register_dmc_tasks()

__all__ = ["PointParams", "SafePointCircleEnv"]
