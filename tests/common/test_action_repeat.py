"""Action repeat: a held action's env steps add up, every one of them passes the shield, and the safety metrics count
env steps, not agent steps."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.common.action_repeat import ActionRepeat
from sppo_sb3.common.keys import COST_KEY, COSTLY_STEPS_KEY, ENV_STEPS_KEY, INTERVENED_KEY, INTERVENTIONS_KEY
from sppo_sb3.common.monitor import EpisodeCostInfo
from sppo_sb3.common.safety import SafetyMetrics
from sppo_sb3.shield import ShieldWrapper

POINT = "SafePointCircle-v0"
THRUST_X = np.array([1.0, 0.0], dtype=np.float32)  # full thrust along x: into the wall at x = 2.5


def test_a_held_action_sums_its_env_steps() -> None:
    repeated, plain = ActionRepeat(gym.make(POINT), 5), gym.make(POINT)
    repeated.reset(seed=0), plain.reset(seed=0)
    for _ in range(4):
        obs, reward, terminated, truncated, info = repeated.step(THRUST_X)
        steps = [plain.step(THRUST_X) for _ in range(info[ENV_STEPS_KEY])]
        np.testing.assert_array_equal(obs, steps[-1][0])
        assert reward == pytest.approx(sum(step[1] for step in steps))
        assert info[COST_KEY] == sum(step[4][COST_KEY] for step in steps)
        assert info[ENV_STEPS_KEY] == 5 and (terminated, truncated) == steps[-1][2:4]


def test_a_held_action_ends_with_the_episode() -> None:
    env = ActionRepeat(gym.make(POINT), 5)  # unshielded: the robot crosses the wall and the episode ends there
    env.reset(seed=0)
    for _ in range(100):
        _, _, terminated, _, info = env.step(THRUST_X)
        if terminated:
            break
    assert terminated and info[COSTLY_STEPS_KEY] == 1 and 1 <= info[ENV_STEPS_KEY] <= 5


def test_a_proposal_held_into_the_unsafe_set_costs_nothing_behind_the_shield() -> None:
    """The shield checks every env step of a held action: the wall is never crossed."""
    env = ShieldWrapper(gym.make(POINT), "auto", action_repeat=5)
    env.reset(seed=0)
    costs = env_steps = interventions = 0
    for _ in range(100):
        _, _, terminated, truncated, info = env.step(THRUST_X)
        costs += info[COST_KEY]
        env_steps += info[ENV_STEPS_KEY]
        interventions += info[INTERVENTIONS_KEY]
        assert info[INTERVENED_KEY] == (info[INTERVENTIONS_KEY] > 0) and not terminated
    assert truncated and costs == 0 and env_steps == 500  # the 500-step episode, held 5 env steps at a time
    assert interventions > 100  # more intervened env steps than agent steps: the held steps were checked


def test_checking_only_the_first_env_step_of_a_held_action_pays() -> None:
    """The same proposals, shielded at the agent's step only and then held: the robot crosses the wall, so the test
    above can fail."""
    env = ActionRepeat(gym.make(POINT), 5)
    rule = ShieldWrapper(gym.make(POINT), "auto").rule
    obs, _ = env.reset(seed=0)
    costs = 0.0
    for _ in range(100):
        decided = rule.shield(obs[None].astype(np.float64), THRUST_X[None].astype(np.float64)).actions[0]
        obs, _, terminated, _, info = env.step(decided.astype(np.float32))
        costs += info[COST_KEY]
        if terminated:
            break
    assert costs > 0


def test_the_unshielded_repeat_pays_so_the_test_above_can_fail() -> None:
    env = ActionRepeat(gym.make(POINT), 5)
    env.reset(seed=0)
    assert sum(env.step(THRUST_X)[4][COST_KEY] for _ in range(100)) > 0


def test_a_shield_outside_an_unshielded_repeat_is_refused() -> None:
    """Shielding the first env step of each held action only would fail open."""
    with pytest.raises(ValueError, match=r"only the first env step.*ShieldWrapper\(env, rule, action_repeat=k\)"):
        ShieldWrapper(ActionRepeat(gym.make(POINT), 5), "auto")


@pytest.mark.parametrize("repeat", [0, -1, 2.5, True])
def test_an_action_repeat_is_a_positive_int(repeat: object) -> None:
    with pytest.raises(ValueError, match="an int >= 1"):
        ShieldWrapper(gym.make(POINT), "auto", action_repeat=repeat)  # type: ignore[arg-type]


def test_continue_charges_the_penalty_per_intervened_env_step() -> None:
    told, silent = (ShieldWrapper(gym.make(POINT), "auto", penalty=p, action_repeat=5) for p in (0.5, 0.0))
    told.reset(seed=0), silent.reset(seed=0)
    for _ in range(60):
        _, told_reward, *_, info = told.step(THRUST_X)
        _, silent_reward, *_ = silent.step(THRUST_X)
        assert told_reward == pytest.approx(silent_reward - 0.5 * info[INTERVENTIONS_KEY])


def test_the_safety_metrics_and_the_monitor_count_env_steps() -> None:
    """Costly env steps and intervened env steps, not agent steps: a held action that crosses the wall is one costly
    env step whatever the repeat, and the metrics' steps are the env's."""
    metrics, env_steps, agent_steps = SafetyMetrics(n_envs=1), 0, 0
    env = DummyVecEnv([lambda: EpisodeCostInfo(ActionRepeat(gym.make(POINT), 5))])
    env.reset()
    for agent_steps in range(1, 101):  # noqa: B007
        _, rewards, dones, infos = env.step(THRUST_X[None])
        metrics.update_from_infos(rewards, dones, infos)
        env_steps += infos[0][ENV_STEPS_KEY]
        if dones[0]:
            break
    assert metrics.violations == 1 and metrics.unsafe_episodes == 1 and infos[0]["episode_violations"] == 1
    assert metrics.steps == env_steps > agent_steps

    metrics, interventions = SafetyMetrics(n_envs=1), 0
    env = DummyVecEnv([lambda: EpisodeCostInfo(ShieldWrapper(gym.make(POINT), "auto", action_repeat=5))])
    env.reset()
    for _ in range(100):
        _, rewards, dones, infos = env.step(THRUST_X[None])
        metrics.update_from_infos(rewards, dones, infos)
        interventions += infos[0][INTERVENTIONS_KEY]
    assert metrics.interventions == interventions > 100  # more intervened env steps than agent steps
    assert metrics.violations == 0 and metrics.steps == 500


def test_sailr_refuses_actions_held_where_its_shield_does_not_see_them() -> None:
    from tiny_hyperparams import TINY_SAILR

    from sppo_sb3 import SAILR

    with pytest.raises(ValueError, match="only the first env step of each action that ActionRepeat holds"):
        SAILR("MlpPolicy", ActionRepeat(gym.make(POINT), 5), **TINY_SAILR)


def test_deployment_holds_each_action_as_long_as_training_did() -> None:
    """A model trained behind ``ShieldWrapper(..., action_repeat=5)`` is deployed at the same time scale: with its
    shield (every env step checked) and alone, each of its actions is held for 5 env steps."""
    from tiny_hyperparams import TINY_SPPO

    from sppo_sb3 import SPPO
    from sppo_sb3.shield.evaluation import deployment_action_repeat, evaluate_deployment, run_episode

    env = ShieldWrapper(gym.make(POINT), "auto", action_repeat=5)
    model = SPPO("TOLDPolicy", env, **{**TINY_SPPO, "learning_starts": 20, "seed": 0}).learn(40)
    assert deployment_action_repeat(model) == 5
    held = {True: ShieldWrapper(gym.make(POINT), env.rule, action_repeat=5), False: ActionRepeat(gym.make(POINT), 5)}
    for shielded, held_env in held.items():
        episode = run_episode(model, held_env, seed=0)
        metrics = evaluate_deployment(model, lambda: gym.make(POINT), n_eval_episodes=1, shielded=shielded, seed=0)
        assert metrics["mean_reward"] == pytest.approx(episode.reward)
        assert episode.length == 100 if shielded else episode.terminated  # alone, this tiny policy crosses the wall
