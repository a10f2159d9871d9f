"""SPPO as an SB3 algorithm: smoke runs, shielded training, persistence, determinism, errors."""

from __future__ import annotations

import contextlib
import io
import zipfile
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import KVWriter, Logger
from tiny_hyperparams import TINY_SPPO

from sppo_sb3 import SPPO
from sppo_sb3.common.action_repeat import ActionRepeat
from sppo_sb3.common.costs import MissingCostError
from sppo_sb3.shield import PointCircleShieldingRule, ShieldingRule, ShieldWrapper
from sppo_sb3.sppo.buffers import ShieldedReplayBuffer
from sppo_sb3.sppo.optim import init_optimizer_state
from sppo_sb3.sppo.topo import TOPO_STATS, TOPOConfig, topo_update


def tiny_sppo(env="SafePointCircle-v0", **overrides) -> SPPO:
    return SPPO("TOLDPolicy", env, **{**TINY_SPPO, "seed": 0, **overrides})


def test_smoke_learn_predict_and_metrics():
    model = tiny_sppo().learn(150)
    assert model.num_timesteps == 150
    assert model.safety_metrics.steps == 150
    obs = np.array([0.5, 0.5, 0.1, 0.0], dtype=np.float32)
    action, state = model.predict(obs, deterministic=True)
    assert action.shape == (2,) and state[0].shape == (1, 3, 2)  # the plan's mean: (n_envs, horizon, action dims)
    assert np.all(np.abs(action) <= 1.0)
    model.plan_at_predict = False
    prior, state = model.predict(np.stack([obs, obs]))
    assert prior.shape == (2, 2) and state is None
    np.testing.assert_array_equal(prior[0], prior[1])


def test_every_executed_action_is_shielded_and_safe():
    """Warm-up (random) and planning phases both: no violation with the shield, violations without it."""
    shielded = tiny_sppo(learning_starts=600).learn(1_000)
    assert shielded.safety_metrics.violations == 0
    assert shielded.safety_metrics.interventions > 0
    assert shielded.safety_metrics.safety_rate == 100.0
    unshielded = tiny_sppo(learning_starts=600, shield=None).learn(1_000)
    assert unshielded.safety_metrics.violations > 0
    assert unshielded.safety_metrics.safety_rate < 100.0


@pytest.mark.parametrize("on_intervention", ["terminate", "restart"])
def test_b_tilde_holds_the_absorbing_relabel_of_real_interventions(on_intervention):
    model = tiny_sppo(learning_starts=400, on_intervention=on_intervention).learn(400)
    buffer = model.replay_buffer
    n = buffer.pos
    assert buffer.intervened[:n].any()
    for t in np.flatnonzero(buffer.intervened[:n, 0]):
        executed = model.policy.unscale_action(buffer.actions[t, 0])
        backup = model.shield_rule.backup_action(buffer.observations[t, 0][None].astype(np.float64))[0]
        np.testing.assert_allclose(executed, backup, atol=1e-5)  # B holds the safe action
    first = np.flatnonzero(buffer.intervened[:n, 0])[0]
    episode_end = first + np.flatnonzero(buffer.dones[first:n, 0])[:1]
    stop = int(episode_end[0]) + 1 if len(episode_end) else n
    if on_intervention == "terminate":  # the paper's M̃: nothing of an episode follows its first intervention
        assert not buffer.relabel_valid[first + 1 : stop, 0].any()
    else:  # B̃ restarts at the next real state
        assert buffer.relabel_valid[:n, 0].all()


def test_n_envs_two_plans_all_envs_in_one_batch():
    env = make_vec_env("SafePointCircle-v0", n_envs=2, seed=0)
    model = tiny_sppo(env).learn(200)
    assert model.replay_buffer.n_envs == 2
    assert model._plan_mean.shape[0] == 2
    actions, _ = model.predict(env.reset(), episode_start=np.ones(2, dtype=bool))
    assert actions.shape == (2, 2)


def test_save_load_predict_and_resume_identically(tmp_path):
    model = tiny_sppo().learn(120)
    model.save(tmp_path / "sppo")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = SPPO.load(tmp_path / "sppo", env=model.get_env())
    loaded.load_replay_buffer(tmp_path / "buffer")
    obs = np.array([[0.2, -0.3, 0.5, 0.1]], dtype=np.float32)
    th.manual_seed(7)
    expected, _ = model.predict(obs, deterministic=True)
    th.manual_seed(7)
    got, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(expected, got)
    for (name, a), b in zip(model.policy.state_dict().items(), loaded.policy.state_dict().values()):
        assert th.equal(a, b), name
    assert loaded.policy.optimizer.state_dict()["state"].keys() == model.policy.optimizer.state_dict()["state"].keys()
    assert loaded.safety_metrics.steps == 120
    loaded.learn(60, reset_num_timesteps=False)
    assert loaded.num_timesteps == 180 and loaded.safety_metrics.steps == 180
    assert loaded.replay_buffer.size() == 180


def test_loading_to_deploy_does_not_allocate_the_replay_buffer(tmp_path):
    tiny_sppo(buffer_size=1_000_000).save(tmp_path / "sppo")
    loaded = SPPO.load(tmp_path / "sppo", env=gym.make("SafePointCircle-v0"))
    assert loaded.replay_buffer is None
    assert loaded.predict(np.zeros(4, dtype=np.float32))[0].shape == (2,)


@contextlib.contextmanager
def storages_tagged_as_cuda() -> Iterator[None]:
    """``torch.save`` records every storage at ``cuda:0``, as in a model saved on a GPU machine."""

    def tag(storage: object) -> str | None:
        return "cuda:0" if getattr(storage, "device", None) == th.device("cpu") else None

    def no_restore(storage: object, location: str) -> None:
        return None

    entry = (0, tag, no_restore)
    th.serialization.register_package(*entry)
    try:
        yield
    finally:
        th.serialization._package_registry.remove(entry)


def test_a_model_saved_on_cuda_loads_on_cpu(tmp_path):
    model = tiny_sppo().learn(80)
    with storages_tagged_as_cuda():
        model.save(tmp_path / "sppo")
    if not th.cuda.is_available():  # the file really holds CUDA storages: a plain torch.load cannot place them
        with zipfile.ZipFile(tmp_path / "sppo.zip") as archive, pytest.raises(RuntimeError, match="CUDA"):
            th.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)
    loaded = SPPO.load(tmp_path / "sppo", device="cpu")
    assert all(p.device.type == "cpu" for p in loaded.policy.parameters())
    obs = np.array([[0.2, -0.3, 0.5, 0.1]], dtype=np.float32)
    th.manual_seed(7)
    expected, _ = model.predict(obs, deterministic=True)
    th.manual_seed(7)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], expected)
    loaded.set_env(model.get_env())
    loaded.learn(20, reset_num_timesteps=False)  # the restored optimisers step on the CPU
    assert loaded.num_timesteps == 100


def test_seeded_runs_are_identical():
    first, second = tiny_sppo(seed=3).learn(100), tiny_sppo(seed=3).learn(100)
    for a, b in zip(first.policy.parameters(), second.policy.parameters()):
        assert th.equal(a, b)


def test_topo_loss_decreases_on_a_fixed_batch():
    model = tiny_sppo(learning_starts=200).learn(200)  # fills B̃ with real (shielded) data, no updates yet
    batch = model.replay_buffer.sample_sequences(64, 3)
    cfg = TOPOConfig()
    pol = model.policy
    noise, lr, ema = th.zeros(batch.actions.shape), th.tensor(1e-3), th.tensor(0.01)
    init_optimizer_state(pol.optimizer)
    init_optimizer_state(pol.pi_optimizer)
    loss = TOPO_STATS.index("loss")
    args = (pol.model, pol.model_target, pol.optimizer, pol.pi_optimizer, batch, noise, lr, ema, cfg, model.gamma)
    losses = [topo_update(*args)[loss].item() for _ in range(60)]
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])


def test_actions_stay_inside_asymmetric_bounds():
    env = gym.wrappers.RescaleAction(gym.make("Pendulum-v1"), np.float32(-0.5), np.float32(1.5))
    model = tiny_sppo(env, learning_starts=20, shield=None).learn(40)
    actions = np.stack([model.predict(env.observation_space.sample())[0] for _ in range(20)])
    assert actions.min() >= -0.5 and actions.max() <= 1.5
    assert isinstance(model.replay_buffer, ShieldedReplayBuffer)


class _DictObs(gym.Env):
    observation_space = gym.spaces.Dict({"position": gym.spaces.Box(-1, 1, (2,), np.float32)})
    action_space = gym.spaces.Box(-1, 1, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        return self.observation_space.sample(), {}

    def step(self, action):
        return self.observation_space.sample(), 0.0, False, False, {}


class _ImageObs(_DictObs):
    observation_space = gym.spaces.Box(0, 255, (16, 16, 3), np.uint8)


@pytest.mark.parametrize(
    ("env", "error", "match"),
    [
        ("CartPole-v1", TypeError, "Box action space"),
        (_DictObs(), TypeError, "FlattenObservation"),
        (_ImageObs(), TypeError, "image observations are not supported"),
    ],
)
def test_unsupported_spaces_are_rejected_with_a_clear_error(env, error, match):
    with pytest.raises(error, match=match):
        tiny_sppo(env)


class _InfiniteBounds(gym.Env):
    observation_space = gym.spaces.Box(-1, 1, (2,), np.float32)
    action_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        return np.zeros(2, np.float32), {}

    def step(self, action):
        return np.full(2, np.nan, np.float32), 0.0, False, False, {}


def test_infinite_action_bounds_are_rejected():
    with pytest.raises(ValueError, match="finite action bounds"):
        tiny_sppo(_InfiniteBounds())


def test_nan_observations_stop_training_with_a_clear_error():
    env = _InfiniteBounds()
    env.action_space = gym.spaces.Box(-1, 1, (1,), np.float32)
    with pytest.raises(ValueError, match="non-finite observation"):
        tiny_sppo(env, shield=None).learn(10)


class StillTorque(ShieldingRule):
    """A rule for Pendulum's observations and 1-D torque: the backup is no torque, ``Q̄ = 0`` everywhere."""

    gamma = 0.99

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 1))

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.zeros(len(obs))


def test_a_shield_on_an_env_without_cost_is_a_clear_error():
    with pytest.raises(MissingCostError, match=r"info\['cost'\]"):
        tiny_sppo("Pendulum-v1", shield=StillTorque(), learning_starts=5).learn(5)


def test_the_point_rule_on_another_env_is_a_clear_error():
    with pytest.raises(ValueError, match=r"observations \[x, y, vx, vy\]"):
        tiny_sppo("Pendulum-v1", shield=PointCircleShieldingRule(), learning_starts=5).learn(5)


# ---------------------------------------------------------------- the planner's warm start as SB3's recurrent state
def test_deterministic_predictions_repeat_and_survive_save_load(tmp_path):
    model = tiny_sppo().learn(100)
    obs = np.array([[0.2, -0.3, 0.5, 0.1], [1.0, 0.4, -0.2, 0.3]], dtype=np.float32)
    first, state = model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], first)
    warm, warm_state = model.predict(obs, state=state, deterministic=True)
    np.testing.assert_array_equal(model.predict(obs, state=state, deterministic=True)[0], warm)
    model.save(tmp_path / "sppo")
    loaded = SPPO.load(tmp_path / "sppo")
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], first)
    np.testing.assert_array_equal(loaded.predict(obs, state=state, deterministic=True)[0], warm)
    restarted, _ = model.predict(obs, state=warm_state, episode_start=np.array([True, False]), deterministic=True)
    np.testing.assert_array_equal(restarted[0], first[0])  # a new episode plans from a cold start


def test_evaluation_during_training_leaves_training_unchanged(tmp_path):
    """EvalCallback calls predict between rollouts: training's warm start, data and updates must not notice."""
    from stable_baselines3.common.callbacks import EvalCallback

    plain = tiny_sppo(seed=4).learn(160)
    evaluated = tiny_sppo(seed=4)
    eval_env = make_vec_env("SafePointCircle-v0", n_envs=3, seed=9, env_kwargs=dict(max_episode_steps=20))
    callback = EvalCallback(eval_env, eval_freq=50, n_eval_episodes=3, log_path=str(tmp_path), verbose=0)
    evaluated.learn(160, callback=callback)
    assert callback.n_calls == 160 and len(callback.evaluations_results) == 3
    th.testing.assert_close(evaluated._plan_mean, plain._plan_mean, rtol=0, atol=0)
    for a, b in zip(plain.policy.parameters(), evaluated.policy.parameters()):
        assert th.equal(a, b)


@pytest.mark.parametrize("train_envs", [1, 2])
def test_evaluation_on_vec_envs_of_any_size(train_envs):
    from stable_baselines3.common.evaluation import evaluate_policy

    model = tiny_sppo(make_vec_env("Pendulum-v1", n_envs=train_envs, seed=0), shield=None, learning_starts=30).learn(60)
    for eval_envs in (1, 2, 5, 7):
        env = make_vec_env("Pendulum-v1", n_envs=eval_envs, seed=1, env_kwargs=dict(max_episode_steps=10))
        rewards, lengths = evaluate_policy(model, env, n_eval_episodes=eval_envs, return_episode_rewards=True)
        assert len(rewards) == eval_envs and set(lengths) == {10}
    assert model._plan_mean.shape[0] == train_envs


def test_policy_save_load_and_sb3_default_arguments(tmp_path):
    """TOLDPolicy.load accepts what its own _get_constructor_parameters saves; SB3's defaults are accepted."""
    from sppo_sb3.sppo.policies import TOLDPolicy

    model = tiny_sppo(optimize_memory_usage=False)
    model.policy.save(tmp_path / "policy.pth")
    loaded = TOLDPolicy.load(tmp_path / "policy.pth")
    for a, b in zip(model.policy.parameters(), loaded.parameters()):
        assert th.equal(a, b)
    obs = th.zeros(1, 4)
    th.testing.assert_close(loaded._predict(obs), model.policy._predict(obs))
    with pytest.raises(ValueError, match="optimize_memory_usage=False"):
        tiny_sppo(optimize_memory_usage=True)


def test_predict_takes_what_sb3_takes():
    """Float64 batches and a plain tuple of floats are observations, as in SB3's ``predict``."""
    model = tiny_sppo()
    assert model.predict(np.zeros((3, 4), dtype=np.float64))[0].shape == (3, 2)
    assert model.predict((0.0, 0.0, 0.0, 0.0))[0].shape == (2,)


class RecordDumps(KVWriter):
    """Every logger dump of a run."""

    def __init__(self) -> None:
        self.dumps: list[dict[str, Any]] = []

    def write(self, key_values: dict[str, Any], key_excluded: dict[str, Any], step: int = 0) -> None:
        self.dumps.append(dict(key_values))


@pytest.mark.parametrize("train_freq", [4, (1, "episode")])
def test_n_updates_is_logged_as_sac_logs_it(train_freq) -> None:
    """``train/n_updates`` in every dump, with ``gradient_steps=-1``, is what SB3's SAC logs in the same run."""
    logged = {}
    schedule = dict(learning_starts=50, gradient_steps=-1, train_freq=train_freq, batch_size=8, seed=0)
    sac_kwargs = {**schedule, "policy_kwargs": dict(net_arch=[8])}
    for algo, kwargs in ((SPPO, {**TINY_SPPO, **schedule, "shield": None}), (SAC, sac_kwargs)):
        recorder = RecordDumps()
        model = algo("TOLDPolicy" if algo is SPPO else "MlpPolicy", "Pendulum-v1", **kwargs)
        model.set_logger(Logger(None, [recorder]))
        model.learn(450, log_interval=1)
        logged[algo] = [dump.get("train/n_updates") for dump in recorder.dumps]
    assert logged[SPPO] == logged[SAC]
    assert logged[SPPO][-1] is not None and logged[SPPO][-1] > 0


@pytest.mark.parametrize("on_intervention", ["continue", "none"])
def test_cmdp_relabels_train_shielded(on_intervention: str) -> None:
    """The relabels for tasks where a violation does not end the episode train end to end, still shielded."""
    model = tiny_sppo(on_intervention=on_intervention, penalty=2.0).learn(200)
    assert model.replay_buffer.on_intervention == on_intervention and model.replay_buffer.penalty == 2.0
    assert model.safety_metrics.violations == 0 and model.safety_metrics.interventions > 0


class PositiveFirstCoordinateRule(ShieldingRule):
    """Rejects every action whose first coordinate is positive: ``Q̄(s, a) = max(a_0, 0)``, backup ``ζ(s) = 0``."""

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.maximum(np.asarray(actions, dtype=np.float64)[:, 0], 0.0)

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 2))


def test_the_shield_executes_the_planners_first_accepted_candidate() -> None:
    """``num_candidates > 1``: where the rule rejects the plan, an accepted alternative of the planner is executed
    and stored as a normal step; the backup (and the relabel) only where the rule rejects every candidate."""
    planner = {**TINY_SPPO["planner_kwargs"], "num_candidates": 4}
    ranked = tiny_sppo(shield=PositiveFirstCoordinateRule(), planner_kwargs=planner, learning_starts=20).learn(300)
    buffer, n = ranked.replay_buffer, ranked.replay_buffer.pos
    executed = ranked.policy.unscale_action(buffer.actions[:n, 0])
    assert ranked.alternatives_executed > 0
    assert np.all(executed[:, 0] <= 1e-6)  # every stored step is an accepted candidate or the backup
    plain = tiny_sppo(shield=PositiveFirstCoordinateRule(), learning_starts=20).learn(300)
    assert plain.alternatives_executed == 0
    assert ranked.safety_metrics.interventions < plain.safety_metrics.interventions


# --------------------------------------------------------------------------------------------- the held action
def test_behind_a_held_action_shield_sppo_counts_env_steps_and_relabels_the_wrappers_interventions() -> None:
    """``ShieldWrapper(..., action_repeat=5)``: SPPO acts every 5 env steps, the wrapper checks each of them, and SPPO's
    metrics and relabel see the interventions the wrapper took on the held steps."""
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), "auto", action_repeat=5)
    model = SPPO("TOLDPolicy", env, **{**TINY_SPPO, "learning_starts": 20, "seed": 0}).learn(200)
    metrics, buffer = model.safety_metrics, model.replay_buffer
    n = buffer.pos
    assert model.num_timesteps == 200 and metrics.steps == 1000  # agent steps, and the env steps they held
    assert metrics.violations == 0 and metrics.interventions > 0
    assert buffer.interventions[:n].sum() == metrics.interventions
    np.testing.assert_array_equal(buffer.intervened[:n], buffer.interventions[:n] > 0)
    assert buffer.interventions[:n].max() > 1  # several held env steps of one agent step were intervened


def test_a_shielded_sppo_refuses_actions_held_where_its_shield_does_not_see_them() -> None:
    held = ActionRepeat(gym.make("SafePointCircle-v0"), 5)
    with pytest.raises(ValueError, match=r"only the first env step of each action that ActionRepeat holds"):
        SPPO("TOLDPolicy", held, **TINY_SPPO)
    assert SPPO("TOLDPolicy", held, shield=None, **TINY_SPPO).shield_rule is None  # unshielded, on purpose: allowed
