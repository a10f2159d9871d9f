"""The velocity tasks ``sppo_sb3/Safety<Robot>Velocity-v1`` against Safety-Gymnasium's definitions.

What Safety-Gymnasium's source computes (``safety_gymnasium/tasks/safe_velocity/safety_*_velocity_v{0,1}.py``, the
registrations in ``safety_gymnasium/__init__.py``), and how each fact is checked here without Safety-Gymnasium (it
does not import on gymnasium 1.x):

- the env is gymnasium's ``<Robot>-v4`` with its default arguments, and its ``step`` repeats the v4 step's reward
  and termination: :func:`test_replays_gymnasium_v4` plays one recorded random action sequence (with resets on
  termination) through our env and through ``gym.make("<Robot>-v4")`` and compares observations, rewards,
  ``terminated``/``truncated`` and the v4 info, exactly;
- the velocity is ``Δ / dt`` over the frame skip of ``data.qpos[0]`` (HalfCheetah, Hopper, Walker2d, Swimmer), of
  ``get_body_com("torso")[:2]`` = ``data.body("torso").xpos[:2]`` (Ant) or of ``mass_center`` = the mass-weighted
  mean of ``data.xipos[:, :2]`` (Humanoid), taken before and after ``do_simulation``; the cost compares
  ``sqrt(vx² + vy²)`` (Ant, Humanoid) or the signed ``vx`` (the others; v1's Swimmer overrides v0's xy speed) with
  the threshold: ``float(velocity > threshold)``. :func:`measured_velocity` recomputes this from
  ``env.unwrapped.data`` around every step, independently of the env's code, and the tests compare it with
  ``info["velocity"]`` and ``info["cost"]``;
- the thresholds of v1 (:data:`SAFETY_GYMNASIUM_V1`) and ``max_episode_steps=1000``; a violation does not end the
  episode (their ``step`` returns the v4 env's ``terminated``).
"""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.mujoco import MujocoEnv
from stable_baselines3.common.env_checker import check_env

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import COST_KEY, SHAPED_COST_KEY, VELOCITY_KEY
from sppo_sb3.envs.velocity import (
    HALF_CHEETAH,
    VELOCITY_TASKS,
    SafetyVelocityEnv,
    VelocityTask,
    velocity_distance_to_unsafe,
    velocity_is_unsafe,
)

pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")

#: Safety-Gymnasium's v1 threshold of each robot, and whether its cost is on the xy speed (else the signed x velocity)
SAFETY_GYMNASIUM_V1: dict[str, tuple[float, bool]] = {
    "HalfCheetah": (3.2096, False),
    "Hopper": (0.7402, False),
    "Walker2d": (2.3415, False),
    "Ant": (2.6222, True),
    "Swimmer": (0.2282, False),
    "Humanoid": (1.4149, True),
}
REPLAY_STEPS = 200
IDS = [task.robot for task in VELOCITY_TASKS]


def tracked_position(env: gym.Env, robot: str) -> np.ndarray:
    """The xy position (x only for the sagittal robots) whose change Safety-Gymnasium's ``step`` calls velocity."""
    mujoco_env = env.unwrapped
    assert isinstance(mujoco_env, MujocoEnv)
    model, data = mujoco_env.model, mujoco_env.data
    if robot == "Ant":
        return data.body("torso").xpos[:2].copy()
    if robot == "Humanoid":
        return (model.body_mass @ data.xipos)[:2] / model.body_mass.sum()
    if robot == "Swimmer":
        return data.qpos[:2].copy()
    return data.qpos[:1].copy()


def measured_velocity(env: gym.Env, robot: str, before: np.ndarray) -> float:
    """``Δ / dt`` of :func:`tracked_position` since ``before``: the xy speed on Ant and Humanoid, else the x velocity."""
    mujoco_env = env.unwrapped
    assert isinstance(mujoco_env, MujocoEnv)
    dt = mujoco_env.model.opt.timestep * mujoco_env.frame_skip
    delta = (tracked_position(env, robot) - before) / dt
    return float(np.hypot(delta[0], delta[1])) if robot in ("Ant", "Humanoid") else float(delta[0])


def push(env: gym.Env, index: int, speed: float) -> None:
    """Reset, then set generalized velocity ``index`` (0: x, 1: y of a free joint) to ``speed`` and all others to 0."""
    env.reset(seed=0)
    mujoco_env = env.unwrapped
    assert isinstance(mujoco_env, MujocoEnv)
    qvel = np.zeros(mujoco_env.model.nv)
    qvel[index] = speed
    mujoco_env.set_state(mujoco_env.data.qpos.copy(), qvel)


def test_the_table_is_safety_gymnasiums() -> None:
    assert {task.robot: (task.threshold, task.planar) for task in VELOCITY_TASKS} == SAFETY_GYMNASIUM_V1
    for task in VELOCITY_TASKS:
        assert task.env_id == f"sppo_sb3/Safety{task.robot}Velocity-v1"
        assert gym.spec(task.base_id).entry_point == f"{task.base.__module__}:{task.base.__name__}"
        assert task.base.__module__.endswith("_v4")


@pytest.mark.parametrize("task", VELOCITY_TASKS, ids=IDS)
def test_registration(task: VelocityTask) -> None:
    spec = gym.spec(task.env_id)
    assert spec.namespace == "sppo_sb3" and spec.max_episode_steps == 1000
    env = gym.make(task.env_id)
    velocity_env = env.unwrapped
    assert isinstance(velocity_env, SafetyVelocityEnv) and isinstance(velocity_env, task.base) and velocity_env.task is task
    assert env.get_wrapper_attr("velocity_threshold") == task.threshold
    assert env.get_wrapper_attr("alpha") == pytest.approx(0.1 * task.threshold)
    assert gym.make(task.env_id, alpha=0.05).get_wrapper_attr("alpha") == 0.05


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("task", VELOCITY_TASKS, ids=IDS)
def test_check_env(task: VelocityTask) -> None:
    check_env(gym.make(task.env_id))


@pytest.mark.parametrize("task", VELOCITY_TASKS, ids=IDS)
def test_replays_gymnasium_v4(task: VelocityTask) -> None:
    """Reward, termination and observation are the v4 env's; the cost is ``velocity > threshold`` of ``Δ / dt``."""
    env, reference = gym.make(task.env_id), gym.make(task.base_id)
    space = env.action_space
    assert isinstance(space, gym.spaces.Box)
    actions = np.random.default_rng(0).uniform(space.low, space.high, size=(REPLAY_STEPS, *space.shape)).astype(space.dtype)
    seed = 0
    obs, _ = env.reset(seed=seed)
    reference_obs, _ = reference.reset(seed=seed)
    assert np.array_equal(obs, reference_obs)
    for action in actions:
        before = tracked_position(env, task.robot)
        obs, reward, terminated, truncated, info = env.step(action)
        reference_obs, reference_reward, reference_terminated, reference_truncated, reference_info = reference.step(action)
        assert np.array_equal(obs, reference_obs)
        assert (reward, terminated, truncated) == (reference_reward, reference_terminated, reference_truncated)
        assert all(np.array_equal(info[key], value) for key, value in reference_info.items())

        velocity = measured_velocity(env, task.robot, before)
        assert info[VELOCITY_KEY] == pytest.approx(velocity, rel=1e-9, abs=1e-9)
        assert info[COST_KEY] == float(velocity > task.threshold)
        dist = max(0.0, task.threshold - info[VELOCITY_KEY])
        assert info[SHAPED_COST_KEY] == pytest.approx(max(0.0, 1.0 - dist / (0.1 * task.threshold)), abs=1e-12)
        if terminated or truncated:
            seed += 1
            env.reset(seed=seed)
            reference.reset(seed=seed)


@pytest.mark.parametrize("task", VELOCITY_TASKS, ids=IDS)
def test_a_violation_costs_one_and_does_not_terminate(task: VelocityTask) -> None:
    """Pushed forward at twice the threshold, the robot violates; the episode goes on (the v4 env's termination)."""
    env = gym.make(task.env_id)
    push(env, 0, 2 * task.threshold)
    before = tracked_position(env, task.robot)
    _, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape))
    assert measured_velocity(env, task.robot, before) > task.threshold
    assert (info[COST_KEY], info[SHAPED_COST_KEY], terminated, truncated) == (1.0, 1.0, False, False)

    push(env, 0, 0.5 * task.threshold)  # half the threshold: safe, and outside the band of α = 10%
    _, _, _, _, info = env.step(np.zeros(env.action_space.shape))
    assert 0 < info[VELOCITY_KEY] < task.threshold
    assert (info[COST_KEY], info[SHAPED_COST_KEY]) == (0.0, 0.0)


@pytest.mark.parametrize("task", VELOCITY_TASKS, ids=IDS)
def test_backwards_and_sideways(task: VelocityTask) -> None:
    """Running backwards is safe on the x-velocity tasks (their code's signed ``vx``); sideways counts on Ant/Humanoid."""
    env = gym.make(task.env_id)
    push(env, 0, -2 * task.threshold)
    _, _, _, _, info = env.step(np.zeros(env.action_space.shape))
    assert info[COST_KEY] == float(task.planar)
    if task.planar:  # a free joint: qvel[1] is the y velocity
        push(env, 1, 2 * task.threshold)
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape))
        assert info[COST_KEY] == 1.0


def test_violating_every_step_runs_to_the_time_limit() -> None:
    """HalfCheetah (which never terminates) held above the threshold: 1000 costly steps, truncated on the last."""
    env = gym.make(HALF_CHEETAH.env_id)
    push(env, 0, 2 * HALF_CHEETAH.threshold)
    cheetah = env.unwrapped
    assert isinstance(cheetah, SafetyVelocityEnv)
    for step in range(1, 1001):
        qvel = cheetah.data.qvel.copy()
        qvel[0] = 2 * HALF_CHEETAH.threshold
        cheetah.set_state(cheetah.data.qpos.copy(), qvel)
        _, _, terminated, truncated, info = env.step(np.zeros(6))
        assert info[COST_KEY] == 1.0 and not terminated
        assert truncated == (step == 1000)


def test_shaped_cost_ramps_up_in_the_band() -> None:
    threshold = 2.0
    alpha = 0.2
    velocity = np.array([-5.0, 0.0, 1.6, 1.8, 1.85, 1.9, 1.95, 2.0, 2.1, 9.0])
    cost = shaped_cost(velocity_distance_to_unsafe(velocity, threshold), alpha)
    np.testing.assert_allclose(cost, [0, 0, 0, 0, 0.25, 0.5, 0.75, 1, 1, 1], atol=1e-12)
    assert np.all(np.diff(cost) >= 0)
    np.testing.assert_array_equal(velocity_is_unsafe(velocity, threshold), velocity > 2.0)  # 2.0 itself is safe


def test_shaped_cost_of_the_env_follows_its_alpha() -> None:
    """A band as wide as 10 thresholds holds every step of a short random walk: ``1 - (thr - v) / α``."""
    threshold = HALF_CHEETAH.threshold
    env = gym.make(HALF_CHEETAH.env_id, alpha=10 * threshold)
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    for _ in range(20):
        _, _, _, _, info = env.step(rng.uniform(-1, 1, 6))
        assert info[SHAPED_COST_KEY] == pytest.approx(max(0.0, 1 - (threshold - info[VELOCITY_KEY]) / (10 * threshold)))
        assert 0 < info[SHAPED_COST_KEY] < 1
    with pytest.raises(ValueError, match="alpha"):
        gym.make(HALF_CHEETAH.env_id, alpha=-0.1)


def test_pickles_with_its_arguments() -> None:
    env = gym.make(HALF_CHEETAH.env_id, alpha=0.5, reset_noise_scale=0.0).unwrapped
    clone = pickle.loads(pickle.dumps(env))
    assert isinstance(clone, SafetyVelocityEnv)
    assert (clone.alpha, clone.velocity_threshold) == (0.5, HALF_CHEETAH.threshold)
    assert clone.reset(seed=0)[0].tolist() == env.reset(seed=1)[0].tolist()  # no reset noise: any seed, same state
