"""MPPI planner: eqs. 2, 3, 10, 11 on hand-computed cases, warm start, bounds, batching."""

import math

import pytest
import torch as th
from tiny_hyperparams import TINY_MPPI, TINY_TOLD

from sppo_sb3.sppo.planner import (
    MPPIConfig,
    MPPIPlanner,
    draw_noise,
    linear_schedule,
    low_precision_copy,
    mppi,
    refit_gaussian,
    trajectory_return,
    warm_start,
)
from sppo_sb3.sppo.world_model import ELU, TOLD

GAMMA = 0.99  # the planner's discount, SPPO's gamma


def tiny_model(obs_dim: int = 3, action_dim: int = 2) -> TOLD:
    th.manual_seed(0)
    return TOLD(obs_dim, action_dim, **TINY_TOLD)


def test_refit_gaussian_matches_hand_computed_weights():
    # two elites, one action dim, horizon 1: Ω = exp(τ(Φ - max Φ)) = [exp(-τ), 1]
    elites = th.tensor([[[[0.0]], [[1.0]]]])  # (E=1, k=2, H=1, A=1)
    returns = th.tensor([[1.0, 2.0]])
    tau = 0.5
    mean, std = refit_gaussian(elites, returns, tau)
    w0, w1 = math.exp(-tau), 1.0
    expected_mean = (w0 * 0.0 + w1 * 1.0) / (w0 + w1)  # eq. 2
    expected_std = math.sqrt((w0 * expected_mean**2 + w1 * (1 - expected_mean) ** 2) / (w0 + w1))  # eq. 3
    assert mean.item() == pytest.approx(expected_mean, rel=1e-6)
    assert std.item() == pytest.approx(expected_std, rel=1e-6)


def test_refit_gaussian_is_per_env():
    elites = th.tensor([[[[0.0]], [[1.0]]], [[[4.0]], [[4.0]]]])
    mean, std = refit_gaussian(elites, th.tensor([[0.0, 0.0], [3.0, 1.0]]), 1.0)
    assert mean[0].item() == pytest.approx(0.5) and std[0].item() == pytest.approx(0.5)
    assert mean[1].item() == pytest.approx(4.0) and std[1].item() == pytest.approx(0.0, abs=1e-6)


def test_schedules_decay_linearly():
    cfg = MPPIConfig(horizon=5, horizon_warmup=100, min_std_start=0.5, min_std_end=0.05, min_std_decay=100)
    assert cfg.horizon_at(0) == 1 and cfg.horizon_at(50) == 3 and cfg.horizon_at(10**6) == 5
    assert cfg.min_std_at(0) == pytest.approx(0.5)
    assert cfg.min_std_at(50) == pytest.approx(0.275)
    assert cfg.min_std_at(1000) == pytest.approx(0.05)
    assert linear_schedule(1.0, 2.0, 0, 3) == 2.0


def small_planner(**overrides) -> MPPIPlanner:
    cfg = MPPIConfig(**{"num_samples": 32, "num_elites": 4, "iterations": 3, "horizon": 3, "horizon_warmup": 0, **overrides})
    return MPPIPlanner(cfg, action_dim=2, gamma=GAMMA)


def plan(planner: MPPIPlanner, model: TOLD, obs: th.Tensor, **kwargs) -> th.Tensor:
    """A cold-started plan's actions."""
    return planner.plan(model, obs, planner.initial_mean(len(obs)), 0, **kwargs)[0]


def test_plan_shapes_bounds_and_sigma_floor():
    model, planner = tiny_model(), small_planner(min_std_start=0.7, min_std_end=0.7)
    actions, mean, _ = planner.plan(model, th.randn(3, 3), planner.initial_mean(3), step=0)
    assert actions.shape == (3, 2) and mean.shape == (3, 3, 2)
    assert actions.abs().max() <= 1.0
    # eq. 11: the final σ never drops below ε, so sampled actions spread at least that much across calls
    th.manual_seed(1)
    draws = th.stack([plan(planner, model, th.zeros(1, 3)) for _ in range(30)])
    assert draws.std(0).min() > 0.2


def test_warm_start_shifts_by_one_step():
    previous = th.randn(2, 3, 2)
    shifted = warm_start(previous, 3)
    assert th.equal(shifted[:, :-1], previous[:, 1:])
    assert th.all(shifted[:, -1] == 0)
    assert warm_start(previous, 2).shape == (2, 2, 2)


def test_candidates_are_the_plan_then_the_first_iterations_best_first_actions():
    """``num_candidates``: the plan's action first, then the first actions of iteration 1's best trajectories, ranked
    by their returns (eq. 10): recomputed here from the same noise."""
    cfg = MPPIConfig(num_samples=16, num_elites=4, iterations=2, horizon=2, num_candidates=4, max_std=0.3)  # no clipping
    model = tiny_model()
    assert cfg.num_policy_samples == 0  # every elite is a Gaussian sample
    noise = draw_noise(cfg, 2, 2, 2, True, th.Generator().manual_seed(1), th.device("cpu"))
    obs, warm = th.randn(2, 3), th.zeros(2, 2, 2)
    with th.no_grad():
        _, _, alternatives = mppi(model, obs, warm, noise, th.tensor(0.1), cfg, GAMMA)
        samples = (warm.unsqueeze(1) + cfg.max_std * noise.samples[0]).clamp(-1.0, 1.0)  # (E, N, H, A)
        z = model.encode(obs).repeat_interleave(cfg.num_samples, 0)
        flat = samples.permute(2, 0, 1, 3).reshape(2, -1, 2)
        returns = trajectory_return(model, z, flat, GAMMA, cfg.policy_std, noise.terminal[0]).view(2, -1)
    assert alternatives.shape == (2, 3, 2)
    for env in range(2):
        rows = [int(th.nonzero((samples[env, :, 0] == a).all(-1))[0]) for a in alternatives[env]]
        ranked = returns[env, rows]
        assert th.all(ranked[:-1] >= ranked[1:])  # best first
        assert ranked[0] == returns[env].max()
    planner = MPPIPlanner(cfg, action_dim=2, gamma=GAMMA)
    plan = planner.plan(model, obs, planner.initial_mean(2), 0, deterministic=True, generator=th.Generator().manual_seed(1))
    assert plan.candidates.shape == (2, 4, 2) and th.equal(plan.candidates[:, 0], plan.action)
    with pytest.raises(ValueError, match="num_candidates"):
        MPPIConfig(num_elites=4, num_candidates=6)
    with pytest.raises(ValueError, match="num_elites"):
        MPPIConfig(num_samples=16, num_elites=64)


def test_the_plan_starts_from_the_given_state():
    """The warm start is the caller's: the returned mean seeds the next plan, and other means give other plans."""
    model, planner = tiny_model(), small_planner(iterations=1, momentum=0.9)
    obs = th.randn(2, 3)
    mean = planner.plan(model, obs, planner.initial_mean(2), 0).mean
    gen = th.Generator().manual_seed(0)
    warm = planner.plan(model, obs, mean, 0, deterministic=True, generator=gen).action
    cold = planner.plan(model, obs, planner.initial_mean(2), 0, deterministic=True, generator=gen.manual_seed(0)).action
    assert not th.allclose(warm, cold)
    with pytest.raises(ValueError, match="state must have shape"):
        planner.plan(model, obs, planner.initial_mean(3), 0)


def test_deterministic_plans_are_a_pure_function_of_obs_state_and_generator():
    model, planner = tiny_model(), small_planner()
    obs, state = th.randn(2, 3), th.rand(2, 3, 2) - 0.5
    first = planner.plan(model, obs, state, 0, deterministic=True, generator=th.Generator().manual_seed(5))
    second = planner.plan(model, obs, state, 0, deterministic=True, generator=th.Generator().manual_seed(5))
    assert th.equal(first[0], second[0]) and th.equal(first[1], second[1])
    assert th.equal(first[0], first[1][:, 0].clamp(-1, 1))  # deterministic: μ_J's first action


def test_mppi_is_a_function_of_its_noise():
    """All randomness enters through PlanNoise: the same noise gives the same plan, whatever torch's RNG does."""
    model, cfg = tiny_model(), MPPIConfig(**TINY_MPPI, horizon=3)
    noise = draw_noise(cfg, 2, 3, 2, False, None, th.device("cpu"))
    obs, warm, min_std = th.randn(2, 3), th.zeros(2, 3, 2), th.tensor(0.1)
    with th.no_grad():
        first = mppi(model, obs, warm, noise, min_std, cfg, GAMMA)
        th.manual_seed(123)
        second = mppi(model, obs, warm, noise, min_std, cfg, GAMMA)
    assert th.equal(first[0], second[0]) and th.equal(first[1], second[1])


def test_batched_planning_equals_per_env_planning_without_noise():
    """All envs are planned in one call: with zero-variance sampling the result must not depend on batching."""
    model = tiny_model()
    cfg = dict(max_std=1e-9, min_std_start=0.0, min_std_end=0.0, policy_std=0.0)
    obs = th.randn(3, 3)
    batched = plan(small_planner(**cfg), model, obs, deterministic=True)
    single = th.cat([plan(small_planner(**cfg), model, obs[i : i + 1], deterministic=True) for i in range(3)])
    assert th.allclose(batched, single, atol=1e-5)


def test_planner_prefers_high_reward_actions():
    """A model whose reward is +a[0] must plan a[0] close to +1."""
    model = tiny_model(action_dim=1)
    with th.no_grad():
        for net in (model.reward, model.q1, model.q2, model.dynamics):
            for p in net.parameters():
                p.zero_()
        model.reward[0].weight[:, -1] = 1.0  # the action's input column
        model.reward[0].bias.fill_(1.0)
        model.reward[2].weight.copy_(th.eye(TINY_TOLD["hidden_dim"]))  # hidden = a + 1 >= 0 passes both ELUs unchanged
        model.reward[-1].weight.fill_(0.1)
    planner = MPPIPlanner(MPPIConfig(num_samples=64, num_elites=8, iterations=4, horizon=2, horizon_warmup=0), 1, GAMMA)
    th.manual_seed(0)
    assert planner.plan(model, th.zeros(1, 3), planner.initial_mean(1), step=10**6, deterministic=True)[0].item() > 0.8


def test_bfloat16_planner_tracks_fp32_returns():
    model = tiny_model()
    shadow = low_precision_copy(model, th.bfloat16)
    z = model.encode(th.randn(64, 3))
    action = th.rand(64, 2) * 2 - 1
    with th.no_grad():
        model.reward[-1].weight.normal_()  # non-zero head
        shadow.reward[-1].weight.copy_(model.reward[-1].weight)
        _, r32 = model.next(z, action)
        _, r16 = shadow.next(z.bfloat16(), action.bfloat16())
    assert r16.dtype == th.float32
    assert th.allclose(r16, r32, atol=0.05 * r32.abs().max().item())


def test_inference_elu_equals_torch_elu_and_keeps_autograd():
    x = th.cat([th.randn(4096) * 5, th.tensor([0.0, -1e4, 1e4, -1e-8, 1e-8])])
    with th.no_grad():
        assert th.allclose(ELU()(x), th.nn.functional.elu(x), atol=1e-6, rtol=0)
    x.requires_grad_(True)
    ELU()(x).sum().backward()  # with autograd on it is F.elu, whose gradient is exp(x) below 0 and 1 above
    assert x.grad is not None and th.allclose(x.grad, th.where(x > 0, th.ones_like(x), th.exp(x.detach())))
