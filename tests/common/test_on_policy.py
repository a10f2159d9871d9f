"""The shared cost-aware on-policy machinery: cost GAE, the cost buffer, the cost critic head, the tracker, the rollout
loop every on-policy algorithm runs on (spaces, VecNormalize, SB3's warnings), errors."""

from __future__ import annotations

import contextlib
import inspect
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecNormalize
from tiny_hyperparams import QUICK_CSC, TINY_ON_POLICY

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_lab.configs import REPO_HYPERPARAMS_DIR as HYPERPARAMS_DIR
from sppo_sb3.common.cost_buffer import CostRolloutBuffer
from sppo_sb3.common.cost_policy import CostActorCriticPolicy
from sppo_sb3.common.costs import MissingCostError
from sppo_sb3.common.gae import compute_gae
from sppo_sb3.common.keys import EPISODE_COST_ESTIMATE_LOG_KEY, LAGRANGE_MULTIPLIER_LOG_KEY
from sppo_sb3.common.lagrange import DEFAULT_COST_LIMIT
from sppo_sb3.common.safety import EpisodeCostTracker, SafetyMetrics
from sppo_sb3.cpo import CPO
from sppo_sb3.csc import CSC
from sppo_sb3.pdo import PDO
from sppo_sb3.sailr import SAILR


def test_cost_gae_hand_computed() -> None:
    # one env, 3 steps, an episode boundary before step 2; gamma = 0.5, lambda = 0.5
    costs = np.array([[1.0], [0.0], [1.0]])
    values = np.array([[0.5], [1.0], [0.25]])
    starts = np.array([[1.0], [0.0], [1.0]])
    adv, ret = compute_gae(
        costs, values, starts, last_values=np.array([2.0]), dones=np.array([False]), gamma=0.5, gae_lambda=0.5
    )
    # step 2: δ = 1 + 0.5·2 - 0.25 = 1.75, A = 1.75
    # step 1: next step starts an episode → δ = 0 - 1 = -1, A = -1
    # step 0: δ = 1 + 0.5·1 - 0.5 = 1, A = 1 + 0.25·(-1) = 0.75
    np.testing.assert_allclose(adv[:, 0], [0.75, -1.0, 1.75])
    np.testing.assert_allclose(ret[:, 0], [1.25, 0.0, 2.0])
    # a terminal last step: no bootstrap
    adv, _ = compute_gae(costs, values, starts, last_values=np.array([2.0]), dones=np.array([True]), gamma=0.5, gae_lambda=0.5)
    assert adv[2, 0] == pytest.approx(0.75)


def test_cost_gae_matches_sb3_reward_gae() -> None:
    rng = np.random.default_rng(0)
    n_steps, n_envs = 7, 3
    obs_space = spaces.Box(-1, 1, (2,))
    act_space = spaces.Box(-1, 1, (1,))
    sb3 = RolloutBuffer(n_steps, obs_space, act_space, gamma=0.9, gae_lambda=0.8, n_envs=n_envs)
    rewards, values = rng.normal(size=(n_steps, n_envs)), rng.normal(size=(n_steps, n_envs))
    starts = rng.random((n_steps, n_envs)) < 0.3
    for t in range(n_steps):
        sb3.add(np.zeros((n_envs, 2)), np.zeros((n_envs, 1)), rewards[t], starts[t], th.tensor(values[t]), th.zeros(n_envs))
    last, dones = rng.normal(size=n_envs), np.array([True, False, False])
    sb3.compute_returns_and_advantage(th.tensor(last), dones)
    adv, ret = compute_gae(rewards, values, starts, last, dones, 0.9, 0.8)
    np.testing.assert_allclose(adv, sb3.advantages, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ret, sb3.returns, rtol=1e-5, atol=1e-5)


def _filled_buffer(masks: np.ndarray) -> CostRolloutBuffer:
    n_steps, n_envs = masks.shape
    buf = CostRolloutBuffer(
        n_steps, spaces.Box(-1, 1, (1,)), spaces.Box(-1, 1, (1,)), gamma=0.9, gae_lambda=1.0, n_envs=n_envs
    )
    for t in range(n_steps):
        obs = np.full((n_envs, 1), t, dtype=np.float32)
        buf.add(obs, np.zeros((n_envs, 1)), np.ones(n_envs), np.zeros(n_envs), th.zeros(n_envs), th.zeros(n_envs),
                cost=np.full(n_envs, 1.0), cost_value=th.zeros(n_envs), mask=masks[t])  # fmt: skip
    buf.compute_returns_and_advantage(th.zeros(n_envs), np.zeros(n_envs, dtype=bool), last_cost_values=th.zeros(n_envs))
    return buf


def test_cost_buffer_stores_cost_gae_and_masks() -> None:
    masks = np.array([[1, 1], [1, 0], [0, 0], [1, 1]], dtype=np.float32)
    buf = _filled_buffer(masks)
    # constant cost 1, zero values, gamma 0.9, lambda 1: discounted cost-to-go
    np.testing.assert_allclose(buf.cost_returns[:, 0], [1 + 0.9 + 0.81 + 0.729, 1 + 0.9 + 0.81, 1.9, 1.0], rtol=1e-6)
    assert buf.n_learnable == 5
    seen = np.concatenate([batch.observations.numpy().ravel() for batch in buf.get(batch_size=2)])
    assert len(seen) == 5
    # step 2 is masked in both envs, step 1 in env 1 only
    assert sorted(seen.tolist()) == [0.0, 0.0, 1.0, 3.0, 3.0]
    full = next(buf.get(None))
    assert full.cost_returns.shape == (5,)


def test_cost_policy_head_and_save_params() -> None:
    policy = CostActorCriticPolicy(spaces.Box(-1, 1, (3,)), spaces.Box(-1, 1, (2,)), lambda _: 1e-3, net_arch=[8])
    assert policy.cost_net_arch == [8]
    out = policy.predict_cost_values(th.zeros(5, 3))
    assert out.shape == (5, 1)
    # the cost head is trained by the optimiser and named "value" (TRPO's natural gradient skips it)
    head = {id(p) for p in policy.cost_value_net.parameters()}
    assert head <= {id(p) for group in policy.optimizer.param_groups for p in group["params"]}
    assert all("value" in name for name, _ in policy.named_parameters() if name.startswith("cost_value_net"))
    assert policy._get_constructor_parameters()["cost_net_arch"] == [8]


def test_episode_cost_tracker() -> None:
    tracker = EpisodeCostTracker(n_envs=2)
    tracker.start_rollout()
    tracker.update(np.array([1.0, 0.0]), np.array([False, False]))
    assert tracker.estimate() == pytest.approx(0.5)  # no finished episode yet: running mean
    tracker.update(np.array([1.0, 0.0]), np.array([True, False]))
    assert tracker.estimate() == pytest.approx(2.0) and tracker.mean_length() == 2.0
    tracker.start_rollout()  # nothing finished in this rollout: the recent window
    assert tracker.estimate() == pytest.approx(2.0)
    tracker.update(np.array([0.0, 0.0]), np.array([False, True]))
    assert tracker.estimate() == pytest.approx(0.0) and tracker.mean_length() == 3.0


@pytest.mark.parametrize("algo", [PDO, CPO, SAILR])
def test_missing_cost_is_a_clear_error(algo: type) -> None:
    kwargs = {"shield": None} if algo is SAILR else {}
    with pytest.warns(UserWarning, match="plain PPO") if algo is SAILR else contextlib.nullcontext():
        model = algo("MlpPolicy", "Pendulum-v1", **TINY_ON_POLICY, **kwargs)
    with pytest.raises(MissingCostError, match=r"info\['cost'\]"):
        model.learn(64)
    assert model.num_timesteps == 0  # failed on the very first step


def test_wrong_buffer_or_policy_is_a_clear_error() -> None:
    with pytest.raises(TypeError, match="CostRolloutBuffer"):
        PDO(
            "MlpPolicy",
            "SafePointCircle-v0",
            rollout_buffer_class=RolloutBuffer,
            **TINY_ON_POLICY,
        )
    from stable_baselines3.common.policies import ActorCriticPolicy

    with pytest.raises(TypeError, match="CostActorCriticPolicy"):
        PDO(ActorCriticPolicy, "SafePointCircle-v0", **TINY_ON_POLICY)


@pytest.mark.parametrize("algo", [PDO, CPO])
def test_safety_metrics_logged_once(algo: type, tmp_path) -> None:
    """The safety figures and the measured episode cost appear under ``safety/``, and the cost under no other key."""
    model = algo("MlpPolicy", "SafePointCircle-v0", seed=1, **_tiny(algo))
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(256)
    header = set((tmp_path / "progress.csv").read_text().splitlines()[0].split(","))
    assert {"safety/cumulative_violations", "safety/safety_rate", EPISODE_COST_ESTIMATE_LOG_KEY} <= header
    assert [key for key in header if key.endswith("ep_cost_estimate")] == [EPISODE_COST_ESTIMATE_LOG_KEY]
    assert model.safety_metrics.steps == 256


@pytest.mark.parametrize("algo", [PDO, CPO, SAILR, CSC])
def test_callbacks_see_costs_and_can_stop(algo: type, tmp_path) -> None:
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback

    class StopAt(BaseCallback):
        def _on_step(self) -> bool:
            assert "costs" in self.locals and "infos" in self.locals
            return self.num_timesteps < 100

    model = algo("MlpPolicy", "SafePointCircle-v0", seed=0, **_tiny(algo))
    model.learn(256, callback=CallbackList([CheckpointCallback(64, str(tmp_path)), StopAt()]))
    assert model.num_timesteps == 100
    assert len(list(tmp_path.glob("*.zip"))) == 1


class _MatrixActions(gym.ActionWrapper):
    """The Point task behind a Box action space of shape (2, 2): the env executes the mean of the two rows."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.action_space = spaces.Box(-1.0, 1.0, (2, 2), np.float32)

    def action(self, action: np.ndarray) -> np.ndarray:
        return action.mean(axis=0)


def _tiny(algo: type) -> dict[str, Any]:
    """Small-budget arguments of each on-policy algorithm (the others' own update budgets at their defaults)."""
    return QUICK_CSC if algo is CSC else TINY_ON_POLICY


@pytest.mark.parametrize("algo", [PDO, CPO, SAILR, CSC])
def test_multi_dimensional_box_actions(algo: type) -> None:
    """A Box of shape (2, 2) trains, and predict returns actions of that shape."""
    env = _MatrixActions(gym.make("SafePointCircle-v0"))
    kwargs = {"shield": None} if algo is SAILR else {}  # the Point task's shield acts on its own (2,) actions
    with pytest.warns(UserWarning, match="plain PPO") if algo is SAILR else contextlib.nullcontext():
        model = algo("MlpPolicy", env, seed=0, **_tiny(algo), **kwargs)
    model.learn(128)
    assert model.num_timesteps == 128
    actions, _ = model.predict(np.zeros((3, 4), dtype=np.float32), deterministic=True)
    assert actions.shape == (3, 2, 2)


@pytest.mark.parametrize("algo", [PDO, CPO, SAILR, CSC])
def test_safety_metrics_see_the_original_rewards_under_vec_normalize(algo: type) -> None:
    """The episode returns of the safety metrics are the env's (Monitor's), not VecNormalize's scaled rewards."""
    env = VecNormalize(make_vec_env("SafePointCircle-v0", n_envs=2, seed=0, env_kwargs=dict(max_episode_steps=20)))
    model = algo("MlpPolicy", env, seed=0, **_tiny(algo))
    model.learn(128)
    monitored = [info["r"] for info in model.ep_info_buffer]
    returns = [episode["return"] for episode in model.safety_metrics.recent]
    assert len(monitored) == len(returns) >= 6
    np.testing.assert_allclose(returns, monitored, atol=1e-5)
    original = env.get_original_reward()
    assert not np.allclose(env.normalize_reward(original), original, atol=1e-2)  # the learner sees other rewards


@pytest.mark.parametrize("algo", [PDO, CPO, SAILR, CSC])
def test_recommends_the_cpu_off_the_cpu(algo: type) -> None:
    """SB3's advice to run MLP policies on the CPU, as PPO gives it; device "meta" stands in for a GPU."""
    with pytest.warns(UserWarning, match="primarily intended to run on the CPU"):
        algo("MlpPolicy", "SafePointCircle-v0", device="meta", **_tiny(algo))
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*primarily intended to run on the CPU")
        algo("MlpPolicy", "SafePointCircle-v0", device="cpu", **_tiny(algo))


@pytest.mark.parametrize("algo", [PDO, CSC])
def test_pdo_and_csc_share_one_lagrange_multiplier(algo: type, tmp_path) -> None:
    """The same dual step on the tracker's measured episode cost (also when no episode ended), under one log key."""
    model = algo("MlpPolicy", "SafePointCircle-v0", cost_limit=0.2, lagrange_lr=0.5, lagrange_init=0.1, **_tiny(algo))
    model.set_logger(configure(str(tmp_path), ["csv"]))
    tracker = model.cost_tracker
    tracker.start_rollout()
    for t in range(10):  # one episode of cost 1
        tracker.update(np.array([1.0 if t == 9 else 0.0]), np.array([t == 9]))
    assert model.update_lagrange_multiplier() == pytest.approx(0.1 + 0.5 * (1.0 - 0.2))
    tracker.start_rollout()  # no episode ends in this rollout: the mean of the recent ones
    assert model.update_lagrange_multiplier() == pytest.approx(0.5 + 0.5 * (1.0 - 0.2))
    model.logger.dump(0)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    assert LAGRANGE_MULTIPLIER_LOG_KEY in header


@pytest.mark.parametrize("algo", [PDO, CPO, CSC])
def test_constrained_baselines_share_one_cost_limit(algo: type) -> None:
    assert inspect.signature(algo).parameters["cost_limit"].default == DEFAULT_COST_LIMIT
    with open(HYPERPARAMS_DIR / f"{algo.__name__.lower()}.yml") as file:
        entries = yaml.safe_load(file)
    assert {task: entry["cost_limit"] for task, entry in entries.items()} == dict.fromkeys(entries, DEFAULT_COST_LIMIT)


def test_final_summary_gives_the_last_episodes_return() -> None:
    """The line printed after training: the mean return of the recent window and of the last FINAL_EPISODES."""
    metrics = SafetyMetrics(n_envs=1)
    assert "(last 0)=nan  " in metrics.format_summary()  # no episode yet: no final mean either
    for episode_return in [0.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0]:
        metrics.update(np.array([episode_return]), np.zeros(1), np.ones(1, dtype=bool))
    line = metrics.format_summary()
    assert "mean return (last 7)=21.43 (last 5: 30.00)" in line and "cumulative violations=0" in line
