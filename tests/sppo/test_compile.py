"""Compiled planner and TOPO update against the eager reference; compiling survives save/load/resume and set_env.

The test session runs eager by default (``TORCH_COMPILE_DISABLE=1``, see conftest); these tests turn compilation on.
"""

from __future__ import annotations

import copy
import warnings
from collections.abc import Iterator

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from tiny_hyperparams import SMALL_TOLD, TINY_MPPI, TINY_SPPO

from sppo_sb3 import SPPO
from sppo_sb3.sppo.compile import CompiledFunction, should_compile
from sppo_sb3.sppo.optim import init_optimizer_state
from sppo_sb3.sppo.planner import MPPIConfig, draw_noise, mppi
from sppo_sb3.sppo.policies import TOLDPolicy
from sppo_sb3.sppo.topo import TOPO_STATS, TOPOConfig, topo_update

CPU = th.device("cpu")


@pytest.fixture(autouse=True)
def compilation_on() -> Iterator[None]:
    with th._dynamo.config.patch(disable=False):
        yield


def make_policy(obs_dim: int = 4, action_dim: int = 2) -> TOLDPolicy:
    import gymnasium as gym

    th.manual_seed(0)
    obs_space = gym.spaces.Box(-1, 1, (obs_dim,), np.float32)
    act_space = gym.spaces.Box(-1, 1, (action_dim,), np.float32)
    policy = TOLDPolicy(obs_space, act_space, lambda _: 1e-3, termination=False, **SMALL_TOLD)
    init_optimizer_state(policy.optimizer)
    init_optimizer_state(policy.pi_optimizer)
    return policy


def random_batch(horizon: int = 3, batch: int = 16, obs_dim: int = 4, action_dim: int = 2):
    from sppo_sb3.sppo.buffers import SequenceSamples

    gen = th.Generator().manual_seed(1)
    mask = (th.rand(horizon, batch, generator=gen) > 0.2).float()
    return SequenceSamples(
        observations=th.randn(batch, obs_dim, generator=gen),
        actions=th.rand(horizon, batch, action_dim, generator=gen) * 2 - 1,
        rewards=th.randn(horizon, batch, generator=gen),
        next_observations=th.randn(horizon, batch, obs_dim, generator=gen),
        terminals=(th.rand(horizon, batch, generator=gen) > 0.9).float(),
        mask=mask,
        consistency_mask=mask * (th.rand(horizon, batch, generator=gen) > 0.1).float(),
    )


def run_updates(policy: TOLDPolicy, update, n: int = 3) -> list[th.Tensor]:
    batch, cfg = random_batch(), TOPOConfig()
    noise = th.randn(batch.actions.shape, generator=th.Generator().manual_seed(2))
    stats = []
    for i in range(n):
        ema = th.tensor(0.01 if i % 2 else 0.0)
        models, optimizers = (policy.model, policy.model_target), (policy.optimizer, policy.pi_optimizer)
        stats.append(update(*models, *optimizers, batch, noise, th.tensor(1e-3), ema, cfg, 0.99).clone())
    return stats


def test_compiled_topo_update_equals_eager():
    """Same losses on the same batches (to 1e-5 relative), and the same parameters after three updates."""
    eager_policy = make_policy()
    compiled_policy = copy.deepcopy(eager_policy)
    compiled = CompiledFunction(topo_update, True, CPU, "TOPO update")
    eager_stats = run_updates(eager_policy, topo_update)
    compiled_stats = run_updates(compiled_policy, compiled)
    assert compiled.compiled, "compilation fell back to eager"
    for eager, comp in zip(eager_stats, compiled_stats):
        th.testing.assert_close(comp, eager, rtol=1e-5, atol=1e-6, msg=lambda m: f"{TOPO_STATS}: {m}")
    for (name, a), b in zip(eager_policy.state_dict().items(), compiled_policy.state_dict().values()):
        th.testing.assert_close(b, a, rtol=1e-4, atol=1e-6, msg=lambda m, name=name: f"{name}: {m}")


def test_tensor_adam_step_equals_torch_adam():
    """The update's Adam (tensor code) against torch.optim.Adam.step on the same gradients."""
    from sppo_sb3.sppo.optim import adam_step

    th.manual_seed(0)
    mine, theirs = th.nn.Linear(5, 3), th.nn.Linear(5, 3)
    theirs.load_state_dict(mine.state_dict())
    opt_mine = th.optim.Adam(mine.parameters(), lr=1e-2, weight_decay=1e-3)
    opt_theirs = th.optim.Adam(theirs.parameters(), lr=1e-2, weight_decay=1e-3)
    init_optimizer_state(opt_mine)
    for _ in range(5):
        grads = [th.randn_like(p) for p in mine.parameters()]
        adam_step(opt_mine, grads, th.tensor(1e-2))
        for p, g in zip(theirs.parameters(), grads):
            p.grad = g.clone()
        opt_theirs.step()
    for a, b in zip(mine.parameters(), theirs.parameters()):
        th.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)
    opt_theirs.load_state_dict(opt_mine.state_dict())  # the state is torch's own format


def test_compiled_plan_equals_eager_given_the_same_noise():
    model = make_policy().model
    cfg = MPPIConfig(**TINY_MPPI, horizon=3, num_candidates=3)
    noise = draw_noise(cfg, 2, 3, 2, False, th.Generator().manual_seed(3), CPU)
    args = (model, th.randn(2, 4), th.rand(2, 3, 2) - 0.5, noise, th.tensor(0.1), cfg, 0.99)
    compiled = CompiledFunction(mppi, True, CPU, "planner")
    with th.no_grad():
        eager_action, eager_mean, eager_alternatives = mppi(*args)
        action, mean, alternatives = compiled(*args)
    assert compiled.compiled
    th.testing.assert_close(action, eager_action, rtol=1e-5, atol=1e-6)
    th.testing.assert_close(mean, eager_mean, rtol=1e-5, atol=1e-6)
    th.testing.assert_close(alternatives, eager_alternatives, rtol=1e-5, atol=1e-6)


def test_a_failed_compilation_warns_once_and_runs_eagerly():
    def double(x: th.Tensor) -> th.Tensor:
        return 2 * x

    def broken(x: th.Tensor) -> th.Tensor:
        raise RuntimeError("no C++ compiler")

    fn = CompiledFunction(double, True, CPU, "test function")
    fn._compiled = broken
    with pytest.warns(RuntimeWarning, match="torch.compile failed on SPPO's test function"):
        assert fn(th.ones(2)).tolist() == [2.0, 2.0]
    assert not fn.compiled
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert fn(th.ones(1)).tolist() == [2.0]


def test_compile_argument_is_checked_and_resolved():
    assert should_compile("auto", CPU) and should_compile(True, CPU) and not should_compile(False, CPU)
    with th._dynamo.config.patch(disable=True):  # TORCH_COMPILE_DISABLE=1 wins
        assert not should_compile(True, CPU)
    with pytest.raises(ValueError, match="compile must be True, False or 'auto'"):
        SPPO("TOLDPolicy", "Pendulum-v1", compile="yes")


COMPILED_SPPO = {
    **TINY_SPPO,
    "learning_starts": 40,
    "buffer_size": 2_000,
    "policy_kwargs": SMALL_TOLD,
    "planner_kwargs": {**TINY_SPPO["planner_kwargs"], "horizon": 2},
    "compile": True,
    "seed": 0,
}


def test_compiled_sppo_learns_saves_loads_resumes_and_changes_env(tmp_path):
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", **COMPILED_SPPO).learn(80)
    assert model.planner.compiled and model._topo_update.compiled
    model.save(tmp_path / "sppo")
    loaded = SPPO.load(tmp_path / "sppo", env=make_vec_env("SafePointCircle-v0", n_envs=2, seed=1))
    assert loaded.compile is True
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no fallback to eager
        loaded.learn(60, reset_num_timesteps=False)
    assert loaded.planner.compiled and loaded._topo_update.compiled
    assert loaded._plan_mean.shape[0] == 2
    obs = np.zeros((2, 4), dtype=np.float32)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])


CUDA = pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device")


@CUDA
@pytest.mark.cuda
def test_compiled_topo_update_equals_eager_on_cuda():
    """CUDA graphs (mode="reduce-overhead") against the eager update, on the GPU."""
    cuda = th.device("cuda")
    eager_policy = make_policy().to(cuda)
    compiled_policy = copy.deepcopy(eager_policy)
    for policy in (eager_policy, compiled_policy):
        init_optimizer_state(policy.optimizer)
        init_optimizer_state(policy.pi_optimizer)
    compiled = CompiledFunction(topo_update, True, cuda, "TOPO update")
    batch, cfg = random_batch(), TOPOConfig()
    batch = type(batch)(*(x.to(cuda) for x in batch))
    noise = th.randn(batch.actions.shape, device=cuda)
    for i in range(4):
        ema = th.tensor(0.01 if i % 2 else 0.0, device=cuda)
        lr = th.tensor(1e-3, device=cuda)
        models = lambda p: (p.model, p.model_target, p.optimizer, p.pi_optimizer)  # noqa: E731
        eager = topo_update(*models(eager_policy), batch, noise, lr, ema, cfg, 0.99)
        comp = compiled(*models(compiled_policy), batch, noise, lr, ema, cfg, 0.99).clone()
        th.testing.assert_close(comp, eager, rtol=1e-4, atol=1e-5)
    assert compiled.compiled


@CUDA
@pytest.mark.cuda
def test_a_model_trained_and_saved_on_cuda_loads_and_predicts_on_cpu(tmp_path):
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", **{**COMPILED_SPPO, "compile": "auto"}, device="cuda").learn(80)
    model.save(tmp_path / "sppo")
    obs = np.array([[0.2, -0.3, 0.5, 0.1]], dtype=np.float32)
    on_gpu, _ = model.predict(obs, deterministic=True)
    loaded = SPPO.load(tmp_path / "sppo", device="cpu")
    assert all(p.device.type == "cpu" for p in loaded.policy.parameters())
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], on_gpu, atol=1e-4)
    loaded.set_env(model.get_env())
    loaded.learn(40, reset_num_timesteps=False)
    assert loaded.num_timesteps == 120
