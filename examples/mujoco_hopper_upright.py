"""Bring your own MuJoCo task: gymnasium's Hopper that must keep its torso upright, shielded by the general MuJoCo rule.

A user of a gymnasium MuJoCo env writes no shield: only the unsafe set, as a
:class:`~sppo_sb3.shield.StateConstraint` on the simulator state. :class:`~sppo_sb3.shield.MujocoShieldingRule` then
rolls the env's own model from the state it rebuilds from the observation: an MPPI backup that keeps away from the
unsafe set, and ``Q̄`` of "``a``, then the backup", with certificates that spare most solves.

Here the hopper's torso pitch (``qpos[2]``) must stay within ``±`` :data:`MAX_PITCH`: an upright-hopping task.

1. the constraint: :class:`TorsoUpright`, a predicate and a distance of each rolled env step;
2. the task: ``Hopper-v4`` reporting the violation in ``info["cost"]`` and ending the episode there (the unsafe set is
   absorbing, as the shield's guarantee assumes);
3. the rule, registered for the task: SPPO finds it with ``shield="auto"``; ``ShieldWrapper`` shields SB3's SAC.

Run ``python examples/mujoco_hopper_upright.py`` (a few minutes on 2 cores).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import register, registry
from stable_baselines3 import SAC
from stable_baselines3.common.monitor import Monitor

from sppo_sb3 import SPPO
from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY, SHAPED_COST_KEY
from sppo_sb3.common.safety import SafetyMetrics
from sppo_sb3.shield import ConstraintSteps, MujocoShieldingRule, ShieldWrapper, StateConstraint, register_shielding_rule

ENV_ID = "HopperUpright-v0"
MAX_PITCH = 0.2  # rad; gymnasium's Hopper ends its episode beyond 1.0 (its healthy angle range)
ALPHA = 0.05  # rad: the shaped cost of eq. 18 rises over the last 0.05 rad before the limit


# ------------------------------------------------------------------------------------------ 1. the constraint
class TorsoUpright(StateConstraint):
    """Unsafe iff the torso's pitch ``qpos[2]`` after the step leaves ``[-max_pitch, max_pitch]``."""

    def __init__(self, max_pitch: float = MAX_PITCH) -> None:
        self.max_pitch = max_pitch

    def is_unsafe(self, steps: ConstraintSteps) -> np.ndarray:
        return np.abs(steps.qpos(steps.after)[..., 2]) > self.max_pitch

    def distance(self, steps: ConstraintSteps) -> np.ndarray:
        return np.maximum(0.0, self.max_pitch - np.abs(steps.qpos(steps.after)[..., 2]))


# ------------------------------------------------------------------------------------------------ 2. the task
class UprightCost(gym.Wrapper):
    """``info["cost"]``: 1.0 on the step whose torso ends pitched beyond the limit, which also ends the episode."""

    def step(self, action: np.ndarray) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        pitch = abs(float(self.env.unwrapped.data.qpos[2]))
        unsafe = pitch > MAX_PITCH
        info[COST_KEY] = float(unsafe)
        info[SHAPED_COST_KEY] = float(shaped_cost(max(0.0, MAX_PITCH - pitch), ALPHA))
        return obs, reward, terminated or unsafe, truncated, info


def make_upright_hopper(**kwargs: Any) -> gym.Env:
    return UprightCost(gym.make("Hopper-v4", **kwargs))


if ENV_ID not in registry:
    register(id=ENV_ID, entry_point=make_upright_hopper, max_episode_steps=1000)


# ------------------------------------------------------------------------------------------------ 3. the rule
def upright_rule() -> MujocoShieldingRule:
    """The general MuJoCo rule on the task's own model; η and α in the shaped cost's units (see docs/guide/custom_tasks.md)."""
    return MujocoShieldingRule(ENV_ID, TorsoUpright(), alpha=ALPHA, eta=0.2, horizon=10, n_particles=32)


register_shielding_rule(ENV_ID, upright_rule)


def main(steps: int = 1500, learning_starts: int = 500) -> dict[str, tuple[int, int]]:
    """SPPO (``shield="auto"``) and SAC behind ``ShieldWrapper``, ``steps`` each: (violations, interventions)."""
    sppo = SPPO(
        "TOLDPolicy",
        ENV_ID,
        seed=0,
        learning_starts=learning_starts,
        batch_size=64,
        horizon=3,
        policy_kwargs=dict(latent_dim=32, encoder_dim=64, hidden_dim=128),
        planner_kwargs=dict(num_samples=64, num_elites=8, iterations=2),
    ).learn(steps)
    sac = SAC("MlpPolicy", Monitor(ShieldWrapper(gym.make(ENV_ID), upright_rule())), seed=0, learning_starts=learning_starts)
    metrics = SafetyMetrics(n_envs=1)

    def count(locals_: dict[str, Any], _: Any) -> bool:
        metrics.update_from_infos(locals_["rewards"], locals_["dones"], locals_["infos"])
        return True

    sac.learn(steps, callback=count)
    results = {
        "sppo": (sppo.safety_metrics.violations, sppo.safety_metrics.interventions),
        "sac": (metrics.violations, metrics.interventions),
    }
    for name, (violations, interventions) in results.items():
        print(f"{name}: {steps} training steps, violations={violations}, shield interventions={interventions}")
    return results


if __name__ == "__main__":
    main()
