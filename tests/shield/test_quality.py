"""The measures of how well a rule knows where the danger is (``sppo_sb3.shield.analysis.quality``), on the Point model."""

from __future__ import annotations

import numpy as np
import pytest

from sppo_sb3.envs.point_circle import PointParams, point_distance_to_unsafe, point_is_unsafe, point_step
from sppo_sb3.shield import PointCircleShieldingRule
from sppo_sb3.shield.analysis import quality

PARAMS = PointParams()


def brute_force_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """The share of (positive, negative) pairs the scores order right, ties counting half."""
    pos, neg = scores[labels], scores[~labels]
    wins = (pos[:, None] > neg[None, :]).sum() + 0.5 * (pos[:, None] == neg[None, :]).sum()
    return float(wins / (len(pos) * len(neg)))


def test_roc_auc_is_the_share_of_pairs_ranked_right() -> None:
    rng = np.random.default_rng(0)
    labels = rng.random(300) < 0.2
    for scores in (rng.normal(size=300) + labels, rng.integers(0, 4, 300).astype(float)):  # ties in the second
        assert quality.roc_auc(scores, labels) == pytest.approx(brute_force_auc(scores, labels), abs=1e-12)
    assert quality.roc_auc(labels.astype(float), labels) == 1.0 and quality.roc_auc(-labels.astype(float), labels) == 0.0
    assert np.isnan(quality.roc_auc(np.ones(3), np.ones(3, dtype=bool)))


def point_pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """States near the wall, at any speed, and uniform actions: about a tenth of them lead to a violation."""
    rng = np.random.default_rng(seed)
    speed, angle = rng.uniform(0.0, PARAMS.max_speed, n), rng.uniform(0.0, 2.0 * np.pi, n)
    x, y = rng.uniform(1.5, PARAMS.x_limit, n) * rng.choice([-1.0, 1.0], n), rng.uniform(-5.0, 5.0, n)
    return np.stack([x, y, speed * np.cos(angle), speed * np.sin(angle)], axis=1), rng.uniform(-1.0, 1.0, (n, 2))


def test_violation_labels_are_where_a_then_the_backup_enters_the_unsafe_set() -> None:
    rule = PointCircleShieldingRule()
    obs, actions = point_pairs(2000, 1)
    labels = quality.violation_labels(rule.band_free(), obs, actions)
    state, unsafe = point_step(obs, actions, PARAMS), np.zeros(len(obs), dtype=bool)
    for _ in range(300):  # the backup brings x to rest well within this
        unsafe |= point_is_unsafe(state, PARAMS)
        state = point_step(state, rule.backup_action(state), PARAMS)
    np.testing.assert_array_equal(labels, unsafe)
    assert 0.02 < labels.mean() < 0.5
    assert rule.alpha == 0.05 and np.array_equal(rule.band_free().backup_action(obs), rule.backup_action(obs))


def test_the_reference_scores_itself_perfectly_and_the_trivial_predictors_as_documented() -> None:
    rule = PointCircleShieldingRule()
    obs, actions = point_pairs(3000, 2)
    q, shielded = rule.definition2_value(obs, actions), quality.shielded_pairs(rule, obs, actions)
    violates = quality.violation_labels(rule.band_free(), obs, actions)
    own = quality.rule_scores(rule, obs, actions, q, shielded, violates)
    assert (own.mae, own.max_error, own.agreement, own.recall, own.false_shields) == (0.0, 0.0, 1.0, 1.0, 0.0)
    assert own.auc > 0.99  # its Q̄ adds the band's cost to the violation's: nearly, not exactly, a ranking by it
    zero = quality.zero_scores(q, shielded, violates)
    assert zero.mae == pytest.approx(q.mean()) and zero.agreement == pytest.approx(1.0 - shielded.mean())
    assert zero.max_error == q.max()  # δ of Proposition 2.3 on these pairs
    assert (zero.recall, zero.false_shields, zero.auc) == (0.0, 0.0, 0.5)
    fit_obs, fit_actions = point_pairs(3000, 3)
    distance = quality.distance_scores(
        point_distance_to_unsafe(obs, PARAMS),
        q,
        shielded,
        violates,
        point_distance_to_unsafe(fit_obs, PARAMS),
        rule.definition2_value(fit_obs, fit_actions),
    )
    assert distance.agreement == zero.agreement and distance.recall == 0.0  # it never shields
    assert 0.5 < distance.auc < own.auc  # closer is more dangerous, but speed and action matter too


def test_the_learned_shield_script_prints_every_predictors_scores(capsys: pytest.CaptureFixture[str]) -> None:
    from sppo_lab import learned_shield

    argv = ["--warmup-steps", "300", "--steps", "400", "--gradient-steps", "100", "--model-steps", "100", "--seeds", "1"]
    assert learned_shield.main([*argv, "--training-steps", "500", "--latent", "untrained"]) == 0
    out = capsys.readouterr().out
    assert "Scored on 3000 held-out pairs of a held-action walk" in out
    assert "Scored on 500 pairs of a shielded SPPO run of 500 steps" in out  # every pair of a run that short
    rows = ("| learned model, warm-up data |", "| critic, warm-up data |", "| critic, held-action walk |", "| Q̄ ≡ 0 |")
    for row in (
        *rows,
        "| latent model, held-action walk |",
        "| distance alone |",
        *(f"| {eta} |" for eta in learned_shield.ETAS),
    ):
        assert row in out
    assert out.count("Mean Ā on the pairs the model rule shields") == 2  # under both tables
    model_row = next(line for line in out.splitlines() if line.startswith("| model rule |"))
    assert model_row.endswith("| 1.000 |")  # the model rule shields every pair it shields
    walk = learned_shield.held_action_walk(300, 0, 20, 1.0, PointCircleShieldingRule())
    np.testing.assert_array_equal(walk.actions, PointCircleShieldingRule().backup_action(walk.obs))  # all backup
    assert walk.violations == 0 and not walk.dones.any()  # the backup alone never violates


def test_a_training_runs_pairs_are_what_the_recording_rule_was_asked_to_shield() -> None:
    from sppo_lab.recording import RecordingRule

    rule, recording = PointCircleShieldingRule(), RecordingRule(PointCircleShieldingRule())
    batches = [point_pairs(n, seed) for n, seed in ((3, 4), (5, 5))]
    for obs, actions in batches:
        decided = recording.shield(obs, actions)
        np.testing.assert_array_equal(decided.actions, rule.shield(obs, actions).actions)  # the inner rule decides
    obs, actions = recording.pairs()
    np.testing.assert_array_equal(obs, np.concatenate([b[0] for b in batches]))
    np.testing.assert_array_equal(actions, np.concatenate([b[1] for b in batches]))
