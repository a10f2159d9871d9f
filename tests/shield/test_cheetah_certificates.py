"""The Half-Cheetah shield's certificates: the facts they rest on, and the same decisions as solving every step."""

from __future__ import annotations

import numpy as np
import pytest

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.envs.half_cheetah_height import SafeHalfCheetahHeightEnv
from sppo_sb3.shield.mujoco.warm_starts import WarmStarts
from sppo_sb3.shield.tasks.cheetah import HalfCheetahHeightShieldingRule

HOLD = np.full(6, 0.3)  # stands still, front thigh at ~0.61


def small_rule(certify: bool, certificate_particles: int = 3) -> HalfCheetahHeightShieldingRule:
    """A cheaper MPC (the facts hold for any horizon and particle count)."""
    return HalfCheetahHeightShieldingRule(
        horizon=8, n_particles=16, certify=certify, certificate_particles=certificate_particles, n_threads=0
    )


def observations_near_violations(n: int, seed: int = 0) -> np.ndarray:
    """``n`` observations of unshielded random-action episodes, each 1 to 3 steps before the thigh leaves the range."""
    env = SafeHalfCheetahHeightEnv()
    rng = np.random.default_rng(seed)
    episode, near = [env.reset(seed=seed)[0]], []
    while len(near) < n:
        obs, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 6))
        episode.append(obs)
        if terminated:
            near += episode[-4:-1]
        if terminated or truncated:
            episode = [env.reset()[0]]
    return np.asarray(near[:n])


def test_warm_starts_match_predicted_states_only() -> None:
    warm = WarmStarts(capacity=2, horizon=3, n_controls=1, tolerance=1e-5)
    keys, plans, states = np.array([[0.0, 1.0], [2.0, 3.0]]), np.arange(6.0).reshape(2, 3, 1), np.array([[9.0], [8.0]])
    warm.replace(np.array([-1]), keys, plans, states)
    found, used, predicted = warm.lookup(np.array([[2.0, 3.0 + 1e-7], [0.0, 1.001]]))
    assert used.tolist() == [1, -1]
    np.testing.assert_array_equal(found, [plans[1], np.zeros((3, 1))])  # no match: the zero plan
    np.testing.assert_array_equal(predicted, [[8.0], [np.nan]])  # ... and no state
    warm.replace(used, np.array([[5.0, 5.0]]), np.full((1, 3, 1), 7.0), np.array([[7.0]]))  # the used entry goes
    np.testing.assert_array_equal(warm.keys, [[0.0, 1.0], [5.0, 5.0]])
    np.testing.assert_array_equal(warm.states, [[9.0], [7.0]])
    warm.replace(np.array([-1]), np.array([[6.0, 6.0]]), np.full((1, 3, 1), 8.0), np.array([[6.0]]))  # over capacity
    np.testing.assert_array_equal(warm.keys, [[5.0, 5.0], [6.0, 6.0]])  # the oldest went


def test_the_bounds_behind_the_certificates() -> None:
    """``J >= 0``; ``Q̄(s, a) <= J([a, W[1:]])``; ``Q̄(s, ζ(s))`` at most ``J([ζ, W[1:]])`` and ``ζ``'s particle plan's."""
    rule = small_rule(certify=False)
    obs = observations_near_violations(12)
    states = rule.layout.states_from_obs(rule.model, obs)
    actions = np.random.default_rng(1).uniform(-1, 1, (len(obs), 6))
    warm = np.clip(0.3 * np.random.default_rng(2).standard_normal((len(obs), rule.horizon, 6)), -1, 1)
    nominal_cost = rule.plan_costs(states, warm[:, 1:], actions)
    q = rule.solve(states, warm[:, 1:], actions).costs
    assert np.all(q >= 0) and np.all(q <= nominal_cost)
    assert np.any(q < nominal_cost) and np.any(nominal_cost > rule.eta)  # the solve matters on these states
    backup = rule.solve(states, warm)
    backup_value = rule.solve(states, warm[:, 1:], backup.plans[:, 0]).costs
    assert np.all(backup_value <= rule.plan_costs(states, warm[:, 1:], backup.plans[:, 0]))
    assert backup.is_particle.any() and np.all(backup_value[backup.is_particle] <= backup.costs[backup.is_particle])


def shielded_run(rule: HalfCheetahHeightShieldingRule, steps: int, batched: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    """Two envs under ``rule``, aggressive random proposals; ``(actions, intervened)`` of each step.

    ``batched``: one call for both envs (as SPPO); else one call per env (as ``ShieldWrapper``).
    """
    envs = [SafeHalfCheetahHeightEnv() for _ in range(2)]
    obs = np.stack([env.reset(seed=i)[0] for i, env in enumerate(envs)])
    rng = np.random.default_rng(0)
    decisions = []
    for _ in range(steps):
        proposed = rng.uniform(-1, 1, (2, 6))
        if batched:
            decision = rule.shield(obs, proposed)
            actions, intervened = decision.actions, decision.intervened
        else:
            parts = [rule.shield(obs[i : i + 1], proposed[i : i + 1]) for i in range(2)]
            actions = np.concatenate([d.actions for d in parts])
            intervened = np.concatenate([d.intervened for d in parts])
        decisions.append((actions, intervened))
        for i, env in enumerate(envs):
            obs[i], _, terminated, truncated, _ = env.step(actions[i])
            if terminated or truncated:
                obs[i] = env.reset()[0]
    return decisions


@pytest.mark.parametrize("certificate_particles", [0, 3])
def test_certified_rule_decides_as_the_full_rule(certificate_particles: int) -> None:
    steps = 60
    certified = small_rule(certify=True, certificate_particles=certificate_particles)
    full = small_rule(certify=False, certificate_particles=certificate_particles)
    fast_decisions, full_decisions = shielded_run(certified, steps, True), shielded_run(full, steps, True)
    for (fast_actions, fast_intervened), (full_actions, full_intervened) in zip(fast_decisions, full_decisions):
        np.testing.assert_array_equal(fast_intervened, full_intervened)
        np.testing.assert_array_equal(fast_actions, full_actions)
    np.testing.assert_array_equal(certified.warm_starts.plans, full.warm_starts.plans)
    counts = certified.solve_counts
    assert counts.steps == 2 * steps and 0 < counts.q_solves < counts.steps  # certificates were used, and failed
    assert sum(intervened.sum() for _, intervened in full_decisions) > 0  # the run reached the shielding set
    assert full.solve_counts.backup_value_solves == 2 * steps


def test_warm_plans_follow_each_env_whatever_the_batching() -> None:
    """Keyed by the predicted next state, the warm plans serve one call per env as they serve one call for all."""
    batched, per_env = small_rule(certify=True), small_rule(certify=True)
    for (a, i), (b, j) in zip(shielded_run(batched, 30, True), shielded_run(per_env, 30, False)):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(i, j)


def test_a_quiet_stand_is_certified_without_solving() -> None:
    env = SafeHalfCheetahHeightEnv()
    rule = HalfCheetahHeightShieldingRule(seed=0, n_threads=0)
    env.reset(seed=0)
    env.set_state(env.init_qpos, env.init_qvel)
    for _ in range(100):
        obs, *_ = env.step(HOLD)
    for _ in range(3):
        decision = rule.shield(obs[None], HOLD[None])
        assert not decision.intervened[0] and decision.advantage[0] <= rule.eta
        obs, *_ = env.step(decision.actions[0])
        assert rule.warm_starts.lookup(obs[None])[1][0] >= 0  # the env reached the predicted state: a plan is there
    assert rule.solve_counts.q_solves == 0
    obs, _ = env.reset(seed=1)
    assert rule.warm_starts.lookup(obs[None])[1][0] == -1  # a new episode starts from the zero plan


@pytest.mark.parametrize("certify", [True, False])
def test_backup_value_is_zero_advantage(certify: bool) -> None:
    rule = small_rule(certify=certify)
    obs = observations_near_violations(4, seed=3)
    backup = rule.backup_action(obs)
    np.testing.assert_array_equal(rule.advantage(obs, backup, backup), 0.0)  # Proposition 1, exactly
