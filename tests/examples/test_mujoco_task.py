"""A user's own MuJoCo task, shielded by the general rule: ``examples/mujoco_hopper_upright.py``, and the velocity
tasks' registered rules."""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest

from sppo_sb3.envs.velocity import VELOCITY_TASKS, VelocityTask
from sppo_sb3.shield import MujocoShieldingRule, VelocityConstraint, default_shielding_rule


@pytest.fixture(scope="module")
def example(load_example: Callable[[str], ModuleType]) -> ModuleType:
    return load_example("mujoco_hopper_upright")


def test_example_task_is_shielded_while_exploring(example: ModuleType) -> None:
    """Random exploration (before learning starts) of SPPO and of SAC behind ShieldWrapper: no violation, and the
    shield had to act; the same exploration unshielded tips the torso over."""
    results = example.main(steps=300, learning_starts=1000)
    for violations, interventions in results.values():
        assert violations == 0 and interventions > 0
    env = gym.make(example.ENV_ID)
    env.action_space.seed(0)
    env.reset(seed=0)
    unshielded = 0
    for _ in range(300):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        unshielded += int(info["cost"] > 0)
        if terminated or truncated:
            env.reset()
    assert unshielded > 0


def test_example_constraint_reads_the_rolled_state(example: ModuleType) -> None:
    rule = example.upright_rule()
    env = gym.make(example.ENV_ID)
    obs, _ = env.reset(seed=0)
    states = rule.layout.states_from_obs(rule.model, obs[None])
    steps = rule.rollout_steps(states, np.zeros((1, 2, 3)))
    pitch = np.abs(steps.qpos(steps.after)[0, :, 2])
    np.testing.assert_array_equal(example.TorsoUpright().distance(steps)[0], np.maximum(0.0, example.MAX_PITCH - pitch))


@pytest.mark.parametrize("task", VELOCITY_TASKS, ids=lambda task: task.robot)
def test_every_velocity_task_has_its_rule(task: VelocityTask) -> None:
    """``shield="auto"`` finds a MuJoCo rule for each velocity task, with the env's α and the task's threshold."""
    env = gym.make(task.env_id, alpha=0.2 * task.threshold)
    rule = default_shielding_rule(task.env_id, env)
    assert isinstance(rule, MujocoShieldingRule) and isinstance(rule.constraint, VelocityConstraint)
    assert rule.alpha == pytest.approx(0.2 * task.threshold)
    assert rule.constraint.threshold == task.threshold and rule.constraint.planar == task.planar
    obs, _ = env.reset(seed=0)
    q = rule.cost_value(obs[None], np.zeros((1, env.action_space.shape[0])))
    assert np.isfinite(q).all() and q[0] >= 0.0
