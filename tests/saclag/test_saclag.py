"""SACLag's behaviour: the cost critic's Bellman target, the replay buffer's costs, the dual step on ``λ``, what a large
``λ`` does to the actor, its errors, and its safety metrics (logged and saved). SB3's contracts are in
``tests/test_contracts.py``.

The learning test runs on :class:`CostlyBandit`, a one-step task whose rewarded actions cost: the action ``a`` in
[-1, 1] earns ``a`` and costs ``1[a > 0]``. Its thresholds were measured over seeds 0-7 at this test's settings (600
env steps): the deterministic action was 0.80-0.83 with ``λ = 0`` and -0.64 to -0.47 with ``λ = 10``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.logger import Logger, configure
from stable_baselines3.sac.policies import SACPolicy
from tiny_hyperparams import TINY_SACLAG

from sppo_sb3 import SACLag
from sppo_sb3.common.cost_buffer import CostReplayBuffer, CostReplayBufferSamples
from sppo_sb3.common.costs import MissingCostError
from sppo_sb3.common.keys import EPISODE_COST_ESTIMATE_LOG_KEY, LAGRANGE_MULTIPLIER_LOG_KEY, SAFETY_LOG_PREFIX


class CostlyBandit(gym.Env):
    """One step per episode from a constant observation: the action ``a`` earns ``a`` and costs ``1[a > 0]``.

    The best cost-free action is ``a = 0`` (reward 0); the best action is ``a = 1`` (reward 1, cost 1), better than
    every cost-free one for ``λ < 1``.

    :param obs_dim: entries of the (zero) observation.
    :param report_cost: put ``info["cost"]`` in the step's info.
    """

    def __init__(self, obs_dim: int = 1, report_cost: bool = True) -> None:
        self.observation_space = spaces.Box(-1, 1, (obs_dim,), np.float32)
        self.action_space = spaces.Box(-1, 1, (1,), np.float32)
        self.report_cost = report_cost

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        return np.zeros(self.observation_space.shape, np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = float(np.asarray(action).reshape(-1)[0])
        info = {"cost": float(a > 0)} if self.report_cost else {}
        return np.zeros(self.observation_space.shape, np.float32), a, True, False, info


def silent(model: SACLag) -> SACLag:
    """The model with a logger that writes nothing (for calling ``train`` outside ``learn``)."""
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


# ------------------------------------------------------------------------------------------------ the cost critic
@pytest.mark.parametrize("n_cost_critics", [1, 2])
def test_bellman_targets_by_hand(n_cost_critics: int) -> None:
    """``c + γ_C (1 - done) max_i Q_C,i'(s', a')`` with the *target* cost critic and ``γ_C``, beside SAC's soft reward
    target ``r + γ (1 - done)(min_j Q_j'(s', a') - α log π(a'|s'))``, both on the same ``a' ~ π(·|s')``."""
    policy_kwargs = dict(net_arch=[8], n_cost_critics=n_cost_critics)
    model = SACLag("MlpPolicy", CostlyBandit(obs_dim=2), gamma=0.9, cost_gamma=0.5, policy_kwargs=policy_kwargs, seed=0)
    with th.no_grad():  # the online cost critic no longer equals its target: a target read from it would differ
        for param in model.cost_critic.parameters():
            param.add_(0.5)
    gen = th.Generator().manual_seed(3)
    obs, next_obs = th.rand(4, 2, generator=gen) * 2 - 1, th.rand(4, 2, generator=gen) * 2 - 1
    data = CostReplayBufferSamples(
        observations=obs,
        actions=th.rand(4, 1, generator=gen) * 2 - 1,
        next_observations=next_obs,
        dones=th.tensor([[0.0], [1.0], [0.0], [0.0]]),
        rewards=th.tensor([[0.5], [-1.0], [2.0], [0.0]]),
        costs=th.tensor([[1.0], [1.0], [0.0], [0.25]]),
    )
    alpha = th.tensor(0.3)
    th.manual_seed(11)
    reward_target, cost_target = model._bellman_targets(data, alpha)

    th.manual_seed(11)  # the same next actions, drawn by hand
    with th.no_grad():
        next_actions, next_log_prob = model.actor.action_log_prob(next_obs)
        inputs = th.cat([next_obs, next_actions], dim=1)
        cost_q = th.cat([q(inputs) for q in model.cost_critic_target.q_networks], dim=1).max(dim=1, keepdim=True).values
        reward_q = th.cat([q(inputs) for q in model.critic_target.q_networks], dim=1).min(dim=1, keepdim=True).values
    not_done = 1.0 - data.dones
    th.testing.assert_close(cost_target, data.costs + 0.5 * not_done * cost_q)
    th.testing.assert_close(reward_target, data.rewards + 0.9 * not_done * (reward_q - 0.3 * next_log_prob.reshape(-1, 1)))
    assert cost_target[1].item() == 1.0  # a terminal: the cost alone


def test_replay_buffer_costs_belong_to_their_transitions() -> None:
    """Sampled costs come from the same env and step as the rest (here ``c = s[0]``, ``r = -s[0]``); a time-limit
    truncation bootstraps (``done = 0``) and a termination does not."""
    space = spaces.Box(-10, 10, (1,), np.float32)
    buffer = CostReplayBuffer(100, space, spaces.Box(-1, 1, (1,), np.float32), device="cpu", n_envs=2)
    for step in range(20):
        obs = np.array([[step], [100 + step]], dtype=np.float32) / 100
        done = np.array([step % 5 == 4, step % 7 == 6])
        truncated = [step % 5 == 4, False]  # env 0's episodes are cut by a time limit, env 1's terminate
        infos = [{"cost": float(o[0]), "TimeLimit.truncated": cut} for o, cut in zip(obs, truncated)]
        buffer.add(obs, obs + 1, np.zeros((2, 1), np.float32), -obs[:, 0], done, infos)
    data = buffer.sample(256)
    th.testing.assert_close(data.costs, data.observations)
    th.testing.assert_close(data.rewards, -data.observations)
    env_1 = data.observations[:, 0] >= 1.0
    steps = th.round(data.observations[:, 0] * 100).long() % 100
    assert th.all(data.dones[~env_1, 0] == 0)  # env 0's episode ends are all truncations
    th.testing.assert_close(data.dones[env_1, 0], (steps[env_1] % 7 == 6).float())
    assert env_1.any() and (~env_1).any()


# ------------------------------------------------------------------------------------------------ the multiplier
def test_lagrange_multiplier_rises_above_the_limit_and_falls_to_zero_below() -> None:
    """Each ``train`` takes one step ``λ ← max(0, λ + η(J_C - d))`` on the mean cost of the last ``cost_window``
    finished episodes, whatever the number of gradient steps."""
    model = silent(
        SACLag("MlpPolicy", CostlyBandit(), cost_limit=2.0, lagrange_lr=0.5, lagrange_init=1.0, cost_window=2, seed=0)
    )
    tracker = model.cost_tracker

    def episode_then_dual_step(cost: float | None) -> float:
        if cost is not None:
            tracker.update(np.array([cost]), np.array([True]))
        model.train(gradient_steps=0, batch_size=8)
        return model.lagrange_multiplier

    tracker.update(np.array([5.0]), np.array([True]))
    assert episode_then_dual_step(7.0) == pytest.approx(1.0 + 0.5 * (6.0 - 2.0))  # J_C = mean(5, 7) > d = 2
    # the window (7, 0), not the episodes since the last step (0) nor all of them (5, 7, 0): J_C = 3.5
    assert episode_then_dual_step(0.0) == pytest.approx(3.0 + 0.5 * (3.5 - 2.0))
    assert episode_then_dual_step(0.0) == pytest.approx(3.75 - 0.5 * 2.0)  # J_C = 0 < d: down by η·d a step
    assert [episode_then_dual_step(None) for _ in range(4)] == pytest.approx([1.75, 0.75, 0.0, 0.0])  # never below 0


@pytest.mark.parametrize(("cost_limit", "lagrange_init"), [(0.0, 0.0), (1.0, 1.0)])
def test_lagrange_multiplier_follows_the_costs_while_learning(cost_limit: float, lagrange_init: float) -> None:
    """On the bandit, whose episodes cost at most 1: with ``d = 0`` the warm-up's costly episodes push ``λ`` up; with
    ``d = 1`` no episode exceeds the limit and ``λ`` falls from 1 to exactly 0."""
    model = SACLag(
        "MlpPolicy",
        CostlyBandit(),
        cost_limit=cost_limit,
        lagrange_init=lagrange_init,
        lagrange_lr=0.05,
        **{**TINY_SACLAG, "learning_starts": 50},
        seed=0,
    )
    model.learn(150)
    if cost_limit == 0.0:
        assert model.lagrange_multiplier > 0.5  # 100 dual steps on J_C ≈ 0.5 (uniform warm-up actions)
    else:
        assert model.lagrange_multiplier == 0.0


# ------------------------------------------------------------------------------------------------ the actor
@pytest.mark.parametrize(("lagrange_multiplier", "low", "high"), [(0.0, 0.5, 1.0), (10.0, -1.0, -0.2)])
def test_large_multiplier_makes_the_actor_prefer_the_cost_free_action(
    lagrange_multiplier: float, low: float, high: float
) -> None:
    """With ``λ = 0`` SAC takes the rewarded, costly action ``a ≈ 1``; with a fixed ``λ = 10`` (``r - λc`` is best at
    ``a <= 0``) the actor's penalty ``λ·Q_C`` moves it below 0. Measured: 0.80-0.83 and -0.64 to -0.47 (seeds 0-7)."""
    model = SACLag(
        "MlpPolicy",
        CostlyBandit(),
        learning_starts=100,
        batch_size=64,
        learning_rate=3e-3,
        buffer_size=10_000,
        lagrange_lr=0.0,  # λ stays at lagrange_init
        lagrange_init=lagrange_multiplier,
        policy_kwargs=dict(net_arch=[32]),
        seed=0,
    )
    model.learn(600)
    assert model.lagrange_multiplier == lagrange_multiplier
    action = float(model.predict(np.zeros(1, np.float32), deterministic=True)[0][0])
    assert low < action < high


# ------------------------------------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(cost_limit=-1.0), ValueError, "cost_limit must be >= 0"),
        (dict(lagrange_lr=-0.1), ValueError, "lagrange_lr must be >= 0"),
        (dict(lagrange_init=-1.0), ValueError, "lagrange_init must be >= 0"),
        (dict(cost_gamma=1.5), ValueError, r"cost_gamma is a discount in \[0, 1\]"),
        (dict(cost_window=0), ValueError, "cost_window must be >= 1"),
        (dict(policy_kwargs=dict(n_cost_critics=0)), ValueError, "n_cost_critics must be >= 1"),
        (dict(replay_buffer_class=ReplayBuffer), TypeError, "needs a CostReplayBuffer"),
    ],
)
def test_bad_arguments_are_clear_errors(kwargs: dict[str, Any], error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        SACLag("MlpPolicy", CostlyBandit(), **kwargs)


def test_policy_without_cost_critic_and_env_without_costs_are_clear_errors() -> None:
    with pytest.raises(TypeError, match="must be a SACLagPolicy"):
        SACLag(SACPolicy, CostlyBandit())
    model = SACLag("MlpPolicy", CostlyBandit(report_cost=False), **TINY_SACLAG)
    with pytest.raises(MissingCostError, match="did not report"):
        model.learn(4)


# ------------------------------------------------------------------------------------------------ safety metrics
def test_safety_metrics_are_logged_and_saved(tmp_path) -> None:
    """``safety/`` figures, ``J_C`` and ``λ`` in ``progress.csv``; the metrics, the tracker's window and ``λ`` survive
    save/load, and a resumed run keeps counting."""
    model = SACLag("MlpPolicy", CostlyBandit(), lagrange_lr=0.05, **TINY_SACLAG, seed=0)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(100, log_interval=10)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in ("episodes", "cumulative_violations", "safety_rate", "ep_cost_mean"):
        assert f"{SAFETY_LOG_PREFIX}{key}" in header
    assert {EPISODE_COST_ESTIMATE_LOG_KEY, LAGRANGE_MULTIPLIER_LOG_KEY, "train/cost_critic_loss", "train/cost_q"} <= set(
        header
    )
    metrics = model.safety_metrics
    assert metrics.episodes == metrics.steps == 100 and 0 < metrics.violations < 100  # every episode is one step
    assert model.lagrange_multiplier > 0.0

    model.save(tmp_path / "saclag.zip")
    loaded = SACLag.load(tmp_path / "saclag.zip", env=CostlyBandit())
    assert loaded.safety_metrics.summary() == metrics.summary()
    assert list(loaded.cost_tracker.recent_costs) == list(model.cost_tracker.recent_costs)
    assert loaded.lagrange_multiplier == model.lagrange_multiplier and loaded.cost_window == model.cost_window
    saved, restored = (m.cost_critic.optimizer.state_dict()["state"] for m in (model, loaded))
    assert restored and th.equal(restored[0]["exp_avg"], saved[0]["exp_avg"])  # the cost critic's Adam state
    loaded.learn(20, reset_num_timesteps=False)
    assert loaded.safety_metrics.steps == 120 and loaded.safety_metrics.episodes == 120
