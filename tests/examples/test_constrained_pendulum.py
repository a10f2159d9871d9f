"""The "designing your own safe task" example: Pendulum-v1 with |θ̇| <= 4, a brake backup and Q̄ on its dynamics."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env
from tiny_hyperparams import SMALL_TOLD, TINY_SPPO

from sppo_sb3 import SPPO
from sppo_sb3.common.keys import COST_KEY
from sppo_sb3.shield import LearnedDynamicsRule, ShieldWrapper
from sppo_sb3.shield.registry import SHIELDING_RULES


@pytest.fixture(scope="module")
def example(load_example: Callable[[str], ModuleType]) -> ModuleType:
    return load_example("constrained_pendulum")


def test_env_passes_sb3_check_env(example: ModuleType) -> None:
    check_env(gym.make(example.ENV_ID).unwrapped, warn=True)


def test_rule_model_is_the_env(example: ModuleType) -> None:
    env = gym.make(example.ENV_ID).unwrapped
    rng = np.random.default_rng(0)
    for _ in range(20):
        env.reset(seed=0)
        state, torque = np.array([rng.uniform(-np.pi, np.pi), rng.uniform(-4.0, 4.0)]), rng.uniform(-2.0, 2.0, 1)
        env.state = state.copy()
        env.step(torque)
        np.testing.assert_allclose(env.state, example.pendulum_step(state[None], torque[None])[0])


def test_the_brake_is_safe_from_every_starting_state(example: ModuleType) -> None:
    rule = example.PendulumBrakeRule()
    states = np.array([[np.pi + a, b] for a in np.linspace(-1.0, 1.0, 41) for b in np.linspace(-0.5, 0.5, 11)])
    for _ in range(200):
        states = example.pendulum_step(states, rule.brake(states))
        assert np.all(np.abs(states[:, 1]) <= example.MAX_SPEED)


def pump(env: gym.Env, episodes: int = 3) -> tuple[int, int]:
    """Energy pumping at full torque (it violates within an episode): violations and interventions."""
    violations = interventions = 0
    for episode in range(episodes):
        obs, _ = env.reset(seed=episode)
        done = False
        while not done:
            action = np.array([2.0 if obs[2] >= 0 else -2.0], dtype=np.float32)
            obs, _, terminated, truncated, info = env.step(action)
            violations += int(info[COST_KEY] > 0)
            interventions += int(info.get("shield_intervened", False))
            done = terminated or truncated
    return violations, interventions


def test_the_shield_stops_a_pumping_policy(example: ModuleType) -> None:
    assert pump(gym.make(example.ENV_ID))[0] == 3
    violations, interventions = pump(ShieldWrapper(gym.make(example.ENV_ID), example.PendulumBrakeRule()))
    assert violations == 0 and interventions > 0


def test_shielded_sppo_has_no_violation(example: ModuleType) -> None:
    small = {
        **TINY_SPPO,
        "learning_starts": 200,
        "batch_size": 32,
        "policy_kwargs": SMALL_TOLD,
        "planner_kwargs": {**TINY_SPPO["planner_kwargs"], "num_samples": 32, "num_elites": 8},
    }
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*nothing is shielded")  # "auto" finds the registered rule
        summary = example.train_sppo(600, **small)
    assert summary["cumulative_violations"] == 0
    model = SPPO("TOLDPolicy", example.ENV_ID, **small)
    assert isinstance(model.shield_rule, example.PendulumBrakeRule)


def as_obs(states: np.ndarray) -> np.ndarray:
    """``(B, 2)`` states ``[θ, θ̇]`` → ``(B, 3)`` observations ``[cos θ, sin θ, θ̇]``."""
    return np.stack([np.cos(states[:, 0]), np.sin(states[:, 0]), states[:, 1]], axis=1)


def test_the_learned_rule_stops_a_pumping_policy_once_fitted(example: ModuleType) -> None:
    """Only the brake and the speed limit known: dynamics fitted on random transitions (measured: 0 violations on
    seeds 0-2 after 300 updates); before any fitting it predicts no change, and the pump violates."""
    rng = np.random.default_rng(0)
    states = np.stack([rng.uniform(-np.pi, np.pi, 3000), rng.uniform(-6.0, 6.0, 3000)], axis=1)
    torques = rng.uniform(-2.0, 2.0, (3000, 1))
    rule = SHIELDING_RULES[f"{example.ENV_ID}:learned"](seed=0)
    assert isinstance(rule, LearnedDynamicsRule)
    assert pump(ShieldWrapper(gym.make(example.ENV_ID), rule), episodes=1)[0] == 1
    rule.update(as_obs(states), torques, as_obs(example.pendulum_step(states, torques)), gradient_steps=300)
    violations, interventions = pump(ShieldWrapper(gym.make(example.ENV_ID), rule), episodes=1)
    assert violations == 0 and interventions > 0
