"""Bring your own task: a cart on a rail next to a cliff, shielded by a hand-written rule, trained with SB3's PPO.

The three pieces a user writes:

1. a gymnasium env that reports the violation indicator ``info["cost"]`` (1.0 on the step that enters the unsafe
   set, else 0.0) and terminates there (the unsafe set is absorbing);
2. a :class:`~sppo_sb3.shield.ShieldingRule`: the backup policy ``ζ`` and ``Q̄(s, a)``, the discounted shaped cost
   (eq. 18) of taking ``a`` then following ``ζ`` — both on batches of raw observations;
3. ``register_shielding_rule(env_id, factory)`` so that the package's algorithms pick the rule with ``shield="auto"``,
   and :class:`~sppo_sb3.shield.ShieldWrapper` to shield any other SB3 algorithm.

Run ``python examples/custom_task_shield.py``.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import register, registry
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY
from sppo_sb3.common.safety import SafetyMetrics
from sppo_sb3.shield import ShieldingRule, ShieldWrapper, default_shielding_rule, register_shielding_rule

ENV_ID = "CartCliff-v0"
CLIFF = 1.0  # the cart falls off the rail when x > CLIFF
WALL = -1.0  # a wall stops the cart at x = WALL
DT = 0.1
MAX_SPEED = 1.0


# ------------------------------------------------------------------------------------------------- 1. the task
def cart_step(state: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Known dynamics on a batch: ``x += v·dt + F·dt²/2``, ``v += F·dt`` (unit mass), speed clipped, wall at -1.

    :param state: ``(B, 2)`` states ``[x, v]``.
    :param force: ``(B, 1)`` forces, clipped to [-1, 1] here.
    :return: the next states ``(B, 2)``.
    """
    force = np.clip(force[:, 0], -1.0, 1.0)
    x = state[:, 0] + state[:, 1] * DT + force * DT**2 / 2.0
    v = np.clip(state[:, 1] + force * DT, -MAX_SPEED, MAX_SPEED)
    hit_wall = x < WALL
    return np.stack([np.where(hit_wall, WALL, x), np.where(hit_wall, 0.0, v)], axis=1)


class CartCliffEnv(gym.Env[np.ndarray, np.ndarray]):
    """A cart rewarded for standing as far right as possible — next to a cliff at ``x = 1``.

    Observation ``[x, v]``, action: a force in [-1, 1]. Reward ``x`` per step. Falling (``x > 1``) is a violation:
    ``info["cost"] = 1.0`` and the episode terminates. ``info["shaped_cost"]`` is ``ĉ`` of eq. 18.
    """

    def __init__(self, alpha: float = 0.1) -> None:
        self.alpha = alpha
        self.observation_space = gym.spaces.Box(
            np.array([WALL, -MAX_SPEED], dtype=np.float32), np.array([2.0, MAX_SPEED], dtype=np.float32)
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.state = np.zeros(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.state = np.array([self.np_random.uniform(-0.5, 0.0), 0.0])
        return self.state.astype(np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.state = cart_step(self.state[None], np.asarray(action, dtype=np.float64).reshape(1, 1))[0]
        fell = bool(self.state[0] > CLIFF)
        info = {COST_KEY: float(fell), "shaped_cost": float(shaped_cost(max(0.0, CLIFF - self.state[0]), self.alpha))}
        obs = np.clip(self.state, self.observation_space.low, self.observation_space.high).astype(np.float32)
        return obs, float(self.state[0]), fell, False, info


# ------------------------------------------------------------------------------------------------- 2. the rule
class CartCliffShieldingRule(ShieldingRule):
    """Backup ``ζ``: brake to a stop. ``Q̄(s, a) = Σ_t γ^(t+1) ĉ(s_(t+1))`` along "apply ``a``, then brake".

    The rollouts of a batch run together on the known dynamics; a rollout ends at rest (``ĉ`` then stays constant:
    geometric tail ``ĉ·γ^(t+1)/(1-γ)``) or off the cliff (absorbing, ``ĉ = 1`` forever).

    :param alpha: shaped-cost band of eq. 18 in front of the cliff.
    :param gamma: discount of ``Q̄``.
    :param eta: advantage threshold ``η >= 0``.
    """

    def __init__(self, alpha: float = 0.1, gamma: float = 0.99, eta: float = 0.0) -> None:
        super().__init__(eta=eta)
        self.alpha = alpha
        self.gamma = gamma
        self.horizon = math.ceil(MAX_SPEED / DT) + 2  # full braking stops the cart from any speed in this many steps

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """Braking force ``clip(-v/dt, -1, 1)`` (stops exactly once the speed is small), shape ``(B, 1)``."""
        return np.clip(-obs[:, 1:2] / DT, -1.0, 1.0)

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` for a batch, by rolling "``a`` then brake" through :func:`cart_step`."""
        tail = 1.0 / (1.0 - self.gamma)
        state = cart_step(obs[:, :2].astype(np.float64), actions)
        q = np.zeros(len(obs))
        running = np.ones(len(obs), dtype=bool)
        for t in range(self.horizon):
            fell = state[:, 0] > CLIFF
            at_rest = np.abs(state[:, 1]) < 1e-9
            cost = shaped_cost(np.maximum(0.0, CLIFF - state[:, 0]), self.alpha)
            q += running * self.gamma ** (t + 1) * np.where(fell, tail, np.where(at_rest, cost * tail, cost))
            running &= ~(fell | at_rest)
            if not running.any():
                break
            state = cart_step(state, self.backup_action(state))
        return q


# ------------------------------------------------------------------------------------------------- 3. registration
if ENV_ID not in registry:
    register(id=ENV_ID, entry_point=CartCliffEnv, max_episode_steps=200)
register_shielding_rule(ENV_ID, CartCliffShieldingRule)


def make_shielded_env() -> ShieldWrapper:
    """The task with its registered rule in front of it: every executed action is shielded (eq. 12)."""
    rule = default_shielding_rule(ENV_ID)
    assert rule is not None
    return ShieldWrapper(gym.make(ENV_ID), rule)


class SafetyCallback(BaseCallback):
    """Counts violations, safety rate and shield interventions of an SB3 run with the package's :class:`SafetyMetrics`."""

    def __init__(self) -> None:
        super().__init__()
        self.metrics = SafetyMetrics(n_envs=1)

    def _on_training_start(self) -> None:
        self.metrics.resize(self.training_env.num_envs)

    def _on_step(self) -> bool:
        self.metrics.update_from_infos(self.locals["rewards"], self.locals["dones"], self.locals["infos"])
        return True


def train_ppo(total_timesteps: int = 4096, seed: int = 0) -> tuple[PPO, dict[str, float]]:
    """(a) SB3's PPO behind the shield: returns the model and the safety summary of its training.

    :param total_timesteps: env steps of training.
    :param seed: seed of PPO and the env.
    """
    model = PPO("MlpPolicy", make_shielded_env(), n_steps=512, batch_size=128, n_epochs=4, seed=seed, verbose=0)
    callback = SafetyCallback()
    model.learn(total_timesteps, callback=callback)
    return model, callback.metrics.summary()


def run_random(episodes: int = 20, shielded: bool = True, seed: int = 0) -> dict[str, int]:
    """(b) Uniformly random forces in [-1, 1], with or without the shield: violations and interventions.

    :param episodes: number of 200-step episodes.
    :param shielded: put the registered rule in front of the env.
    :param seed: seed of the actions and the resets.
    """
    env: gym.Env = make_shielded_env() if shielded else gym.make(ENV_ID)
    rng = np.random.default_rng(seed)
    violations = interventions = steps = 0
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        done = False
        while not done:
            # a biased random policy: it drifts to the right and would drive off the cliff without the shield
            action = np.array([rng.uniform(-0.5, 1.0)], dtype=np.float32)
            _, _, terminated, truncated, info = env.step(action)
            violations += int(info[COST_KEY] > 0)
            interventions += int(info.get("shield_intervened", False))
            steps += 1
            done = terminated or truncated
    env.close()
    return {"violations": violations, "interventions": interventions, "steps": steps}


if __name__ == "__main__":
    print("random actions, shielded:  ", run_random(shielded=True))
    print("random actions, unshielded:", run_random(shielded=False))
    model, summary = train_ppo(total_timesteps=8192)
    print(f"PPO + ShieldWrapper: {summary}")
