"""CPO: the dual solution of the step problem on constructed quadratics, and the algorithm end to end."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from tiny_hyperparams import TINY_CPO

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.cpo import CPO, cpo_dual_solution

DELTA = 0.01


def _problem(seed: int, dim: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(dim, dim))
    return m @ m.T + 0.5 * np.eye(dim), rng.normal(size=dim), rng.normal(size=dim)


def _step(h: np.ndarray, g: np.ndarray, b: np.ndarray, c: float, delta: float = DELTA):
    h_inv_g, h_inv_b = np.linalg.solve(h, g), np.linalg.solve(h, b)
    sol = cpo_dual_solution(g @ h_inv_g, g @ h_inv_b, b @ h_inv_b, c, delta)
    return sol, sol.coef_g * h_inv_g + sol.coef_b * h_inv_b


def _best_on_grid(h: np.ndarray, g: np.ndarray, b: np.ndarray, c: float, delta: float = DELTA, n: int = 601) -> float:
    """Brute force over the plane spanned by H⁻¹g and H⁻¹b, where the optimum lies (KKT)."""
    u, v = np.linalg.solve(h, g), np.linalg.solve(h, b)
    scale_u, scale_v = math.sqrt(2 * delta / (u @ h @ u)), math.sqrt(2 * delta / (v @ h @ v))
    alpha, beta = np.meshgrid(np.linspace(-3, 3, n) * scale_u, np.linspace(-3, 3, n) * scale_v)
    xs = alpha.reshape(-1, 1) * u + beta.reshape(-1, 1) * v
    kl = 0.5 * np.einsum("ni,ij,nj->n", xs, h, xs)
    ok = (kl <= delta) & (c + xs @ b <= 0)
    return float((xs[ok] @ g).max())


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("c_frac", [-0.9, -0.3, 0.0, 0.3, 0.9])
def test_step_is_feasible_and_optimal_on_quadratics(seed: int, c_frac: float) -> None:
    h, g, b = _problem(seed)
    s = b @ np.linalg.solve(h, b)
    c = c_frac * math.sqrt(2 * DELTA * s)  # |c| < sqrt(2δs): the trust region holds feasible points
    sol, x = _step(h, g, b, c)
    assert sol.case in ("constrained", "unconstrained")
    assert 0.5 * x @ h @ x <= DELTA * (1 + 1e-6)  # KL bound
    assert c + b @ x <= 1e-9  # linearised cost constraint
    assert g @ x >= _best_on_grid(h, g, b, c) - 1e-6  # no feasible point of the plane does better


def test_trust_region_clear_of_the_constraint_is_trpo() -> None:
    h, g, b = _problem(0)
    s, q = b @ np.linalg.solve(h, b), g @ np.linalg.solve(h, g)
    sol, x = _step(h, g, b, c=-2 * math.sqrt(2 * DELTA * s))
    assert sol.case == "unconstrained" and sol.nu == 0.0
    np.testing.assert_allclose(x, math.sqrt(2 * DELTA / q) * np.linalg.solve(h, g))
    assert 0.5 * x @ h @ x == pytest.approx(DELTA)


def test_binding_constraint_bends_the_trpo_step() -> None:
    h, g, _ = _problem(1)
    b = g.copy()  # the cost grows exactly where the reward does
    q = g @ np.linalg.solve(h, g)
    c = -0.5 * math.sqrt(2 * DELTA * q)  # TRPO's step would overshoot the allowed cost increase -c
    sol, x = _step(h, g, b, c)
    assert sol.case == "constrained" and sol.nu > 0
    assert c + b @ x == pytest.approx(0.0, abs=1e-9)  # the constraint is active at the solution
    assert 0.5 * x @ h @ x < DELTA
    # the same with b only nearly parallel to g goes through the general dual formula
    b2 = g + 1e-3 * np.random.default_rng(0).normal(size=g.shape)
    sol2, x2 = _step(h, g, b2, c)
    assert sol2.case == "constrained" and c + b2 @ x2 <= 1e-9 and 0.5 * x2 @ h @ x2 <= DELTA * (1 + 1e-6)


def test_infeasible_case_takes_the_recovery_step() -> None:
    h, g, b = _problem(2)
    h_inv_b = np.linalg.solve(h, b)
    s = b @ h_inv_b
    c = 1.5 * math.sqrt(2 * DELTA * s)  # even the best point of the trust region violates the constraint
    sol, x = _step(h, g, b, c)
    assert sol.case == "infeasible" and sol.coef_g == 0.0
    np.testing.assert_allclose(x, -math.sqrt(2 * DELTA / s) * h_inv_b)
    assert 0.5 * x @ h @ x == pytest.approx(DELTA)  # on the trust-region boundary
    assert b @ x == pytest.approx(-math.sqrt(2 * DELTA * s))  # the largest first-order cost decrease


def test_degenerate_inputs() -> None:
    assert cpo_dual_solution(1.0, 0.0, 0.0, -0.1, DELTA).case == "unconstrained"  # no cost gradient, feasible
    no_grad = cpo_dual_solution(1.0, 0.0, 0.0, 0.1, DELTA)  # no cost gradient, violated: no first-order fix
    assert no_grad.case == "infeasible" and no_grad.coef_b == 0.0 and no_grad.coef_g == 0.0
    zero = cpo_dual_solution(0.0, 0.0, 1.0, -10.0, DELTA)  # no reward gradient, constraint slack
    assert zero.coef_g == 0.0 and zero.coef_b == 0.0
    with pytest.raises(ValueError, match="delta"):
        cpo_dual_solution(1.0, 0.0, 1.0, 0.0, 0.0)


def test_cpo_smoke_save_load_predict(tmp_path) -> None:
    model = CPO("MlpPolicy", "SafePointCircle-v0", seed=0, tensorboard_log=str(tmp_path / "tb"), **TINY_CPO)
    model.learn(256, progress_bar=True)
    assert model.safety_metrics.steps == 256 and model.last_solution is not None
    model.save(tmp_path / "cpo")
    loaded = CPO.load(tmp_path / "cpo")
    obs = np.random.default_rng(0).uniform(-2, 2, size=(16, 4)).astype(np.float32)
    np.testing.assert_allclose(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    np.testing.assert_equal(loaded.safety_metrics.summary(), model.safety_metrics.summary())


def test_cpo_n_envs() -> None:
    model = CPO("MlpPolicy", make_vec_env("SafePointCircle-v0", n_envs=2, seed=0), seed=0, **TINY_CPO)
    model.learn(256)
    assert model.safety_metrics.steps == 256 and model.rollout_buffer.costs.shape == (64, 2)


def test_cpo_recovers_when_the_constraint_is_hopelessly_violated(monkeypatch: pytest.MonkeyPatch) -> None:
    long_rollouts = {**TINY_CPO, "n_steps": 256, "batch_size": 64, "n_critic_updates": 1}
    model = CPO("MlpPolicy", "SafePointCircle-v0", seed=0, **long_rollouts)
    monkeypatch.setattr(model, "constraint_value", lambda: 1e3)
    model.learn(256)
    sol = model.last_solution
    assert sol is not None and sol.case == "infeasible" and sol.coef_g == 0.0
    # the accepted step did not increase the (centred) cost surrogate, and respected the KL bound
    data = next(model.rollout_buffer.get(None))
    with th.no_grad():
        dist = model.policy.get_distribution(data.observations)
        ratio = th.exp(dist.log_prob(data.actions) - data.old_log_prob)
    cadv = data.cost_advantages - data.cost_advantages.mean()
    assert (cadv * ratio).mean().item() <= 1e-7
    assert model.logger.name_to_value["train/kl_divergence_loss"] <= model.target_kl
