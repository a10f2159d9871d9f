"""Action repeat: the agent acts every ``repeat`` env steps and the env steps in between hold its action.

The field's model-based agents plan at about 0.1 s whatever the simulator's step: TD-MPC holds each action for 2–8
steps on dm_control, OmniSafe's model-based agents and SafeDreamer for 5 on Safety-Gymnasium's navigation tasks
(20 ms steps). The agent's step is then the held action's whole run: its reward is the sum of the env steps' rewards,
``info["cost"]`` the sum of their costs, and the info says how many env steps ran (``info["env_steps"]``) and how many
of them had a cost (``info["costly_steps"]``), so that the safety metrics count env steps, not agent steps.

:class:`ActionRepeat` holds an action unshielded. Behind a shield use
``ShieldWrapper(env, rule, action_repeat=repeat)`` instead: it checks every env step inside the repeat, so that no
held step goes unchecked.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym

from sppo_sb3.common.keys import COST_KEY, COSTLY_STEPS_KEY, ENV_STEPS_KEY


def check_action_repeat(repeat: int) -> None:
    """Reject an action repeat that is not a positive whole number of env steps."""
    if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
        raise ValueError(f"action_repeat is how many env steps each action is held for, an int >= 1; got {repeat!r}.")


def check_held_steps_are_shielded(env: Any, owner: str) -> None:
    """Refuse to shield an env whose :class:`ActionRepeat` holds actions where no shield sees them.

    A shield outside an unshielded repeat checks the first env step of each held action and none of the others: it
    would fail open. ``ShieldWrapper(env, rule, action_repeat=k)`` checks them all.

    :param env: a gymnasium env or an SB3 VecEnv.
    :param owner: who shields it, for the message.
    :raises ValueError: ``env`` holds actions in an :class:`ActionRepeat`.
    """
    if hasattr(env, "env_is_wrapped"):  # a VecEnv: any of its envs
        held = any(env.env_is_wrapped(ActionRepeat))
    else:
        held, inner = False, env
        while isinstance(inner, gym.Wrapper) and not held:
            held, inner = isinstance(inner, ActionRepeat), inner.env
    if held:
        raise ValueError(
            f"{owner} would shield only the first env step of each action that ActionRepeat holds, and none of the "
            "others. Hold the actions behind the shield instead: ShieldWrapper(env, rule, action_repeat=k) checks every "
            "env step (and remove the ActionRepeat)."
        )


class HeldSteps:
    """What the env steps of one held action add up to: reward, cost, costly steps and env steps."""

    def __init__(self) -> None:
        self.reward = 0.0
        self.cost = 0.0
        self.costly_steps = 0
        self.env_steps = 0
        self._has_cost = False

    def add(self, reward: SupportsFloat, info: dict[str, Any]) -> None:
        """Count one env step with its reward and info."""
        self.reward += float(reward)
        self.env_steps += 1
        if COST_KEY in info:
            cost = float(info[COST_KEY])
            self.cost += cost
            self.costly_steps += int(cost > 0)
            self._has_cost = True

    def write(self, info: dict[str, Any]) -> dict[str, Any]:
        """The last env step's info with the held action's totals (``info["cost"]`` only where the env reports it)."""
        totals: dict[str, Any] = {ENV_STEPS_KEY: self.env_steps}
        if self._has_cost:
            totals.update({COST_KEY: self.cost, COSTLY_STEPS_KEY: self.costly_steps})
        return {**info, **totals}


class ActionRepeat(gym.Wrapper):
    """Hold each action for ``repeat`` env steps (fewer where the episode ends first), unshielded.

    :param env: the env.
    :param repeat: env steps per action.
    """

    def __init__(self, env: gym.Env, repeat: int) -> None:
        check_action_repeat(repeat)
        super().__init__(env)
        self.repeat = repeat

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        held = HeldSteps()
        for _ in range(self.repeat):
            obs, reward, terminated, truncated, info = self.env.step(action)
            held.add(reward, info)
            if terminated or truncated:
                break
        return obs, held.reward, terminated, truncated, held.write(info)
