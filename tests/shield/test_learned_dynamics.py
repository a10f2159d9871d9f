"""LearnedDynamicsRule: Q̄ rolled on dynamics learned from B, the task's constraint and backup known."""

from __future__ import annotations

import io
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from test_quality import point_pairs
from tiny_hyperparams import TINIEST_TOLD

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_lab.learned_shield import held_action_walk
from sppo_sb3 import SPPO
from sppo_sb3.envs.point_circle import PointParams, point_distance_to_unsafe, point_is_unsafe
from sppo_sb3.shield import LearnedDynamicsRule, PointCircleShieldingRule
from sppo_sb3.shield.analysis import quality
from sppo_sb3.shield.registry import LEARNED_POINT_RULE

PARAMS = PointParams()
REFERENCE = PointCircleShieldingRule()


def point_dynamics_rule(seed: int = 0, **kwargs: object) -> LearnedDynamicsRule:
    """A learned rule with the Point rule's backup, constraint and band (its model still to learn)."""
    env = gym.make("SafePointCircle-v0")
    return LearnedDynamicsRule(
        env.observation_space,
        env.action_space,
        REFERENCE.backup_action,
        lambda obs: point_is_unsafe(obs, PARAMS),
        lambda obs: point_distance_to_unsafe(obs, PARAMS),
        **{"alpha": REFERENCE.alpha, "horizon": REFERENCE.horizon + 10, "seed": seed, **kwargs},  # type: ignore[arg-type]
    )


@pytest.fixture(scope="module")
def fitted_rule() -> LearnedDynamicsRule:
    """Fitted on what a warm-up holds: 3000 uniform steps, a quarter of them braking (2 violations), 1000 minibatches."""
    walk = held_action_walk(3000, 0, 1, 0.25, REFERENCE)
    rule = point_dynamics_rule()
    for _ in range(10):
        rule.update(walk.obs, walk.actions, walk.next_obs, 100, 256)
    return rule


def test_a_learned_model_decides_like_the_point_model_rule(fitted_rule: LearnedDynamicsRule) -> None:
    """On held-out pairs near the wall, the measured margins: agreement 0.967, AUC 1.000, MAE 0.014 (Q̄ ≡ 0: 0.179)."""
    obs, actions = point_pairs(3000, 10)
    reference_q, shielded = REFERENCE.definition2_value(obs, actions), quality.shielded_pairs(REFERENCE, obs, actions)
    violates = quality.violation_labels(REFERENCE.band_free(), obs, actions)
    scores = quality.rule_scores(fitted_rule, obs, actions, reference_q, shielded, violates)
    zero = quality.zero_scores(reference_q, shielded, violates)
    assert scores.agreement >= 0.93 and scores.agreement > zero.agreement + 0.05
    assert scores.auc >= 0.97
    assert scores.mae < 0.3 * zero.mae
    np.testing.assert_allclose(fitted_rule.predict_next(obs, actions)[:, :2], obs[:, :2] + 0.1 * obs[:, 2:], atol=0.05)


def test_the_backup_is_never_shielded_and_an_untrained_model_shields_nothing(fitted_rule: LearnedDynamicsRule) -> None:
    obs, actions = point_pairs(500, 11)
    assert not fitted_rule.shield(obs, fitted_rule.backup_action(obs)).intervened.any()  # Proposition 1
    fresh = point_dynamics_rule()
    np.testing.assert_array_equal(fresh.predict_next(obs, actions), obs)  # no change predicted before learning
    assert not fresh.shield(obs, actions).intervened.any()


def test_state_dict_roundtrip(fitted_rule: LearnedDynamicsRule) -> None:
    buffer = io.BytesIO()
    th.save(fitted_rule.state_dict(), buffer)
    buffer.seek(0)
    clone = point_dynamics_rule(seed=1)
    obs, actions = point_pairs(50, 12)
    clone.load_state_dict(th.load(buffer, weights_only=False))
    np.testing.assert_array_equal(clone.cost_value(obs, actions), fitted_rule.cost_value(obs, actions))
    with pytest.raises(ValueError, match="same spaces and net_arch"):
        point_dynamics_rule(net_arch=(8,)).load_state_dict(fitted_rule.state_dict())


def test_bad_constraints_and_settings_are_refused() -> None:
    with pytest.raises(TypeError, match="is_unsafe must be a callable"):
        LearnedDynamicsRule(*_spaces(), REFERENCE.backup_action, "x<2.5", np.abs, alpha=0.1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="alpha"):
        point_dynamics_rule(alpha=-1.0)
    with pytest.raises(ValueError, match="horizon"):
        point_dynamics_rule(horizon=0)
    with pytest.raises(ValueError, match="observations of size 4"):
        point_dynamics_rule().cost_value(np.zeros((2, 3)), np.zeros((2, 2)))


def _spaces() -> tuple[gym.spaces.Space, gym.spaces.Space]:
    env = gym.make("SafePointCircle-v0")
    return env.observation_space, env.action_space


def test_sppo_refines_a_learned_model_on_its_buffer_and_keeps_it_on_save(tmp_path: Path) -> None:
    """By name (the registered Point variant), fitted on B while SPPO trains, saved and loaded with the model."""
    model = SPPO(
        "TOLDPolicy", "SafePointCircle-v0", shield=LEARNED_POINT_RULE, refine_shield=True, learning_starts=300,
        policy_kwargs=TINIEST_TOLD, horizon=2, compile=False, seed=0,
    )  # fmt: skip
    rule = model.shield_rule
    assert isinstance(rule, LearnedDynamicsRule) and rule.alpha == REFERENCE.alpha
    obs, actions = point_pairs(200, 13)
    before = rule.predict_next(obs, actions)
    model.learn(400)
    assert not np.array_equal(rule.predict_next(obs, actions), before)
    assert "train/shield_loss" in model.logger.name_to_value
    model.save(tmp_path / "sppo")
    loaded = SPPO.load(tmp_path / "sppo")
    assert isinstance(loaded.shield_rule, LearnedDynamicsRule)
    np.testing.assert_array_equal(loaded.shield_rule.cost_value(obs, actions), rule.cost_value(obs, actions))
