"""A safe task nobody tuned: Pendulum-v1 with ``|θ̇| <= 4 rad/s``, shielded by a hand-written rule.

The constraint: the pendulum's angular speed must stay at or below 4 rad/s; a faster step is a violation
(``info["cost"] = 1``) and ends the episode. Swinging up needs about 7.7 rad/s at the bottom, so the constrained
optimum is to swing as high as the speed limit allows. The rule (see docs/guide/custom_tasks.md, "Designing your own
safe task"):

- backup ``ζ``: brake — the torque that stops the pendulum in one step, clipped to Pendulum's ±2;
- ``Q̄(s, a)``: "take ``a``, then brake", rolled on Pendulum's own equations for ``HORIZON`` steps, summing the
  shaped cost of eq. 18 on the distance ``4 - |θ̇|`` (band ``α = 1`` rad/s), absorbing at a violation;
- raw observations ``[cos θ, sin θ, θ̇]``, torques in N·m (the env's units);
- the episode starts hanging (``|θ - π| <= 1``, slow), where braking alone never violates: no shield can save a
  state where the backup itself fails (from upright at rest, even full braking reaches 4.7 rad/s at the bottom);
- rewards shifted to [0, 1] so that the absorbing reward ``R̃ = -1`` is worse than carrying on (with Pendulum's own
  rewards, -16..0 per step, ending the episode through an intervention is cheaper than continuing).

Without Pendulum's equations, only the brake and the speed limit known: ``shield="ConstrainedPendulum-v0:learned"``
(:func:`learned_pendulum_rule`, the dynamics learned from SPPO's buffer).

Run ``python examples/constrained_pendulum.py`` (SPPO with and without the shield, and SB3's SAC behind
``ShieldWrapper``); with the zoo CLI, from the repository root: ``sppo-train --algo sppo --env ConstrainedPendulum-v0
--gym-packages examples.constrained_pendulum -conf hyperparams/sppo.yml`` (``--gym-packages`` imports the module,
which registers the env and its rules).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.pendulum import PendulumEnv
from gymnasium.envs.registration import register, registry
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from sppo_sb3 import SPPO
from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY
from sppo_sb3.common.safety import SafetyMetrics
from sppo_sb3.shield import LatentModelRule, LearnedDynamicsRule, ShieldingRule, ShieldWrapper, register_shielding_rule

ENV_ID = "ConstrainedPendulum-v0"
MAX_SPEED = 4.0  # rad/s: the constraint
G, M, L, DT = 10.0, 1.0, 1.0, 0.05  # Pendulum-v1's constants
MAX_TORQUE, SPEED_CLIP = 2.0, 8.0
WORST_REWARD = -(np.pi**2 + 0.1 * SPEED_CLIP**2 + 0.001 * MAX_TORQUE**2)  # Pendulum's lowest reward per step


# ------------------------------------------------------------------------------------------------- 1. the task
def pendulum_step(state: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """Pendulum-v1's dynamics on a batch (``θ = 0`` upright).

    :param state: ``(B, 2)`` states ``[θ, θ̇]``.
    :param torque: ``(B, 1)`` torques, clipped to ±2 N·m here.
    :return: the next states ``(B, 2)``.
    """
    theta, speed = state[:, 0], state[:, 1]
    u = np.clip(torque[:, 0], -MAX_TORQUE, MAX_TORQUE)
    speed = np.clip(speed + (3 * G / (2 * L) * np.sin(theta) + 3.0 / (M * L**2) * u) * DT, -SPEED_CLIP, SPEED_CLIP)
    return np.stack([theta + speed * DT, speed], axis=1)


def states_from_obs(obs: np.ndarray) -> np.ndarray:
    """``[cos θ, sin θ, θ̇]`` observations → ``[θ, θ̇]`` states, shape ``(B, 2)``."""
    return np.stack([np.arctan2(obs[:, 1], obs[:, 0]), obs[:, 2]], axis=1).astype(np.float64)


class ConstrainedPendulumEnv(PendulumEnv):
    """Pendulum-v1 with ``|θ̇| <= 4``: a violation costs 1 and ends the episode; rewards in [0, 1]; hanging starts.

    ``info["shaped_cost"]`` is ``ĉ`` of eq. 18 on the distance ``4 - |θ̇|``.

    :param alpha: band of eq. 18 (rad/s) for ``info["shaped_cost"]``.
    """

    def __init__(self, alpha: float = 1.0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.alpha = alpha

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed, options=options)
        self.state = np.array([np.pi + self.np_random.uniform(-1.0, 1.0), self.np_random.uniform(-0.5, 0.5)])
        return self._get_obs(), {}

    def step(self, u: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, _, truncated, info = super().step(u)
        speed = abs(float(self.state[1]))
        violated = speed > MAX_SPEED
        info[COST_KEY] = float(violated)
        info["shaped_cost"] = float(shaped_cost(max(0.0, MAX_SPEED - speed), self.alpha))
        return obs, 1.0 - float(reward) / WORST_REWARD, violated, truncated, info


# ------------------------------------------------------------------------------------------------- 2. the rule
class PendulumBrakeRule(ShieldingRule):
    """Backup ``ζ``: brake. ``Q̄(s, a) = Σ_t γ^(t+1) ĉ(s_(t+1))`` along "apply ``a``, then brake" (eqs. 12, 18).

    A rollout that violates is absorbed there (``ĉ = 1`` forever: ``γ^(t+1)/(1-γ)``). With ``γ = 0.99`` and
    ``horizon = 40``, any violation within the horizon costs at least ``γ^40/(1-γ) ≈ 67``, more than the largest
    sum of shaped costs without one (``<= 40``): ``Ā > 0`` for every proposal that leads to a violation the brake
    avoids.

    :param alpha: band of eq. 18 in rad/s: the cost ramps up from ``|θ̇| = 4 - α``.
    :param gamma: discount of ``Q̄``.
    :param horizon: steps of each rollout (the brake settles a swing within 2 s).
    :param eta: advantage threshold ``η >= 0``.
    """

    def __init__(self, alpha: float = 1.0, gamma: float = 0.99, horizon: int = 40, eta: float = 0.0) -> None:
        super().__init__(eta=eta)
        self.alpha = alpha
        self.gamma = gamma
        self.horizon = horizon

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """The torque that stops the pendulum in one step, clipped to ±2 N·m: shape ``(B, 1)``."""
        return self.brake(states_from_obs(obs))

    @staticmethod
    def brake(state: np.ndarray) -> np.ndarray:
        """``u = -(M L²/3)(θ̇/dt + (3g/2L) sin θ)`` clipped to the torque limit, on ``(B, 2)`` states."""
        u = -(M * L**2 / 3.0) * (state[:, 1] / DT + 3 * G / (2 * L) * np.sin(state[:, 0]))
        return np.clip(u, -MAX_TORQUE, MAX_TORQUE)[:, None]

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` for a batch: ``(B,)``, by rolling "``a`` then brake" through :func:`pendulum_step`."""
        state = pendulum_step(states_from_obs(obs), actions)
        q = np.zeros(len(obs))
        running = np.ones(len(obs), dtype=bool)
        for t in range(self.horizon):
            speed = np.abs(state[:, 1])
            violated = speed > MAX_SPEED
            cost = np.where(violated, 1.0 / (1.0 - self.gamma), shaped_cost(np.maximum(0.0, MAX_SPEED - speed), self.alpha))
            q += running * self.gamma ** (t + 1) * cost
            running &= ~violated
            if not running.any():
                break
            state = pendulum_step(state, self.brake(state))
        return q


# ------------------------------------------------------------------------------------------- 2b. the rule, no model
def over_speed(obs: np.ndarray) -> np.ndarray:
    """In the unsafe set ``|θ̇| > 4``, from ``(B, 3)`` observations: ``(B,)`` booleans."""
    return np.abs(obs[:, 2]) > MAX_SPEED


def speed_margin(obs: np.ndarray) -> np.ndarray:
    """Distance ``4 - |θ̇|`` to the unsafe set (0 inside), from ``(B, 3)`` observations: ``(B,)``."""
    return np.maximum(0.0, MAX_SPEED - np.abs(obs[:, 2]))


def learned_pendulum_rule(**kwargs: Any) -> LearnedDynamicsRule:
    """The brake and the constraint without Pendulum's equations: ``Q̄`` rolled on dynamics learned from the buffer.

    What a user who knows only how to stop the pendulum builds; ``SPPO`` fits it on its buffer (``refine_shield``).
    """
    env, rule = ConstrainedPendulumEnv(), PendulumBrakeRule()
    settings: dict[str, Any] = {"alpha": rule.alpha, "gamma": rule.gamma, "horizon": rule.horizon, **kwargs}
    space = env.observation_space, env.action_space
    return LearnedDynamicsRule(*space, rule.backup_action, over_speed, speed_margin, **settings)


def latent_pendulum_rule(**kwargs: Any) -> LatentModelRule:
    """The brake alone: ``Q̄`` rolled on SPPO's own TOLD, the constraint learned from ``info["shaped_cost"]``."""
    env, rule = ConstrainedPendulumEnv(), PendulumBrakeRule()
    settings: dict[str, Any] = {"gamma": rule.gamma, "horizon": rule.horizon, **kwargs}
    return LatentModelRule(env.observation_space, env.action_space, rule.backup_action, **settings)


# ------------------------------------------------------------------------------------------------- 3. registration
if ENV_ID not in registry:
    register(id=ENV_ID, entry_point=ConstrainedPendulumEnv, max_episode_steps=200)
register_shielding_rule(ENV_ID, PendulumBrakeRule)
register_shielding_rule(f"{ENV_ID}:learned", learned_pendulum_rule)  # shield="ConstrainedPendulum-v0:learned"
register_shielding_rule(f"{ENV_ID}:latent", latent_pendulum_rule)


# ------------------------------------------------------------------------------------------------- 4. training
class SafetyCallback(BaseCallback):
    """Counts violations, safety rate and interventions of any SB3 run with the package's :class:`SafetyMetrics`."""

    def __init__(self) -> None:
        super().__init__()
        self.metrics = SafetyMetrics(n_envs=1)

    def _on_step(self) -> bool:
        self.metrics.update_from_infos(self.locals["rewards"], self.locals["dones"], self.locals["infos"])
        return True


SPPO_SMALL: dict[str, Any] = dict(
    learning_starts=500,
    batch_size=128,
    policy_kwargs=dict(latent_dim=32, encoder_dim=64, hidden_dim=128),
    planner_kwargs=dict(num_samples=128, num_elites=16, iterations=4),
)


def train_sppo(total_timesteps: int, shielded: bool = True, seed: int = 0, **kwargs: Any) -> dict[str, float]:
    """SPPO on the task, with its registered rule (``shield="auto"``) or without (``shield=None``): safety summary.

    :param total_timesteps: env steps.
    :param shielded: use the registered rule.
    :param seed: seed of SPPO and the env.
    :param kwargs: SPPO arguments over :data:`SPPO_SMALL`.
    """
    shield = "auto" if shielded else None
    model = SPPO("TOLDPolicy", ENV_ID, shield=shield, seed=seed, **{**SPPO_SMALL, **kwargs})
    model.learn(total_timesteps)
    assert model.safety_metrics is not None
    return model.safety_metrics.summary()


def train_sac(total_timesteps: int, seed: int = 0) -> dict[str, float]:
    """SB3's SAC behind :class:`ShieldWrapper` (the default ``on_intervention``): safety summary.

    :param total_timesteps: env steps.
    :param seed: seed of SAC.
    """
    model = SAC("MlpPolicy", ShieldWrapper(gym.make(ENV_ID), PendulumBrakeRule()), learning_starts=500, seed=seed)
    callback = SafetyCallback()
    model.learn(total_timesteps, callback=callback)
    return callback.metrics.summary()


if __name__ == "__main__":
    print("SPPO, shielded:  ", train_sppo(3000))
    print("SPPO, unshielded:", train_sppo(3000, shielded=False))
    print("SAC + ShieldWrapper:", train_sac(3000))
