"""Tests of the advantage-based shield of Section III-B: rules, Proposition 1, eq. 12, the wrapper, eq. 18."""

from __future__ import annotations

import io
import subprocess
import sys
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from hypothesis import given, settings
from hypothesis import strategies as st
from stable_baselines3.common.vec_env import DummyVecEnv
from tiny_hyperparams import TINY_ROLLOUT

from sppo_lab.point_lap import run_scripted_lap
from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.keys import ADVANTAGE_KEY, COST_KEY, PROPOSED_ACTION_KEY
from sppo_sb3.envs.point_circle import PointParams, point_distance_to_unsafe, point_is_unsafe, point_step
from sppo_sb3.pdo import PDO
from sppo_sb3.sailr import SAILR
from sppo_sb3.shield import (
    RULE_ENV_PARAMETERS,
    SHIELDING_RULES,
    HalfCheetahHeightShieldingRule,
    LearnedCostCriticRule,
    PointCircleShieldingRule,
    ShieldingRule,
    ShieldWrapper,
    default_shielding_rule,
    in_shielding_set,
    register_shielding_rule,
    resolve_shielding_rule,
)
from sppo_sb3.shield.base import advantage_from_values
from sppo_sb3.shield.evaluation import deployment_rule, evaluate_deployment
from sppo_sb3.shield.registry import PAPER_POINT_RULE
from sppo_sb3.shield.tasks.point import paper_point_rule

PARAMS = PointParams()
INTERVENED = "shield_intervened"


def brake_until_rest(rule: PointCircleShieldingRule, states: np.ndarray, steps: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Run the braking backup on the env's own dynamics; return (never unsafe along the way, final states)."""
    safe = ~point_is_unsafe(states, PARAMS)
    for _ in range(steps):
        states = point_step(states, rule.backup_action(states), PARAMS)
        safe &= ~point_is_unsafe(states, PARAMS)
    return safe, states


# --------------------------------------------------------------------------------------------- Point rule
class TestPointRule:
    def test_intervenes_at_speed_towards_the_wall(self) -> None:
        rule = PointCircleShieldingRule()
        # the last row coasts one step: from there braking stops at 2.55, while braking now stops at 2.45
        obs = np.array([[2.3, 0.0, 2.0, 0.0], [-2.3, 1.0, -2.0, 0.0], [1.8, 0.0, 1.0, 0.0], [1.95, 0.0, 1.0, 0.0]])
        actions = np.array([[1.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
        decision = rule.shield(obs, actions)
        assert decision.intervened.all()
        assert (decision.advantage > 0).all()
        np.testing.assert_allclose(decision.actions, rule.backup_action(obs))
        # the backup brakes against the velocity
        assert decision.actions[0, 0] == -1.0 and decision.actions[1, 0] == 1.0

    def test_no_intervention_at_rest_at_the_origin(self) -> None:
        rule = PointCircleShieldingRule()
        rng = np.random.default_rng(0)
        actions = rng.uniform(-1.0, 1.0, size=(64, 2))
        decision = rule.shield(np.zeros((64, 4)), actions)
        assert not decision.intervened.any()
        np.testing.assert_array_equal(decision.actions, actions)

    def test_allowed_actions_keep_the_braking_backup_safe(self) -> None:
        """Invariance: from a state where braking is safe, any allowed action leads where braking is still safe."""
        rule = PointCircleShieldingRule()
        # x strictly inside the safe set: on the boundary x = 2.5 at rest ĉ = 1 forever costs as much as the unsafe
        # set's absorbing tail, so Ā = 0 and the rule is indifferent there (reported, see the shield's notes)
        xs, vs = np.meshgrid(np.linspace(0.0, 2.49, 250), np.linspace(0.0, 2.0, 101))
        states = np.stack([xs.ravel(), np.zeros(xs.size), vs.ravel(), np.zeros(xs.size)], axis=1)
        recoverable, _ = brake_until_rest(rule, states.copy())
        assert 0.3 < recoverable.mean() < 0.95  # the scan covers both recoverable and doomed states
        for push in ([1.0, 0.0], [1.0, 1.0], [0.3, -1.0]):
            decision = rule.shield(states, np.tile(push, (len(states), 1)))
            after = point_step(states, np.clip(decision.actions, -1.0, 1.0), PARAMS)
            still_safe, _ = brake_until_rest(rule, after)
            assert still_safe[recoverable].all(), states[recoverable & ~still_safe]

    def test_braking_from_the_worst_allowed_state_stays_safe_in_the_env(self) -> None:
        rule = PointCircleShieldingRule()
        xs, vs = np.meshgrid(np.linspace(0.0, 2.49, 250), np.linspace(0.0, 2.0, 201))
        states = np.stack([xs.ravel(), np.zeros(xs.size), vs.ravel(), np.zeros(xs.size)], axis=1)
        recoverable, _ = brake_until_rest(rule, states.copy())
        push = np.array([1.0, 0.0])
        allowed = ~rule.shield(states, np.tile(push, (len(states), 1))).intervened & recoverable
        worst = states[np.argmax(np.where(allowed, states[:, 0] * states[:, 2], -1.0))]
        assert worst[0] * worst[2] > 1.0  # a fast approach close to the wall, not a trivial state

        env = gym.make("SafePointCircle-v0")
        env.reset(seed=0)
        env.unwrapped.state = worst.copy()
        obs, _, terminated, _, info = env.step(push.astype(np.float32))
        assert not terminated and info[COST_KEY] == 0.0
        for _ in range(50):
            obs, _, terminated, _, info = env.step(rule.backup_action(obs[None].astype(np.float64))[0].astype(np.float32))
            assert not terminated and info[COST_KEY] == 0.0
            assert abs(env.unwrapped.state[0]) <= PARAMS.x_limit
        np.testing.assert_allclose(env.unwrapped.state[2:], 0.0, atol=1e-9)  # the backup brought it to rest
        env.close()


# --------------------------------------------------------------------------------------------- Proposition 1
safe_point_states = st.tuples(
    st.floats(-PARAMS.x_limit, PARAMS.x_limit),
    st.floats(-PARAMS.y_limit, PARAMS.y_limit),
    st.floats(0.0, PARAMS.max_speed),
    st.floats(0.0, 2.0 * np.pi),
).map(lambda s: np.array([s[0], s[1], s[2] * np.cos(s[3]), s[2] * np.sin(s[3])]))


@settings(max_examples=60, deadline=None)
@given(
    states=st.lists(safe_point_states, min_size=1, max_size=16),
    eta=st.floats(0.0, 5.0),
    seed=st.integers(0, 2**16),
)
def test_proposition1_point_rule(states: list[np.ndarray], eta: float, seed: int) -> None:
    """With η >= 0 the backup action itself is never shielded, so every executed action is admissible."""
    rule = PointCircleShieldingRule(eta=eta)
    obs = np.stack(states)
    backup = rule.backup_action(obs)
    decision = rule.shield(obs, backup)
    assert not decision.intervened.any()
    np.testing.assert_array_equal(decision.advantage, 0.0)
    # a shielded batch of random proposals executes only actions that are themselves not shielded
    proposals = np.random.default_rng(seed).uniform(-1.0, 1.0, size=(len(obs), 2))
    executed = rule.shield(obs, proposals).actions
    assert not rule.shield(obs, executed).intervened.any()


def random_learned_rule(obs_dim: int, act_dim: int, seed: int, eta: float = 0.0) -> LearnedCostCriticRule:
    """A learned rule whose critic has random (non-zero) weights, so that Q̄ is far from constant."""
    obs_space = gym.spaces.Box(-3.0, 3.0, shape=(obs_dim,))
    act_space = gym.spaces.Box(-2.0, 2.0, shape=(act_dim,))
    rule = LearnedCostCriticRule(obs_space, act_space, lambda o: np.clip(o[:, :act_dim], -2.0, 2.0), eta=eta, seed=seed)
    gen = th.Generator().manual_seed(seed)
    with th.no_grad():
        for param in rule.critic.parameters():
            param.copy_(th.randn(param.shape, generator=gen) * 0.5)
    return rule


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    batch=st.integers(1, 40),
    obs_dim=st.integers(1, 6),
    act_dim=st.integers(1, 3),
    eta=st.floats(0.0, 0.5),
)
def test_proposition1_learned_rule(seed: int, batch: int, obs_dim: int, act_dim: int, eta: float) -> None:
    act_dim = min(act_dim, obs_dim)
    rule = random_learned_rule(obs_dim, act_dim, seed, eta)
    rng = np.random.default_rng(seed)
    obs = rng.uniform(-3.0, 3.0, size=(batch, obs_dim))
    decision = rule.shield(obs, rule.backup_action(obs))
    assert not decision.intervened.any()
    np.testing.assert_array_equal(decision.advantage, 0.0)
    proposals = rng.uniform(-2.0, 2.0, size=(batch, act_dim))
    q = rule.cost_value(obs, proposals)
    assert np.all((q >= 0.0) & (q <= rule.gamma))
    executed = rule.shield(obs, proposals).actions
    assert not rule.shield(obs, executed).intervened.any()


# --------------------------------------------------------------------------------------------- eq. 12 semantics
class FirstCoordinateRule(ShieldingRule):
    """Toy rule with ``Q̄(s, a) = a_0`` and the backup ``ζ(s) = 0``, so that ``Ā(s, a) = a_0``."""

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.asarray(actions, dtype=np.float64)[:, 0].copy()

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 2))


def test_shield_executes_proposal_iff_advantage_at_most_eta() -> None:
    eta = 0.25
    rule = FirstCoordinateRule(eta=eta)
    actions = np.array([[-1.0, 0.5], [0.0, -0.5], [0.25, 0.9], [0.2500001, 0.3], [1.0, 1.0]])
    decision = rule.shield(np.zeros((5, 3)), actions)
    np.testing.assert_array_equal(decision.advantage, actions[:, 0])
    np.testing.assert_array_equal(decision.intervened, [False, False, False, True, True])  # Ā == η is allowed
    np.testing.assert_array_equal(decision.actions[:3], actions[:3])
    np.testing.assert_array_equal(decision.actions[3:], 0.0)


def test_shield_first_accepted_executes_each_rows_first_accepted_candidate() -> None:
    """Ranked proposals: the first candidate with ``Ā <= η`` is executed, the backup where none is, and a NaN
    candidate is never accepted (fail closed)."""
    rule = FirstCoordinateRule(eta=0.25)
    candidates = np.array(
        [
            [[0.1, 0.1], [0.9, 0.9], [0.0, 0.3]],  # the plan is accepted
            [[0.9, 0.1], [0.5, 0.2], [0.2, -0.4]],  # the plan and the next rejected: the third
            [[0.9, 0.1], [np.nan, 0.2], [0.7, 0.0]],  # none: the backup
            [[0.9, 0.1], [np.nan, 0.2], [-1.0, 0.5]],  # the NaN is skipped
        ]
    )
    decision, choice = rule.shield_first_accepted(np.zeros((4, 3)), candidates)
    np.testing.assert_array_equal(choice, [0, 2, -1, 2])
    np.testing.assert_array_equal(decision.intervened, [False, False, True, False])
    np.testing.assert_array_equal(decision.actions, [[0.1, 0.1], [0.2, -0.4], [0.0, 0.0], [-1.0, 0.5]])
    np.testing.assert_array_equal(decision.advantage, [0.1, 0.2, 0.9, -1.0])
    single, first = rule.shield_first_accepted(np.zeros((4, 3)), candidates[:, :1])
    plain = rule.shield(np.zeros((4, 3)), candidates[:, 0])
    np.testing.assert_array_equal(single.actions, plain.actions)
    np.testing.assert_array_equal(first, np.where(plain.intervened, -1, 0))


def test_in_shielding_set_boundary() -> None:
    adv = np.array([-1.0, 0.0, 0.2, np.nextafter(0.2, 1.0), 3.0])
    np.testing.assert_array_equal(in_shielding_set(adv, 0.2), [False, False, False, True, True])
    np.testing.assert_array_equal(in_shielding_set(np.array([0.0]), 0.0), [False])


def test_invalid_eta() -> None:
    with pytest.raises(ValueError, match="Proposition 1"):
        FirstCoordinateRule(eta=-0.1)


# --------------------------------------------------------------------------------------------- ShieldWrapper
class ActionRecorder(gym.Wrapper):
    """Records the actions the wrapped env actually receives."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.received: list[np.ndarray] = []

    def step(self, action: Any) -> Any:
        self.received.append(np.array(action, copy=True))
        return self.env.step(action)


def run_random_episodes(shielded: bool, episodes: int = 20, steps: int = 500) -> tuple[int, int]:
    """Random actions of magnitude 1 on each axis; returns (violations, interventions)."""
    env: gym.Env = gym.make("SafePointCircle-v0")
    if shielded:
        env = ShieldWrapper(env, PointCircleShieldingRule())
    rng = np.random.default_rng(0)
    violations = interventions = 0
    for episode in range(episodes):
        env.reset(seed=episode)
        for _ in range(steps):
            _, _, terminated, truncated, info = env.step(rng.choice([-1.0, 1.0], size=2).astype(np.float32))
            violations += int(info[COST_KEY] > 0)
            interventions += int(info.get(INTERVENED, False))
            if terminated or truncated:
                break
    env.close()
    return violations, interventions


def test_wrapper_random_policy_zero_violations() -> None:
    violations, interventions = run_random_episodes(shielded=True)
    assert violations == 0
    assert interventions > 0
    unshielded_violations, _ = run_random_episodes(shielded=False)
    assert unshielded_violations > 0


def test_wrapper_info_and_executed_action() -> None:
    rule = PointCircleShieldingRule()
    recorder = ActionRecorder(gym.make("SafePointCircle-v0"))
    env = ShieldWrapper(recorder, rule)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(1)
    seen_intervention = seen_free = False
    for _ in range(300):
        proposal = rng.uniform(-1.5, 1.5, size=2).astype(np.float32)  # out of bounds on purpose: clipped first
        prev = obs.astype(np.float64)
        obs, _, terminated, truncated, info = env.step(proposal)
        for key in (INTERVENED, PROPOSED_ACTION_KEY, ADVANTAGE_KEY, COST_KEY):
            assert key in info
        clipped = np.clip(proposal, -1.0, 1.0)
        np.testing.assert_allclose(info[PROPOSED_ACTION_KEY], clipped)
        received = recorder.received[-1]
        assert received.dtype == env.action_space.dtype and env.action_space.contains(received)
        assert info[INTERVENED] == bool(info[ADVANTAGE_KEY] > rule.eta)
        expected = rule.backup_action(prev[None])[0] if info[INTERVENED] else clipped
        np.testing.assert_allclose(received, expected, rtol=1e-6, atol=1e-6)
        seen_intervention |= info[INTERVENED]
        seen_free |= not info[INTERVENED]
        if terminated or truncated:
            obs, _ = env.reset()
    assert seen_intervention and seen_free


def test_wrapper_takeover_gives_the_backup_the_rest_of_the_episode() -> None:
    rule = FirstCoordinateRule(eta=0.5)  # intervenes iff a_0 > 0.5; ζ(s) = 0
    recorder = ActionRecorder(gym.make("SafePointCircle-v0", max_episode_steps=6))
    env = ShieldWrapper(recorder, rule, on_intervention="takeover")
    safe, unsafe = np.array([0.3, 0.3], dtype=np.float32), np.array([0.9, 0.0], dtype=np.float32)
    for _ in range(2):  # the second episode starts with the agent in control again
        env.reset(seed=0)
        flags = [env.step(safe)[4][INTERVENED], env.step(unsafe)[4][INTERVENED]]
        truncated = False
        while not truncated:
            _, _, terminated, truncated, info = env.step(safe)
            assert not terminated
            flags.append(info[INTERVENED])
            np.testing.assert_array_equal(recorder.received[-1], 0.0)  # the backup, though the proposal is allowed
        assert flags == [False, True, True, True, True, True]


def test_wrapper_step_before_reset() -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), PointCircleShieldingRule())
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2, dtype=np.float32))


# --------------------------------------------------------------------------------------------- check_action_space
class BadBackupRule(PointCircleShieldingRule):
    def __init__(self, backup: np.ndarray) -> None:
        super().__init__()
        self._backup = backup

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.tile(self._backup, (len(obs), 1))


def test_backup_out_of_bounds_is_a_clear_error() -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), BadBackupRule(np.array([2.0, 0.0])))
    with pytest.raises(ValueError, match="outside the env's action space"):
        env.reset(seed=0)


def test_backup_wrong_shape_is_a_clear_error() -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), BadBackupRule(np.zeros(3)))
    with pytest.raises(ValueError, match=r"shape \(2, 3\).*return shape \(2, 2\)"):
        env.reset(seed=0)


def test_non_box_action_space_is_rejected() -> None:
    rule = PointCircleShieldingRule()
    with pytest.raises(TypeError, match="Box"):
        rule.check_action_space(gym.spaces.Discrete(3), np.zeros((1, 4)))
    with pytest.raises(TypeError, match="Box"):
        ShieldWrapper(gym.make("CartPole-v1"), rule)


def test_learned_rule_backup_checked_against_the_action_space() -> None:
    obs_space = gym.spaces.Box(-1.0, 1.0, shape=(2,))
    rule = LearnedCostCriticRule(obs_space, gym.spaces.Box(-1.0, 1.0, shape=(1,)), lambda o: 3.0 * np.ones((len(o), 1)))
    with pytest.raises(ValueError, match="outside the env's action space"):
        rule.check_action_space(rule.action_space, np.zeros((1, 2)))


# --------------------------------------------------------------------------------------------- eq. 18
def test_shaped_cost_indicator_when_alpha_is_zero() -> None:
    np.testing.assert_array_equal(shaped_cost(np.array([0.0, 1e-9, 0.1, 3.0]), 0.0), [1.0, 0.0, 0.0, 0.0])


def test_shaped_cost_ramp() -> None:
    dist = np.array([0.0, 0.125, 0.25, 0.5, 0.75, 10.0])
    np.testing.assert_allclose(shaped_cost(dist, 0.5), [1.0, 0.75, 0.5, 0.0, 0.0, 0.0])
    assert float(shaped_cost(0.01, 0.05)) == pytest.approx(0.8)


def test_shaped_cost_negative_alpha() -> None:
    with pytest.raises(ValueError, match="alpha"):
        shaped_cost(0.1, -0.5)


# --------------------------------------------------------------------------------------------- learned rule
GAMMA, ALPHA, DX = 0.99, 0.3, 0.1


def rail_step(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """1-D rail: ``x' = max(x + 0.1·a, -1)``; unsafe iff ``x' > 1`` (absorbing: the episode ends)."""
    return np.maximum(x + DX * np.clip(a, -1.0, 1.0), -1.0)


def rail_shaped_cost(x: np.ndarray) -> np.ndarray:
    return shaped_cost(np.maximum(0.0, 1.0 - x), ALPHA)


def rail_true_q(x: float, a: float) -> float:
    """Fixed point of the clamped backup: ``Q̄(x, a) = min(γ, ĉ(x') + γ·(1 - done)·Q̄(x', ζ))`` with ζ ≡ -1."""
    nxt = float(rail_step(np.array(x), np.array(a)))
    if nxt > 1.0:
        return GAMMA
    if nxt <= 1.0 - ALPHA:  # ĉ(x') = 0, and ζ only moves further from the cliff
        return 0.0
    return min(GAMMA, float(rail_shaped_cost(np.array(nxt))) + GAMMA * rail_true_q(nxt, -1.0))


def fitted_rail_rule() -> LearnedCostCriticRule:
    rng = np.random.default_rng(0)
    n = 20_000
    x, a = rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)
    nxt = rail_step(x, a)
    done = nxt > 1.0
    cost = np.where(done, 1.0, rail_shaped_cost(nxt))
    rule = LearnedCostCriticRule(
        gym.spaces.Box(-1.0, 1.5, shape=(1,)),
        gym.spaces.Box(-1.0, 1.0, shape=(1,)),
        lambda o: -np.ones((len(o), 1)),
        gamma=GAMMA,
        eta=0.05,  # above the fit's error: with η = 0 tiny errors between equally safe actions would be shielded
        tau=0.05,
        seed=0,
    )
    for _ in range(15):
        loss = rule.update(x[:, None], a[:, None], cost, nxt[:, None], done, gradient_steps=100, batch_size=256)
    assert loss < 1e-3
    return rule


@pytest.fixture(scope="module")
def rail_rule() -> LearnedCostCriticRule:
    return fitted_rail_rule()


def test_learned_rule_approaches_the_true_cost_values(rail_rule: LearnedCostCriticRule) -> None:
    xs, acts = (g.ravel() for g in np.meshgrid(np.linspace(-1.0, 1.0, 81), np.linspace(-1.0, 1.0, 21)))
    truth = np.array([rail_true_q(x, a) for x, a in zip(xs, acts)])
    pred = rail_rule.cost_value(xs[:, None], acts[:, None])
    assert np.all((pred >= 0.0) & (pred <= GAMMA))
    err = np.abs(pred - truth)
    assert np.sqrt(np.mean(err**2)) < 0.03, np.sqrt(np.mean(err**2))
    assert err.max() < 0.15, err.max()
    # away from the cliff, moving away costs nothing
    assert pred[(xs < 0.3) & (acts < 0.0)].max() < 0.05


def test_learned_rule_shields_towards_the_cliff(rail_rule: LearnedCostCriticRule) -> None:
    obs = np.array([[0.95], [0.85], [0.0], [-0.5]])
    decision = rail_rule.shield(obs, np.ones((4, 1)))
    np.testing.assert_array_equal(decision.intervened, [True, True, False, False])
    np.testing.assert_array_equal(decision.actions[:2], -1.0)
    assert not rail_rule.shield(obs, rail_rule.backup_action(obs)).intervened.any()  # Proposition 1


def test_learned_rule_stays_in_definition2_range() -> None:
    rule = random_learned_rule(3, 2, seed=7)
    rng = np.random.default_rng(0)
    obs, actions = rng.uniform(-30.0, 30.0, size=(500, 3)), rng.uniform(-20.0, 20.0, size=(500, 2))
    q = rule.cost_value(obs, actions)
    assert 0.0 <= q.min() < 1e-6 and rule.gamma - 1e-6 < q.max() <= rule.gamma  # saturated both ways, never outside
    # before any update the critic is constant (Q̄ ≈ 0.001·γ): Ā ≡ 0, nothing is shielded yet
    fresh = LearnedCostCriticRule(gym.spaces.Box(-1.0, 1.0, (3,)), gym.spaces.Box(-1.0, 1.0, (2,)), lambda o: o[:, :2])
    q_fresh = fresh.cost_value(obs, actions)
    assert np.all(q_fresh == q_fresh[0]) and q_fresh[0] == pytest.approx(1e-3 * fresh.gamma)
    assert not fresh.shield(obs, np.clip(actions, -1.0, 1.0)).intervened.any()


def test_learned_rule_targets_are_capped() -> None:
    """A terminal step with ĉ = 1 is fitted to γ, not 1 (Definition 2)."""
    rule = LearnedCostCriticRule(
        gym.spaces.Box(-1.0, 1.0, (1,)), gym.spaces.Box(-1.0, 1.0, (1,)), lambda o: np.zeros((len(o), 1)), lr=1e-2, seed=0
    )
    obs = np.linspace(-1.0, 1.0, 64)[:, None]
    for _ in range(3):
        rule.update(obs, obs, np.ones(64), obs, np.ones(64), gradient_steps=100)
    np.testing.assert_allclose(rule.cost_value(obs, obs), rule.gamma, atol=0.02)


def test_learned_rule_fits_the_mean_target() -> None:
    """The fit's minimiser is the mean of noisy targets (a proper scoring rule), also next to 0.

    Each state's steps cost 0 or 0.02 at random and end there: Q̄ → 0.01. The critic's own predictions need no clip
    at 0 (Q̄ = γ·σ(f) > 0), so noise in them cannot bias the targets upwards.
    """
    rule = LearnedCostCriticRule(
        gym.spaces.Box(-1.0, 1.0, (1,)), gym.spaces.Box(-1.0, 1.0, (1,)), lambda o: np.zeros((len(o), 1)), lr=1e-2, seed=0
    )
    rng = np.random.default_rng(0)
    obs = np.repeat(np.linspace(-1.0, 1.0, 16), 64)[:, None]
    costs = rng.choice([0.0, 0.02], size=len(obs))
    for _ in range(5):
        rule.update(obs, obs, costs, obs, np.ones(len(obs)), gradient_steps=100, batch_size=256)
    np.testing.assert_allclose(rule.cost_value(obs[::64], obs[::64]), 0.01, atol=0.002)


def test_learned_rule_state_dict_roundtrip(rail_rule: LearnedCostCriticRule) -> None:
    buffer = io.BytesIO()
    th.save(rail_rule.state_dict(), buffer)
    buffer.seek(0)
    clone = LearnedCostCriticRule(
        rail_rule.observation_space, rail_rule.action_space, rail_rule.backup_policy, gamma=GAMMA, tau=0.05, seed=123
    )
    obs, acts = np.linspace(-1.0, 1.0, 50)[:, None], np.linspace(1.0, -1.0, 50)[:, None]
    assert not np.array_equal(clone.cost_value(obs, acts), rail_rule.cost_value(obs, acts))
    clone.load_state_dict(th.load(buffer, weights_only=False))
    np.testing.assert_array_equal(clone.cost_value(obs, acts), rail_rule.cost_value(obs, acts))
    for p, q in zip(clone.critic_target.parameters(), rail_rule.critic_target.parameters()):
        assert th.equal(p, q)


def test_learned_rule_rejects_mismatched_state_and_inputs() -> None:
    small = LearnedCostCriticRule(gym.spaces.Box(-1.0, 1.0, (2,)), gym.spaces.Box(-1.0, 1.0, (1,)), lambda o: o[:, :1])
    other = LearnedCostCriticRule(
        gym.spaces.Box(-1.0, 1.0, (2,)), gym.spaces.Box(-1.0, 1.0, (1,)), lambda o: o[:, :1], net_arch=(32,)
    )
    with pytest.raises(ValueError, match="net_arch"):
        small.load_state_dict(other.state_dict())
    with pytest.raises(ValueError, match="size 2"):
        small.cost_value(np.zeros((3, 5)), np.zeros((3, 1)))
    with pytest.raises(ValueError, match="one length"):
        small.update(np.zeros((3, 2)), np.zeros((2, 1)), np.zeros(3), np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(ValueError, match=">= 0"):
        small.update(np.zeros((3, 2)), np.zeros((3, 1)), -np.ones(3), np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="gamma"):
        LearnedCostCriticRule(gym.spaces.Box(-1.0, 1.0, (2,)), gym.spaces.Box(-1.0, 1.0, (1,)), lambda o: o, gamma=1.0)
    with pytest.raises(TypeError, match="Box"):
        LearnedCostCriticRule(gym.spaces.Discrete(3), gym.spaces.Box(-1.0, 1.0, (1,)), lambda o: o)


# --------------------------------------------------------------------------------------------- registry
ENV_MODULES = ("sppo_sb3.envs.point_circle", "sppo_sb3.envs.half_cheetah_height")


@pytest.mark.parametrize(
    ("env_id", "alpha", "rule_class"),
    [("SafePointCircle-v0", 0.3, PointCircleShieldingRule), ("SafeHalfCheetahHeight-v1", 0.1, HalfCheetahHeightShieldingRule)],
)
def test_auto_rule_is_built_from_the_env_parameters(env_id: str, alpha: float, rule_class: type) -> None:
    """``shield="auto"`` gives the rule of the env made, with its ``alpha`` (it used to take the rule's default)."""
    venv = DummyVecEnv([lambda: gym.make(env_id, alpha=alpha)])
    for shield in ("auto", env_id):
        rule = resolve_shielding_rule(shield, venv, required=True)
        assert isinstance(rule, rule_class) and rule.alpha == alpha
    assert default_shielding_rule(env_id, gym.make(env_id, alpha=alpha)).alpha == alpha  # a gymnasium env too
    assert default_shielding_rule(env_id).alpha == gym.make(env_id).unwrapped.alpha  # no env: the task's default
    # another task's rule named explicitly is not built from this env's parameters
    other = "SafePointCircle-v0" if env_id != "SafePointCircle-v0" else "SafeHalfCheetahHeight-v1"
    assert resolve_shielding_rule(other, venv, required=True).alpha == default_shielding_rule(other).alpha


def test_auto_rule_of_an_algorithm_takes_the_env_alpha() -> None:
    model = SAILR("MlpPolicy", gym.make("SafePointCircle-v0", alpha=0.3), shield="auto", **TINY_ROLLOUT)
    assert isinstance(model.shield_rule, PointCircleShieldingRule) and model.shield_rule.alpha == 0.3


def test_registered_rule_env_parameters() -> None:
    class AlphaRule(FirstCoordinateRule):
        def __init__(self, alpha: float = 1.0) -> None:
            super().__init__()
            self.alpha = alpha

    env_id = "RegistryParams-v0"
    try:
        register_shielding_rule(env_id, AlphaRule, env_parameters=("alpha",))
        env = gym.make("SafePointCircle-v0", alpha=0.25)
        assert default_shielding_rule(env_id, env).alpha == 0.25
        assert default_shielding_rule(env_id).alpha == 1.0
        register_shielding_rule(env_id, AlphaRule)  # re-registered without parameters: called without arguments
        assert default_shielding_rule(env_id, env).alpha == 1.0
        register_shielding_rule(env_id, AlphaRule, env_parameters=("no_such_attribute",))
        with pytest.raises(ValueError, match="'no_such_attribute', which this env lacks"):
            default_shielding_rule(env_id, env)
        with pytest.raises(TypeError, match="sequence of attribute names"):
            register_shielding_rule(env_id, AlphaRule, env_parameters="alpha")
    finally:
        SHIELDING_RULES.pop(env_id, None)
        RULE_ENV_PARAMETERS.pop(env_id, None)


@pytest.mark.parametrize("module", ENV_MODULES)
def test_env_module_alone_loads_no_shield_module(module: str) -> None:
    """Imported and stepped in a fresh interpreter, without the package's ``__init__``, an env loads no shield code."""
    code = f"""
import importlib, importlib.util, sys, types
import gymnasium as gym
package = types.ModuleType("sppo_sb3")
package.__path__ = list(importlib.util.find_spec("sppo_sb3").submodule_search_locations)
sys.modules["sppo_sb3"] = package  # the package's __init__ imports every algorithm, and so the shield
importlib.import_module({module!r})
env_id = "SafePointCircle-v0" if "point" in {module!r} else "SafeHalfCheetahHeight-v1"
env = gym.make(env_id)
env.reset(seed=0)
env.step(env.action_space.sample())
print(" ".join(sorted(name for name in sys.modules if name.startswith("sppo_sb3"))))
"""
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert module in loaded
    assert not [name for name in loaded if name.startswith("sppo_sb3.shield")], loaded


@pytest.mark.parametrize("module", [*ENV_MODULES, "sppo_sb3.shield.tasks.point", "sppo_sb3.shield.tasks.cheetah"])
def test_modules_import_first_in_a_fresh_interpreter(module: str) -> None:
    subprocess.run([sys.executable, "-c", f"import {module}"], check=True)


POINT_RULES = {
    "wall": PointCircleShieldingRule,
    "wall, band 0.5": lambda **kw: PointCircleShieldingRule(alpha=0.5, **kw),
    "paper": paper_point_rule,
}


@pytest.mark.parametrize("name", POINT_RULES)
def test_point_rule_never_shields_by_rounding(name: str) -> None:
    """A proposal that moves ``x`` exactly as braking does (``v_x = 0``, no ``x`` force: a purely tangential action)
    has ``Ā = 0``, right next to the wall; the two ``Q̄`` terms once summed in different orders gave ``Ā ≈ 1e-14 > η = 0``
    and shielded 14–24% of these."""
    rule = POINT_RULES[name]()
    rng = np.random.default_rng(0)
    for x in (2.1, 2.2, 2.3, 2.4):
        n = 200
        obs = np.stack([np.full(n, x), rng.uniform(-4.0, 4.0, n), np.zeros(n), rng.uniform(-2.0, 2.0, n)], axis=1)
        tangential = np.stack([np.zeros(n), rng.uniform(-1.0, 1.0, n)], axis=1)
        decision = rule.shield(obs, tangential)
        assert not decision.intervened.any()
        np.testing.assert_array_equal(decision.advantage, 0.0)
    # the state of the report: coasting with a = (0, 0), Ā was 7e-15
    at_rest_in_x = rule.shield(np.array([[2.3, 0.0, 0.0, 2.0]]), np.zeros((1, 2)))
    assert not at_rest_in_x.intervened[0] and at_rest_in_x.advantage[0] == 0.0
    pushing_out = rule.shield(np.array([[2.4, 0.0, 0.5, 0.0]]), np.array([[1.0, 0.0]]))
    assert pushing_out.intervened[0]


def test_advantage_within_rounding_of_zero_is_zero() -> None:
    """``Ā`` is 0 where its two terms differ by rounding only; a real difference, however small, stays."""
    q = np.array([100.0, 3.0, 0.0, 1e-3, np.nan])
    other = np.array([100.0 + 4e-14, 3.0 - 2e-15, 0.0, 1e-3 + 1e-9, 1.0])
    advantage = advantage_from_values(q, other)
    np.testing.assert_array_equal(advantage[:3], 0.0)
    assert advantage[3] == pytest.approx(-1e-9) and np.isnan(advantage[4])


class SummedBackwards(PointCircleShieldingRule):
    """The Point rule with its batch's halves summed in another order: the backup row's ``Q̄`` differs in the last bits."""

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        q = super().cost_value(obs, actions)
        return q * (1.0 + 3e-16 * (np.arange(len(q)) >= len(q) // 2))


def test_backup_is_never_shielded_whatever_the_summation_order() -> None:
    rule = SummedBackwards()
    obs = sample_safe_states(500, np.random.default_rng(4))
    decision = rule.shield(obs, rule.backup_action(obs))
    assert not decision.intervened.any()
    np.testing.assert_array_equal(decision.advantage, 0.0)


def sample_safe_states(n: int, rng: np.random.Generator) -> np.ndarray:
    """States across the strip and the whole ``y`` range (its limit included), at any speed up to the maximum."""
    speed, angle = rng.uniform(0.0, PARAMS.max_speed, n), rng.uniform(0.0, 2.0 * np.pi, n)
    x, y = rng.uniform(-PARAMS.x_limit, PARAMS.x_limit, n), rng.uniform(-PARAMS.y_limit, PARAMS.y_limit, n)
    return np.stack([x, y, speed * np.cos(angle), speed * np.sin(angle)], axis=1)


def rolled_cost(rule: PointCircleShieldingRule, obs: np.ndarray, actions: np.ndarray, steps: int = 3000) -> np.ndarray:
    """``Q̄`` by brute force: "``a``, then the backup" for ``steps`` steps, every discounted shaped cost summed."""
    state, q, running = point_step(obs, np.clip(actions, -1.0, 1.0), PARAMS), np.zeros(len(obs)), np.ones(len(obs), bool)
    for t in range(steps):
        unsafe = point_is_unsafe(state, PARAMS)
        cost = shaped_cost(point_distance_to_unsafe(state, PARAMS), rule.alpha)
        q += running * rule.gamma ** (t + 1) * np.where(unsafe, 1.0 / (1.0 - rule.gamma), cost)
        running &= ~unsafe
        state = point_step(state, rule.backup_action(state), PARAMS)
    return q


@pytest.mark.parametrize("name", POINT_RULES)
def test_point_q_is_the_backups_discounted_cost(name: str) -> None:
    """``Q̄`` with its fixed horizon, tail and settling equals the brute-force sum over 3000 steps (γ^3000 ≈ 1e-13)."""
    rule = POINT_RULES[name]()
    rng = np.random.default_rng(5)
    obs, actions = sample_safe_states(3000, rng), rng.uniform(-1.0, 1.0, (3000, 2))
    np.testing.assert_allclose(rule.cost_value(obs, actions), rolled_cost(rule, obs, actions), rtol=0, atol=1e-9)


def test_wall_backup_brakes_x_and_keeps_y_unless_near_its_limit() -> None:
    wall, paper = PointCircleShieldingRule(), paper_point_rule()
    obs = np.array([[2.0, 1.0, 1.0, 2.0], [0.0, 14.0, 0.0, 1.5], [0.0, -14.0, 0.0, 1.5]])
    np.testing.assert_array_equal(wall.backup_action(obs), [[-1.0, 0.0], [0.0, -1.0], [0.0, -1.0]])
    np.testing.assert_array_equal(paper.backup_action(obs), [[-1.0, -1.0], [0.0, -1.0], [0.0, -1.0]])
    # from outside its y zone, the wall backup stops x and never lets y reach its band
    banded = PointCircleShieldingRule(alpha=0.5)
    states = sample_safe_states(2000, np.random.default_rng(6))
    outside = np.abs(states[:, 1]) < banded.y_zone
    furthest_y = np.abs(states[:, 1])
    for _ in range(400):
        states = point_step(states, banded.backup_action(states), PARAMS)
        furthest_y = np.maximum(furthest_y, np.abs(states[:, 1]))
    assert np.all(np.abs(states[:, 2]) < 1e-9)
    assert furthest_y[outside].max() <= PARAMS.y_limit - banded.alpha
    assert furthest_y[outside].max() > banded.y_zone  # some rows ran into the zone and were braked there
    with pytest.raises(ValueError, match="backup"):
        PointCircleShieldingRule(backup="stop")


def test_the_papers_point_rule_is_registered_by_name() -> None:
    venv = DummyVecEnv([lambda: gym.make("SafePointCircle-v0")])
    rule = resolve_shielding_rule(PAPER_POINT_RULE, venv, required=True)
    assert isinstance(rule, PointCircleShieldingRule) and (rule.alpha, rule.backup) == (0.5, "sailr")
    default = resolve_shielding_rule("auto", venv, required=True)
    assert (default.alpha, default.backup) == (0.05, "wall")
    # the paper's band: coasting at 1.0 from 1.8 would stop inside it (2.4 > 2.0), the default rule lets it coast
    coasting = (np.array([[1.8, 0.0, 1.0, 0.0]]), np.zeros((1, 2)))
    assert rule.shield(*coasting).intervened[0] and not default.shield(*coasting).intervened[0]


def test_scripted_lap_runs_along_the_wall_under_the_default_rule() -> None:
    """The return ceiling (docs/results.md): the lap at |x| = 2.4 is never overridden by the default rule (band 0.05),
    scores what it scores unshielded and within 5% of the best unshielded lap (at 2.48); the paper's rule never lets
    it past the band's edge, |x| = 2.0, and overrides nearly every step."""
    best_unshielded = run_scripted_lap(2.48)
    assert not best_unshielded.violated and best_unshielded.max_abs_x > 2.48
    shielded, unshielded = run_scripted_lap(2.4, PointCircleShieldingRule()), run_scripted_lap(2.4)
    assert shielded == unshielded and shielded.interventions == 0 and shielded.max_abs_x > 2.4
    assert shielded.episode_return >= 0.95 * best_unshielded.episode_return
    paper = run_scripted_lap(2.4, paper_point_rule())
    assert paper.max_abs_x <= 2.0 and paper.interventions > 400 and paper.episode_return < 0.1 * unshielded.episode_return


def test_shield_wrapper_takes_a_registered_rules_name() -> None:
    assert ShieldWrapper(gym.make("SafePointCircle-v0", alpha=0.2), "auto").rule.alpha == 0.2  # the env's own rule
    assert ShieldWrapper(gym.make("SafePointCircle-v0"), PAPER_POINT_RULE).rule.backup == "sailr"
    with pytest.raises(ValueError, match="No shielding rule is registered for env id 'Pendulum-v1'"):
        ShieldWrapper(gym.make("Pendulum-v1"), "auto")
    with pytest.raises(TypeError, match="not None"):
        ShieldWrapper(gym.make("SafePointCircle-v0"), None)  # type: ignore[arg-type]


def test_deployment_shields_a_model_trained_behind_the_wrapper() -> None:
    """A model shielded by ``ShieldWrapper`` (no rule of its own) is deployed with its training envs' rule."""
    venv = DummyVecEnv([lambda: ShieldWrapper(gym.make("SafePointCircle-v0"), "auto")])
    model = PDO("MlpPolicy", venv, **TINY_ROLLOUT)
    assert deployment_rule(model) is venv.envs[0].rule
    model.predict = lambda *args, **kwargs: (np.array([1.0, 0.0], dtype=np.float32), None)  # into the wall
    make = lambda: gym.make("SafePointCircle-v0", max_episode_steps=60)  # noqa: E731
    shielded = evaluate_deployment(model, make, n_eval_episodes=1, shielded=True)
    unshielded = evaluate_deployment(model, make, n_eval_episodes=1, shielded=False)
    assert shielded["mean_violations"] == 0.0 and shielded["mean_interventions"] > 0
    assert unshielded["mean_violations"] == 1.0
