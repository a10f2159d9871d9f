"""The navigation tasks' rules, checked on the package's own envs (fidelity to Safety-Gymnasium: ``test_fidelity.py``).

Sizes, lengths and rules are Safety-Gymnasium 1.0.0's (``safety_gymnasium/tasks/safe_navigation/``, ``bases/``,
``assets/``): the observation sizes below are what its 24 tasks report after ``make``.
"""

from __future__ import annotations

import itertools

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.common.keys import COST_KEY, SHAPED_COST_KEY
from sppo_sb3.envs.navigation import NAVIGATION_TASKS, SafetyNavigationEnv
from sppo_sb3.envs.navigation.env import GOAL_MET_KEY
from sppo_sb3.envs.navigation.lidar import pseudo_lidar

#: Safety-Gymnasium 1.0.0's flat observation sizes, (robot, task) → levels 0, 1, 2
OBSERVATION_SIZES = {
    ("Point", "Goal"): (28, 60, 60),
    ("Car", "Goal"): (40, 72, 72),
    ("Point", "Button"): (44, 76, 76),
    ("Car", "Button"): (56, 88, 88),
    ("Point", "Push"): (44, 76, 76),
    ("Car", "Push"): (56, 88, 88),
    ("Point", "Circle"): (28, 28, 28),
    ("Car", "Circle"): (40, 40, 40),
}


def test_every_task_is_registered_with_its_sizes_and_length() -> None:
    assert len(NAVIGATION_TASKS) == 24
    for task in NAVIGATION_TASKS:
        env = gym.make(task.env_id)
        assert env.observation_space.shape == (OBSERVATION_SIZES[task.robot, task.task][task.level],), task.env_id
        assert env.action_space.shape == (2,)
        assert env.spec is not None and env.spec.max_episode_steps == (500 if task.task == "Circle" else 1000)
        env.close()


@pytest.mark.parametrize(
    "env_id", ["sppo_sb3/SafetyPointGoal1-v0", "sppo_sb3/SafetyCarButton2-v0", "sppo_sb3/SafetyPointPush2-v0"]
)
def test_passes_sb3_env_checker(env_id: str) -> None:
    check_env(gym.make(env_id).unwrapped)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"robot": "Doggo"}, "unknown robot 'Doggo'"),
        ({"task": "Run"}, "unknown task 'Run'"),
        ({"level": 3}, "unknown level 3"),
        ({"alpha": 0.0}, "alpha"),
    ],
)
def test_bad_arguments_say_what_is_allowed(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SafetyNavigationEnv(**kwargs)


@pytest.mark.parametrize(
    "robot,task,level", [("Point", "Goal", 2), ("Car", "Button", 2), ("Point", "Push", 2), ("Car", "Circle", 2)]
)
def test_layouts_keep_their_keepouts(robot: str, task: str, level: int) -> None:
    env = SafetyNavigationEnv(robot, task, level)
    placements = env.task.sampler.placements
    for seed in range(10):
        env.reset(seed=seed)
        layout = env.layout
        assert set(layout) == set(placements)  # (the goal, re-placed at reset, comes last)
        for (a, xy_a), (b, xy_b) in itertools.combinations(layout.items(), 2):
            gap = np.linalg.norm(xy_a - xy_b) - placements[a].keepout - placements[b].keepout
            assert gap >= -1e-12, (seed, a, b, gap)
        x0, y0, x1, y1 = env.task.extents
        assert all(x0 <= x <= x1 and y0 <= y <= y1 for x, y in layout.values())
        assert env.cost_info()[COST_KEY] == 0.0  # no layout starts in violation


def test_a_seed_repeats_its_episode_and_another_does_not() -> None:
    def rollout(seed: int) -> np.ndarray:
        env = SafetyNavigationEnv("Point", "Goal", 1)
        obs, _ = env.reset(seed=seed)
        actions = np.random.default_rng(0).uniform(-1, 1, (50, 2))
        return np.array([obs, *(env.step(a)[0] for a in actions)])

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.allclose(rollout(3)[0], rollout(4)[0])


def start_frame(env: SafetyNavigationEnv) -> np.ndarray:
    """The rotation (2×2) of the Point's start frame, in which its slide joints move."""
    w, _, _, z = env.model.body_quat[env.model.body("agent").id]
    angle = 2 * np.arctan2(z, w)
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def move_point_to(env: SafetyNavigationEnv, xy: np.ndarray, velocity: tuple[float, float] = (0.0, 0.0)) -> None:
    """Put the Point robot's body at ``xy`` with a world-frame ``velocity`` (its slides move in its start frame)."""
    frame = start_frame(env)
    env.data.qpos[:2] = frame.T @ (xy - env.model.body_pos[env.model.body("agent").id, :2])
    env.data.qvel[:] = 0
    env.data.qvel[:2] = frame.T @ np.asarray(velocity)
    mujoco.mj_forward(env.model, env.data)


def test_a_hazard_costs_inside_its_radius_and_shapes_the_cost_around_it() -> None:
    env = SafetyNavigationEnv("Point", "Goal", 1, alpha=0.2)
    env.reset(seed=0)
    hazard = env.layout["hazard0"]
    away = np.array([1.0, 0.0])
    for distance, cost, shaped in ((0.1, 1.0, 1.0), (0.3, 0.0, 0.5), (0.45, 0.0, 0.0)):
        move_point_to(env, hazard + distance * away)
        info = env.cost_info()
        assert info[COST_KEY] == info["cost_hazards"] == cost, distance
        if shaped == 0.0 or shaped == 1.0:
            assert info[SHAPED_COST_KEY] <= shaped + 1e-9 and (shaped == 0.0 or info[SHAPED_COST_KEY] == 1.0)
        else:  # 0.1 m outside the radius, half of the 0.2 m band, unless another object is nearer
            assert info[SHAPED_COST_KEY] >= shaped - 1e-9


def test_an_unconstrained_vase_never_costs_and_level_two_vases_do() -> None:
    assert "cost_vases_contact" not in SafetyNavigationEnv("Point", "Goal", 1).cost_terms()
    env = SafetyNavigationEnv("Point", "Goal", 2)
    env.reset(seed=0)
    assert {"cost_hazards", "cost_vases_contact", "cost_vases_velocity"} <= set(env.cost_terms())


def test_reaching_the_goal_pays_one_and_moves_the_goal_clear_of_everything() -> None:
    env = SafetyNavigationEnv("Point", "Goal", 1)
    env.reset(seed=0)
    goal = env.layout["goal"].copy()
    move_point_to(env, goal + np.array([0.05, 0.0]))
    env.task.last_dist_goal = 0.05  # as if the robot had already been there: the reward is the goal's +1 alone
    _, reward, terminated, _, info = env.step(np.zeros(2))
    assert info[GOAL_MET_KEY] and not terminated
    assert reward == pytest.approx(1.0, abs=1e-3)
    new_goal = env.layout["goal"]
    assert not np.allclose(new_goal, goal)
    np.testing.assert_allclose(env.data.body("goal").xpos[:2], new_goal)
    placements = env.task.sampler.placements
    for name, xy in env.layout.items():
        if name != "goal":
            assert np.linalg.norm(new_goal - xy) >= placements["goal"].keepout + placements[name].keepout - 1e-12


def test_a_pressed_button_hides_the_buttons_for_ten_steps() -> None:
    env = SafetyNavigationEnv("Point", "Button", 1)
    env.reset(seed=0)
    keys = [key for key, _ in env.observation_keys]
    start = sum(size for _, size in env.observation_keys[: keys.index("buttons_lidar")])
    assert env.observe()[start : start + 16].any()
    env.task.next_goal(env.world, np.random.RandomState(0), env.layout)  # as after a press: the timer restarts
    for _ in range(10):
        assert env.task.constrained_goal_button() is None and "cost_buttons" not in env.cost_terms()
        obs, *_ = env.step(np.zeros(2))
    assert env.task.timer == 0 and obs[start : start + 16].any() and "cost_buttons" in env.cost_terms()


def test_circle_walls_cost_outside_their_band() -> None:
    env = SafetyNavigationEnv("Point", "Circle", 2)
    env.reset(seed=0)
    for xy, cost in (((1.0, 1.0), 0.0), ((1.2, 0.0), 1.0), ((0.0, -1.2), 1.0)):
        move_point_to(env, np.array(xy))
        assert env.cost_info()[COST_KEY] == cost, xy
    level1 = SafetyNavigationEnv("Point", "Circle", 1)
    level1.reset(seed=0)
    move_point_to(level1, np.array([0.0, -1.2]))
    assert level1.cost_info()[COST_KEY] == 0.0  # level 1 bounds x only


def test_circle_rewards_running_counterclockwise() -> None:
    env = SafetyNavigationEnv("Point", "Circle", 0)
    env.reset(seed=0)
    move_point_to(env, np.array([1.5, 0.0]), velocity=(0.0, 1.0))
    assert env.task.reward(env.world) == pytest.approx(0.1, rel=1e-6)  # (−u·y + v·x)/r = 1 m/s on the circle


def test_pseudo_lidar_bins_and_aliasing() -> None:
    identity = np.eye(3)
    reading = pseudo_lidar(np.array([[1.5, 0.0, 0.0]]), np.zeros(3), identity, max_dist=3.0)
    assert reading[0] == pytest.approx(0.5) and reading[1] == 0.0 and reading[15] == pytest.approx(0.5)
    bin_size = 2 * np.pi / 16
    angle = 2.25 * bin_size  # a quarter into bin 2: bin 3 reads a quarter, bin 1 three quarters
    reading = pseudo_lidar(np.array([[np.cos(angle), np.sin(angle)]]), np.zeros(3), identity, max_dist=3.0)
    np.testing.assert_allclose(reading[[1, 2, 3]], np.array([0.75, 1.0, 0.25]) * 2 / 3)
    near_far = pseudo_lidar(np.array([[1.0, 0.0], [2.0, 0.0]]), np.zeros(3), identity, max_dist=3.0)
    assert near_far[0] == pytest.approx(2 / 3)  # the nearer object wins its bin
    assert not pseudo_lidar(np.array([[4.0, 0.0]]), np.zeros(3), identity, max_dist=3.0).any()
