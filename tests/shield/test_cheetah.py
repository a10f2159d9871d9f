"""SafeHalfCheetahHeight-v1 and its MPC shielding rule (paper Section V-A)."""

from __future__ import annotations

import pickle

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.envs.half_cheetah_height import SafeHalfCheetahHeightEnv, height_distance_to_unsafe, height_is_unsafe
from sppo_sb3.shield import default_shielding_rule
from sppo_sb3.shield.tasks.cheetah import HalfCheetahHeightShieldingRule, rollout_heights_python

HOLD = np.full(6, 0.3)  # a constant torque under which the cheetah stands still with its front thigh at ~0.61


def settle(env: SafeHalfCheetahHeightEnv, action: np.ndarray, steps: int = 100) -> np.ndarray:
    """Start from the model's rest pose at zero velocity, hold ``action`` for ``steps`` steps, return the observation."""
    env.reset(seed=0)
    env.set_state(env.init_qpos, env.init_qvel)
    for _ in range(steps):
        obs, *_ = env.step(action)
    return obs


def place(env: SafeHalfCheetahHeightEnv, rootz: float) -> None:
    """Rest pose at zero velocity, lifted by ``rootz`` (mid-air: the thigh's height is ``0.70 + rootz``)."""
    env.reset(seed=0)
    qpos = env.init_qpos.copy()
    qpos[1] = rootz
    env.set_state(qpos, np.zeros(env.model.nv))


@pytest.fixture(scope="module")
def env() -> SafeHalfCheetahHeightEnv:
    return SafeHalfCheetahHeightEnv()


@pytest.fixture(scope="module")
def states(env: SafeHalfCheetahHeightEnv) -> dict[str, np.ndarray]:
    """Standing under ``HOLD`` (thigh ~0.61), and falling: one step of ``-1`` after slumping under zero torque (0.49)."""
    standing = settle(env, HOLD)
    settle(env, np.zeros(6))
    return {"falling": env.step(-np.ones(6))[0], "standing": standing}


def fall(env: SafeHalfCheetahHeightEnv) -> None:
    """Put ``env`` in the ``falling`` state."""
    settle(env, np.zeros(6))
    env.step(-np.ones(6))


def make_rule(seed: int = 0, n_threads: int = 0) -> HalfCheetahHeightShieldingRule:
    return HalfCheetahHeightShieldingRule(seed=seed, n_threads=n_threads)


def test_check_env_and_registration(env: SafeHalfCheetahHeightEnv) -> None:
    check_env(SafeHalfCheetahHeightEnv())
    made = gym.make("SafeHalfCheetahHeight-v1")
    assert made.spec is not None and made.spec.max_episode_steps == 1000
    assert made.observation_space.shape == (17,) and made.action_space.shape == (6,)
    made.close()


def test_height_is_the_body_frame_origin_mid_range_at_reset() -> None:
    """SAILR's ``get_body_com("fthigh")`` is the body frame origin ``data.xpos``: 0.70 at reset, not the CoM's 0.575."""
    env = SafeHalfCheetahHeightEnv(reset_noise_scale=0.0)  # the default reset state itself
    env.reset(seed=0)
    height = env.fthigh_height()
    assert height == env.data.xpos[env.model.body("fthigh").id, 2]
    assert height == pytest.approx(0.70, abs=0.01)
    assert env.data.xipos[env.model.body("fthigh").id, 2] == pytest.approx(0.575, abs=0.01)  # the centre of mass


def test_reward_is_forward_velocity_over_five(env: SafeHalfCheetahHeightEnv) -> None:
    env.reset(seed=1)
    for _ in range(3):
        _, reward, _, _, info = env.step(np.ones(6))
        assert isinstance(reward, float)
        assert reward == pytest.approx(info["x_velocity"] / 5.0)


def test_distance_and_unsafe_set() -> None:
    h = np.array([0.3, 0.4, 0.45, 0.7, 0.98, 1.0, 1.2])
    np.testing.assert_allclose(height_distance_to_unsafe(h), [0.0, 0.0, 0.05, 0.3, 0.02, 0.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(height_is_unsafe(h), [True, False, False, False, False, False, True])


@pytest.mark.parametrize(("rootz", "unsafe", "in_band"), [(0.45, True, False), (0.27, False, True), (0.0, False, False)])
def test_cost_and_termination_at_constructed_heights(
    env: SafeHalfCheetahHeightEnv, rootz: float, unsafe: bool, in_band: bool
) -> None:
    place(env, rootz)
    _, _, terminated, truncated, info = env.step(np.zeros(6))
    h = info["fthigh_height"]
    mujoco.mj_kinematics(env.model, env.data)
    assert h == env.data.xpos[env.model.body("fthigh").id, 2]  # the height of the post-step state
    assert terminated is unsafe and not truncated
    assert info["cost"] == float(unsafe)
    expected = 1.0 if unsafe else max(0.0, 1.0 - min(h - 0.4, 1.0 - h) / 0.05)
    assert info["shaped_cost"] == pytest.approx(expected)
    assert (0.0 < info["shaped_cost"] < 1.0) is in_band


def test_falling_below_the_range_terminates(env: SafeHalfCheetahHeightEnv) -> None:
    fall(env)
    _, _, terminated, _, info = env.step(-np.ones(6))  # collapses the front leg from ~0.49
    assert terminated and info["cost"] == 1.0 and info["fthigh_height"] < 0.4


def test_rule_rollouts_match_the_env(env: SafeHalfCheetahHeightEnv) -> None:
    """The state rebuilt from the observation (x = 0) and the model's body-frame sensor reproduce the env's heights."""
    rule = make_rule(n_threads=2)
    obs, _ = env.reset(seed=3)
    controls = np.random.default_rng(0).uniform(-0.5, 0.5, (1, 12, 6))
    heights = [env.step(a)[4]["fthigh_height"] for a in controls[0]]
    states = rule.layout.states_from_obs(rule.model, obs[None])
    assert np.ptp(heights) > 0.05  # the thigh moves: a sensor on another frame would not follow it
    np.testing.assert_allclose(rule.rollout_heights(states, controls)[0], heights, atol=1e-9)
    python = rollout_heights_python(rule.model, mujoco.MjData(rule.model), states, controls)
    np.testing.assert_array_equal(rule.rollout_heights(states, controls), python)


@pytest.mark.parametrize("certify", [True, False])
def test_shield_blocks_a_collapse_and_lets_a_quiet_stand_pass(
    env: SafeHalfCheetahHeightEnv, states: dict[str, np.ndarray], certify: bool
) -> None:
    rule = HalfCheetahHeightShieldingRule(seed=0, n_threads=0, certify=certify)
    obs = np.stack([states["falling"], states["standing"]])
    decision = rule.shield(obs, np.stack([-np.ones(6), HOLD]))
    assert decision.intervened.tolist() == [True, False]
    assert decision.advantage[0] > 10 * rule.eta  # the proposal violates, the backup does not
    np.testing.assert_array_equal(decision.actions[1], HOLD)
    fall(env)
    assert env.step(decision.actions[0])[4]["cost"] == 0.0  # the executed backup keeps the thigh in range


def test_backup_is_never_shielded_and_inside_the_action_space(
    env: SafeHalfCheetahHeightEnv, states: dict[str, np.ndarray]
) -> None:
    rule = make_rule()
    obs = np.stack([states["falling"], states["standing"], env.reset(seed=5)[0]])
    backup = rule.backup_action(obs)
    assert backup.shape == (3, 6)
    assert np.all(backup >= env.action_space.low) and np.all(backup <= env.action_space.high)
    rule.check_action_space(env.action_space, obs)
    np.testing.assert_array_equal(rule.advantage(obs, backup, backup), 0.0)  # Proposition 1, exactly


def test_deterministic_given_a_seed(states: dict[str, np.ndarray]) -> None:
    obs = np.stack([states["falling"], states["standing"]])
    actions = np.stack([-np.ones(6), -HOLD])
    first, second = make_rule(seed=7, n_threads=0), make_rule(seed=7, n_threads=2)
    for _ in range(2):
        a, b = first.shield(obs, actions), second.shield(obs, actions)
        np.testing.assert_array_equal(a.actions, b.actions)
        np.testing.assert_array_equal(a.advantage, b.advantage)
    np.testing.assert_array_equal(first.backup_action(obs), second.backup_action(obs))
    assert not np.array_equal(make_rule(seed=8).backup_action(obs), first.backup_action(obs))  # the seed matters


def test_picklable_and_registered(env: SafeHalfCheetahHeightEnv, states: dict[str, np.ndarray]) -> None:
    rule = make_rule(seed=11)
    clone = pickle.loads(pickle.dumps(rule))
    obs = states["standing"][None]
    np.testing.assert_array_equal(rule.backup_action(obs), clone.backup_action(obs))
    rule.shield(obs, HOLD[None])  # stores a warm plan for the next state ...
    assert len(rule.warm_starts.keys) == 1
    assert len(pickle.loads(pickle.dumps(rule)).warm_starts.keys) == 0  # ... which belongs to the running episode
    assert isinstance(default_shielding_rule("SafeHalfCheetahHeight-v1"), HalfCheetahHeightShieldingRule)
    default = default_shielding_rule("SafeHalfCheetahHeight-v1", env)
    assert (default.eta, default.gamma, default.alpha, default.horizon, default.n_particles) == (0.2, 0.99, 0.05, 15, 64)
