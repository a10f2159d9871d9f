"""The paper's Fig. 7 tasks: dm_control's suite through gymnasium, as TD-MPC runs them (``pip install "sppo_sb3[dmc]"``).

``DMC-<domain>-<task>-v0`` (for example ``DMC-cartpole-swingup-v0``) is shimmy's ``dm_control/<domain>-<task>-v0``
with its dict observation flattened into one vector (:class:`gymnasium.wrappers.FlattenObservation`) and each action
held for TD-MPC's action repeat (:data:`ACTION_REPEAT`: 8 for cartpole, 2 for walker and finger, 4 otherwise) by
:class:`ActionRepeat`. dm_control ends every episode after 1000 physics-control steps (truncation), i.e. after
``1000 / repeat`` steps of the wrapped env; the budgets of SB3 (``n_timesteps``) count wrapped-env steps, so TD-MPC's
"100k env steps" are ``100_000 / repeat`` of them.

The ids are registered on ``import sppo_sb3`` without importing dm_control (slow to import, and an optional extra):
:func:`make_dmc_env` imports it when an env is made and says how to install it when it is missing.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
from gymnasium.envs.registration import register, registry
from gymnasium.wrappers import FlattenObservation

#: TD-MPC's action repeat of each domain (the tasks not listed use :data:`DEFAULT_ACTION_REPEAT`)
ACTION_REPEAT: dict[str, int] = {"cartpole": 8, "walker": 2, "finger": 2}
DEFAULT_ACTION_REPEAT = 4
#: Fig. 7's six tasks, as ``<domain>-<task>``
FIG7_DMC_TASKS: tuple[str, ...] = (
    "cartpole-swingup",
    "finger-spin",
    "hopper-hop",
    "cheetah-run",
    "walker-run",
    "quadruped-run",
)
INSTALL_HINT = 'dm_control tasks need the dmc extra: pip install "sppo_sb3[dmc]"'


class ActionRepeat(gym.Wrapper):
    """Repeat each action ``repeat`` times, summing the rewards; stop early when the episode ends.

    The ``info`` returned is the last inner step's.

    :param env: the environment.
    :param repeat: inner steps per step (at least 1).
    """

    def __init__(self, env: gym.Env, repeat: int) -> None:
        if repeat < 1:
            raise ValueError(f"ActionRepeat: repeat must be at least 1, got {repeat}")
        super().__init__(env)
        self.repeat = repeat

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the inner env up to ``repeat`` times with ``action``.

        :param action: the action.
        :return: the last observation, the summed reward, and the last step's flags and info.
        """
        total = 0.0
        for _ in range(self.repeat):
            obs, reward, terminated, truncated, info = self.env.step(action)
            total += float(reward)
            if terminated or truncated:
                break
        return obs, total, terminated, truncated, info


def action_repeat(domain_task: str) -> int:
    """TD-MPC's action repeat of a ``<domain>-<task>``.

    :param domain_task: for example ``"cartpole-swingup"``.
    """
    return ACTION_REPEAT.get(domain_task.split("-", 1)[0], DEFAULT_ACTION_REPEAT)


def dmc_id(domain_task: str) -> str:
    """The package's gymnasium id of a ``<domain>-<task>`` (``DMC-cartpole-swingup-v0``).

    :param domain_task: for example ``"cartpole-swingup"``.
    """
    return f"DMC-{domain_task}-v0"


def make_dmc_env(domain_task: str, repeat: int | None = None, **kwargs: Any) -> gym.Env:
    """shimmy's ``dm_control/<domain_task>-v0``, observations flattened, actions repeated.

    :param domain_task: for example ``"cartpole-swingup"``.
    :param repeat: action repeat (``None``: TD-MPC's, :func:`action_repeat`).
    :param kwargs: passed to ``gymnasium.make`` (``render_mode``, ``task_kwargs``, ...).
    :raises ImportError: dm_control or shimmy is not installed.
    """
    try:
        import shimmy  # noqa: F401  (registers dm_control/... with gymnasium)
        from dm_control import suite  # noqa: F401
    except ImportError as exc:
        raise ImportError(f"{INSTALL_HINT} ({exc})") from exc
    env = FlattenObservation(gym.make(f"dm_control/{domain_task}-v0", **kwargs))
    return ActionRepeat(env, action_repeat(domain_task) if repeat is None else repeat)


def register_dmc_tasks() -> None:
    """Register ``DMC-<domain>-<task>-v0`` for :data:`FIG7_DMC_TASKS` (no dm_control import)."""
    for domain_task in FIG7_DMC_TASKS:
        if dmc_id(domain_task) not in registry:
            register(id=dmc_id(domain_task), entry_point="sppo_sb3.envs.dmc:make_dmc_env", kwargs={"domain_task": domain_task})
