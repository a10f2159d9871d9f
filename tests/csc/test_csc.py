"""CSC (Conservative Safety Critics): smoke runs, save/load, the rejection sampler and the critic's conservatism."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from tiny_hyperparams import TINY_CSC

import sppo_sb3  # noqa: F401  (registers SafePointCircle-v0)
from sppo_sb3.common.costs import MissingCostError
from sppo_sb3.csc import CSC, CSCPolicy, rejection_sample_actions

ENV_ID = "SafePointCircle-v0"


@pytest.fixture(autouse=True)
def _one_thread():
    threads = th.get_num_threads()
    th.set_num_threads(1)
    yield
    th.set_num_threads(threads)


def test_smoke_learn_logs_and_safety_metrics(tmp_path):
    model = CSC("MlpPolicy", ENV_ID, seed=0, **TINY_CSC)
    model.set_logger(configure(str(tmp_path), ["csv", "tensorboard"]))
    model.learn(256, progress_bar=True)
    assert model.num_timesteps == 256
    summary = model.safety_metrics.summary()
    assert model.safety_metrics.steps == 256
    assert 0.0 <= summary["safety_rate"] <= 100.0
    assert model.lagrange_multiplier >= 0.0
    assert model.cost_buffer.size() == 256
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    assert {"safety/cumulative_violations", "safety/safety_rate", "train/lagrange_multiplier"} <= set(header)
    assert list(tmp_path.glob("events.out.tfevents*"))


def test_save_load_same_deterministic_predict_and_metrics(tmp_path):
    model = CSC("MlpPolicy", ENV_ID, seed=1, **TINY_CSC)
    model.learn(128)
    obs = np.stack([model.observation_space.sample() for _ in range(8)])
    before, _ = model.predict(obs, deterministic=True)
    again, _ = model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(before, again)
    model.save(tmp_path / "csc")
    loaded = CSC.load(tmp_path / "csc")
    after, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(before, after)
    assert loaded._cost_buffer is None  # deploying allocates no replay buffer
    assert loaded.safety_metrics.summary() == pytest.approx(model.safety_metrics.summary(), nan_ok=True)
    assert loaded.lagrange_multiplier == model.lagrange_multiplier
    assert loaded.cost_threshold == model.cost_threshold
    for p, q in zip(model.policy.cost_critic_target.parameters(), loaded.policy.cost_critic_target.parameters()):
        th.testing.assert_close(p, q)
    # the cost critic's replay buffer is saved apart, as SB3's off-policy replay buffers
    model.save_replay_buffer(tmp_path / "buffer")
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert loaded.cost_buffer.size() == model.cost_buffer.size()
    # resume training after loading (cumulative counts keep going)
    loaded.set_env(make_vec_env(ENV_ID, n_envs=1, seed=3))
    loaded.learn(64, reset_num_timesteps=False)
    assert loaded.safety_metrics.steps == model.safety_metrics.steps + 64


def test_two_envs():
    env = make_vec_env(ENV_ID, n_envs=2, seed=0)
    model = CSC("MlpPolicy", env, seed=0, **{**TINY_CSC, "n_steps": 32})
    model.learn(128)
    assert model.num_timesteps == 128
    assert model.safety_metrics.steps == 128
    assert model.cost_buffer.n_envs == 2 and model.cost_buffer.size() == 64  # per-env rows
    actions, _ = model.predict(env.reset(), deterministic=False)
    assert actions.shape == (2, 2)
    assert np.all(np.abs(actions) <= 1.0)


def test_another_number_of_envs_starts_a_new_cost_buffer(tmp_path):
    model = CSC("MlpPolicy", ENV_ID, seed=0, **TINY_CSC).learn(64)
    model.save(tmp_path / "csc")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = CSC.load(tmp_path / "csc", env=make_vec_env(ENV_ID, n_envs=2, seed=1))
    loaded.load_replay_buffer(tmp_path / "buffer")  # one env's transitions
    loaded.learn(64)
    assert loaded.cost_buffer.n_envs == 2 and loaded.cost_buffer.size() == 64  # one rollout of n_steps per env


def test_missing_cost_raises():
    model = CSC("MlpPolicy", "Pendulum-v1", seed=0, **TINY_CSC)
    with pytest.raises(MissingCostError, match="info\\['cost'\\]"):
        model.learn(64)


def test_discrete_action_space_is_refused():
    with pytest.raises(ValueError, match="Box action"):
        CSC("MlpPolicy", "CartPole-v1", **TINY_CSC)


def test_sampler_never_executes_inadmissible_when_admissible_exists():
    gen = th.Generator().manual_seed(0)
    n_samples, n_envs, threshold = 100, 64, 0.3
    candidates = th.randn(n_samples, n_envs, 2, generator=gen)
    q_values = th.rand(n_samples, n_envs, generator=gen)
    q_values[:, :4] = 0.5 + 0.5 * th.rand(n_samples, 4, generator=gen)  # four envs without an admissible sample
    out = rejection_sample_actions(candidates, q_values, threshold)
    admissible = q_values <= threshold
    has_admissible = admissible.any(0)
    assert not has_admissible[:4].any() and has_admissible[4:].all()
    # executed = the first admissible sample, whose Q_C is <= threshold ...
    first = admissible.float().argmax(0)
    assert th.equal(out.sample_index[4:], first[4:])
    assert (out.q_value[4:] <= threshold).all()
    # ... and the argmin where no sample is admissible
    assert th.equal(out.sample_index[:4], q_values[:, :4].argmin(0))
    assert th.equal(out.actions, candidates[out.sample_index, th.arange(n_envs)])
    assert th.equal(out.first_rejected, q_values[0] > threshold)
    assert th.equal(out.admissible, has_admissible)


def test_policy_sampler_with_fake_critic():
    """With Q_C(s, a) = first action coordinate, no executed action has a_0 > threshold when one sample has a_0 <= it."""
    env = gym.make(ENV_ID)
    policy = CSCPolicy(env.observation_space, env.action_space, lambda _: 1e-3, net_arch=[8], cost_threshold=-0.5)

    def fake_cost_values(obs, normalized_actions, target=False):
        return normalized_actions[..., 0]

    policy.cost_values = fake_cost_values  # type: ignore[method-assign]
    obs = th.as_tensor(np.stack([env.observation_space.sample() for _ in range(256)]))
    with th.no_grad():
        sample, _ = policy.sample_safe_actions(obs)
        executed = policy.normalize_actions(sample.actions)
    assert sample.admissible.all()  # 100 N(0, 1) samples: one below -0.5 almost surely
    assert (executed[:, 0] <= -0.5).all()
    assert sample.first_rejected.any() and not sample.first_rejected.all()
    # predict applies the sampler too, and can be switched off
    with th.no_grad():
        assert (policy._predict(obs)[:, 0] <= -0.5).all()
        policy.reject_in_predict = False
        assert (policy._predict(obs)[:, 0] > -0.5).any()


def test_cost_critic_is_conservative():
    """On a dataset of zero-cost terminal transitions with actions in one corner of the Box, CQL pushes Q_C up on
    the other actions, above the plain TD estimate, and keeps it low on the data."""

    def fitted(cql_alpha):
        model = CSC("MlpPolicy", ENV_ID, seed=0, cql_alpha=cql_alpha, **{**TINY_CSC, "cost_learning_rate": 3e-3})
        rng = np.random.default_rng(0)
        obs = rng.uniform(-1, 1, size=(256, 4)).astype(np.float32)
        data_actions = rng.uniform(-1.0, -0.6, size=(256, 2)).astype(np.float32)
        for o, a in zip(obs, data_actions):
            model.cost_buffer.add(o[None], o[None], a[None], np.zeros(1), np.ones(1), [{}])
        model.train_cost_critic(gradient_steps=100, batch_size=64)
        with th.no_grad():
            obs_t = th.as_tensor(obs)
            q_data = model.policy.cost_values(obs_t, th.as_tensor(data_actions)).mean().item()
            q_ood = model.policy.cost_values(obs_t, th.full((256, 2), 0.8)).mean().item()
        return q_data, q_ood

    td_data, td_ood = fitted(0.0)
    cql_data, cql_ood = fitted(1.0)
    assert cql_ood > td_ood + 0.1
    assert cql_ood > cql_data + 0.1
    assert td_data < 0.05


class _Float64Actions(gym.ActionWrapper):
    """The Point task behind a float64 action space."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float64)

    def action(self, action: np.ndarray) -> np.ndarray:
        return action.astype(np.float32)


def test_float64_action_spaces_train():
    model = CSC("MlpPolicy", _Float64Actions(gym.make(ENV_ID)), seed=0, **TINY_CSC).learn(128)
    assert model.num_timesteps == 128


def test_loading_parameters_leaves_the_env_action_space_alone():
    """The policy's bound buffers are copies: set_parameters must not write into the live env's space."""
    model = CSC("MlpPolicy", ENV_ID, seed=0, **TINY_CSC)
    space = model.get_env().action_space
    params = model.get_parameters()
    params["policy"]["action_low"] = th.full_like(params["policy"]["action_low"], 3.0)
    model.set_parameters(params)
    np.testing.assert_array_equal(space.low, [-1.0, -1.0])


class _MatrixActions(gym.ActionWrapper):
    """The Point task behind a Box action space of shape (2, 2): the env executes the mean of the two rows."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2, 2), np.float32)

    def action(self, action: np.ndarray) -> np.ndarray:
        return action.mean(axis=0)


def test_multi_dimensional_box_actions():
    """A Box of shape (2, 2): the sampler, the cost critic and predict work on the flattened actions."""
    model = CSC("MlpPolicy", _MatrixActions(gym.make(ENV_ID)), seed=0, **TINY_CSC).learn(128)
    assert model.num_timesteps == 128 and model.cost_buffer.size() == 128
    obs = np.stack([model.observation_space.sample() for _ in range(3)])
    for deterministic in (False, True):
        actions, _ = model.predict(obs, deterministic=deterministic)
        assert actions.shape == (3, 2, 2) and np.all(np.abs(actions) <= 1.0)
    assert model.predict(obs[0], deterministic=True)[0].shape == (2, 2)


def test_rejected_first_samples_count_as_interventions():
    """With a threshold no action meets, every executed step is the sampler's argmin: an intervention each."""
    model = CSC("MlpPolicy", ENV_ID, seed=0, **{**TINY_CSC, "cost_threshold": -1.0}).learn(64)
    assert model.safety_metrics.steps == 64 and model.safety_metrics.interventions == 64
