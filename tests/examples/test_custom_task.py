"""The "bring your own task" example: a user env + a user ShieldingRule, registered, and used with SB3's PPO."""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env

import sppo_sb3  # noqa: F401
from sppo_sb3.shield import SHIELDING_RULES, ShieldWrapper, default_shielding_rule


@pytest.fixture(scope="module")
def example(load_example: Callable[[str], ModuleType]) -> ModuleType:
    return load_example("custom_task_shield")


def test_env_passes_sb3_check_env(example: ModuleType) -> None:
    env = gym.make(example.ENV_ID)
    check_env(env.unwrapped, warn=True)
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(env.action_space.sample())
    assert info["cost"] == 0.0


def test_rule_is_registered(example: ModuleType) -> None:
    assert SHIELDING_RULES[example.ENV_ID] is example.CartCliffShieldingRule
    rule = default_shielding_rule(example.ENV_ID)
    assert isinstance(rule, example.CartCliffShieldingRule)
    rule.check_action_space(gym.make(example.ENV_ID).action_space, np.array([[0.0, 0.5], [0.9, -1.0]]))


def test_rule_decisions(example: ModuleType) -> None:
    rule = example.CartCliffShieldingRule()
    obs = np.array([[0.9, 1.0], [0.5, 1.0], [0.0, 0.0], [-0.5, -1.0]])
    decision = rule.shield(obs, np.ones((4, 1)))
    np.testing.assert_array_equal(decision.intervened, [True, True, False, False])
    np.testing.assert_array_equal(decision.actions[:2], -1.0)  # brake
    # Proposition 1: the backup itself is never shielded
    rng = np.random.default_rng(0)
    states = np.stack([rng.uniform(-1.0, 1.0, 500), rng.uniform(-1.0, 1.0, 500)], axis=1)
    assert not rule.shield(states, rule.backup_action(states)).intervened.any()


def test_rule_model_matches_the_env(example: ModuleType) -> None:
    """``Q̄`` of the rule equals the discounted shaped cost observed in the env along "a, then brake"."""
    rule = example.CartCliffShieldingRule()
    env = gym.make(example.ENV_ID).unwrapped
    for state, force in [((0.2, 0.8), 1.0), ((0.6, 0.3), 0.5), ((0.85, 0.0), -1.0)]:
        env.reset(seed=0)
        env.state = np.array(state)
        q, action = 0.0, np.array([force])
        for t in range(rule.horizon):
            _, _, terminated, _, info = env.step(action)  # float64, as the rule's rollout
            assert not terminated
            q += rule.gamma ** (t + 1) * info["shaped_cost"]
            if abs(env.state[1]) < 1e-9:  # at rest: the shaped cost stays constant forever
                q += rule.gamma ** (t + 2) * info["shaped_cost"] / (1.0 - rule.gamma)
                break
            action = rule.backup_action(env.state[None])[0]
        expected = rule.cost_value(np.array([state]), np.array([[force]]))[0]
        assert q == pytest.approx(expected, rel=1e-5, abs=1e-9)


def test_random_actions_zero_violations_with_the_shield(example: ModuleType) -> None:
    shielded = example.run_random(episodes=10, shielded=True)
    assert shielded["violations"] == 0
    assert shielded["interventions"] > 0
    assert shielded["steps"] == 10 * 200  # no episode ended early
    assert example.run_random(episodes=10, shielded=False)["violations"] > 0


def test_ppo_behind_the_shield(example: ModuleType) -> None:
    model, summary = example.train_ppo(total_timesteps=1024, seed=0)
    assert isinstance(model, PPO)
    wrapper = model.get_env().envs[0]
    while not isinstance(wrapper, ShieldWrapper):
        wrapper = wrapper.env  # Monitor → ShieldWrapper
    assert isinstance(wrapper.rule, example.CartCliffShieldingRule)
    assert summary["cumulative_violations"] == 0.0
    assert summary["safety_rate"] == 100.0
    assert summary["episodes"] >= 4
    obs = np.array([0.0, 0.0], dtype=np.float32)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1,)
