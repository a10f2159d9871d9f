"""PDO (PPO-Lagrangian): smoke runs, save/load, n_envs, the dual ascent on λ and the combined advantage."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from tiny_hyperparams import TINY_PDO

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.common.lagrange import lagrange_update
from sppo_sb3.pdo import PDO


def test_lagrange_update_projected_dual_ascent() -> None:
    assert lagrange_update(0.0, episode_cost=1.0, cost_limit=0.25, lagrange_lr=0.1) == pytest.approx(0.075)
    assert lagrange_update(0.01, episode_cost=0.0, cost_limit=0.25, lagrange_lr=0.1) == 0.0  # projected to λ >= 0
    assert lagrange_update(1.0, episode_cost=0.25, cost_limit=0.25, lagrange_lr=0.1) == 1.0


def _rollout(model: PDO, episode_cost: float) -> None:
    """Fake the bookkeeping of one rollout in which 4 episodes of length 10 each cost ``episode_cost``."""
    tracker = model.cost_tracker
    tracker.start_rollout()
    for _ in range(4):
        for t in range(10):
            tracker.update(np.array([episode_cost if t == 9 else 0.0]), np.array([t == 9]))


def test_lambda_rises_above_the_limit_and_falls_to_zero_below() -> None:
    model = PDO("MlpPolicy", "SafePointCircle-v0", cost_limit=0.2, lagrange_lr=0.5, **TINY_PDO)
    model.set_logger(configure(None, []))
    lambdas = [model.lagrange_multiplier]
    for _ in range(4):
        _rollout(model, episode_cost=1.0)
        lambdas.append(model.update_lagrange_multiplier())
    assert np.all(np.diff(lambdas) > 0) and lambdas[-1] == pytest.approx(4 * 0.5 * 0.8)
    for _ in range(20):
        _rollout(model, episode_cost=0.0)
        lambdas.append(model.update_lagrange_multiplier())
    assert np.all(np.diff(lambdas[5:]) <= 0) and lambdas[-1] == 0.0


def test_policy_advantage_is_the_lagrangian_combination() -> None:
    model = PDO("MlpPolicy", "SafePointCircle-v0", lagrange_init=3.0, lagrange_lr=1e-9, cost_limit=0.0, **TINY_PDO)
    seen = {}

    class Grab(BaseCallback):
        def _on_rollout_end(self) -> None:
            buf = self.model.rollout_buffer
            seen["adv"], seen["cadv"] = buf.advantages.copy(), buf.cost_advantages.copy()

        def _on_step(self) -> bool:
            return True

    model.learn(64, callback=Grab())
    lam = model.lagrange_multiplier
    assert lam == pytest.approx(3.0, abs=1e-6)
    combined = model.rollout_buffer.advantages.reshape(-1)  # flattened by get(), env-major: one env here
    np.testing.assert_allclose(combined, ((seen["adv"] - lam * seen["cadv"]) / (1 + lam)).reshape(-1), rtol=1e-5)


def test_pdo_smoke_save_load_predict(tmp_path) -> None:
    model = PDO("MlpPolicy", "SafePointCircle-v0", seed=0, tensorboard_log=str(tmp_path / "tb"), **TINY_PDO)
    model.learn(256, progress_bar=True)
    assert model.num_timesteps == 256
    assert model.safety_metrics.steps == 256
    assert model.rollout_buffer.cost_returns.size == 64
    assert any((tmp_path / "tb").iterdir())
    model.save(tmp_path / "pdo")
    loaded = PDO.load(tmp_path / "pdo")
    obs = np.random.default_rng(0).uniform(-2, 2, size=(16, 4)).astype(np.float32)
    np.testing.assert_allclose(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    assert loaded.lagrange_multiplier == model.lagrange_multiplier
    np.testing.assert_equal(loaded.safety_metrics.summary(), model.safety_metrics.summary())  # NaN-aware
    for p1, p2 in zip(model.policy.cost_value_net.parameters(), loaded.policy.cost_value_net.parameters()):
        assert th.equal(p1, p2)


def test_pdo_n_envs_and_resume(tmp_path) -> None:
    env = make_vec_env("SafePointCircle-v0", n_envs=2, seed=0)
    model = PDO("MlpPolicy", env, seed=0, **TINY_PDO)
    model.learn(256)
    assert model.safety_metrics.steps == 256 and model.rollout_buffer.costs.shape == (64, 2)  # costs are not flattened
    model.save(tmp_path / "pdo2")
    loaded = PDO.load(tmp_path / "pdo2", env=make_vec_env("SafePointCircle-v0", n_envs=3, seed=1))
    episodes = loaded.safety_metrics.episodes
    loaded.learn(192, reset_num_timesteps=False)
    assert loaded.num_timesteps == 256 + 192
    assert loaded.safety_metrics.episodes >= episodes and loaded.safety_metrics.n_envs == 3


def test_pdo_seed_is_reproducible() -> None:
    def run() -> np.ndarray:
        model = PDO("MlpPolicy", "SafePointCircle-v0", seed=3, **TINY_PDO)
        model.learn(128)
        return th.nn.utils.parameters_to_vector(model.policy.parameters()).detach().numpy()

    np.testing.assert_array_equal(run(), run())


def test_lagrange_init_sets_the_initial_multiplier() -> None:
    assert PDO("MlpPolicy", "SafePointCircle-v0", lagrange_init=2.0, **TINY_PDO).lagrange_multiplier == 2.0
    with pytest.raises(ValueError, match="lagrange_init must be >= 0"):
        PDO("MlpPolicy", "SafePointCircle-v0", lagrange_init=-1.0, **TINY_PDO)
