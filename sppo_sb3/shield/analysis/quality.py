"""How well a shielding rule knows where the danger is, measured against a model-based reference rule.

A learned ``Q̄`` is judged as a shield uses it, on the same pairs ``(s, a)`` as the reference:

- ``mae``: mean absolute error of ``Q̄`` on Definition 2's scale (:meth:`~sppo_sb3.shield.ShieldingRule.definition2_value`);
  ``max_error``: the largest, an estimate of Proposition 2.3's ``δ = ‖Q̂ - Q̄‖_∞`` on the pairs scored (a rule that is
  ``β``-adoptable on the reference's ``Q̄`` keeps ``(β + (1 + γ)δ)``-adoptability with the learned one);
- ``agreement``: the share of pairs that the two rules shield alike (eq. 12); ``recall``: the share of the pairs the
  reference shields that the rule shields too; ``false_shields``: the share of the pairs the reference lets through
  that the rule shields;
- ``auc``: the ROC AUC of ``Q̄`` for "``a``, then ``ζ``, enters the unsafe set" (the reference rule without a band,
  :func:`violation_labels`): the chance that a random violating pair scores above a random safe one.

Trivial references put these in scale (:func:`zero_scores`, :func:`distance_scores`): a rule that predicts 0
everywhere never shields, so its agreement is the share of pairs the reference lets through.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from sppo_sb3.shield.base import ShieldingRule

#: quantile bins of :func:`distance_scores`' mean ``Q̄`` per distance
DISTANCE_BINS = 20


@dataclass(frozen=True)
class ShieldScores:
    """One predictor's scores against the reference (see the module docstring)."""

    mae: float
    max_error: float
    agreement: float
    recall: float
    false_shields: float
    auc: float

    def as_dict(self) -> dict[str, float]:
        """The scores by name."""
        return asdict(self)


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """ROC AUC of ``scores`` for the boolean ``labels`` (Mann–Whitney, ties count half); NaN with one class only."""
    scores, labels = np.asarray(scores, dtype=np.float64), np.asarray(labels, dtype=bool)
    positives, negatives = int(labels.sum()), int((~labels).sum())
    if positives == 0 or negatives == 0:
        return float("nan")
    order = np.argsort(scores, kind="mergesort")
    ranks = np.empty(len(scores))
    sorted_scores = scores[order]
    # average ranks over ties
    starts = np.r_[0, np.flatnonzero(np.diff(sorted_scores)) + 1]
    ends = np.r_[starts[1:], len(scores)]
    for start, end in zip(starts, ends):
        ranks[order[start:end]] = (start + end + 1) / 2.0
    return float((ranks[labels].sum() - positives * (positives + 1) / 2.0) / (positives * negatives))


def violation_labels(band_free_reference: ShieldingRule, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Whether "``a``, then ``ζ``" enters the unsafe set, from a model-based rule whose band ``α`` is 0.

    With ``α = 0`` the shaped cost of eq. 18 is the indicator of the unsafe set, so the rule's ``Q̄`` is positive
    exactly where its rollout enters it.

    :param band_free_reference: the reference rule built with ``alpha=0`` (its backup must be the evaluated rule's).
    :param obs: ``(N, obs_dim)`` observations.
    :param actions: ``(N, act_dim)`` actions in env units.
    """
    return band_free_reference.definition2_value(obs, actions) > 0.0


def shielded_pairs(rule: ShieldingRule, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Where eq. 12 shields ``a`` in ``s``: the rule's own decisions (``Ā > η``), without executing anything."""
    return rule.shield(np.asarray(obs, dtype=np.float64), np.asarray(actions, dtype=np.float64)).intervened


def scores_from_predictions(
    q: np.ndarray, shielded: np.ndarray, reference_q: np.ndarray, reference_shielded: np.ndarray, violates: np.ndarray
) -> ShieldScores:
    """:class:`ShieldScores` of a predictor's ``Q̄`` (Definition 2's scale) and decisions against the reference's.

    :param q: the predictor's ``Q̄`` of each pair.
    :param shielded: the predictor's decisions.
    :param reference_q: the reference's ``Q̄``.
    :param reference_shielded: the reference's decisions.
    :param violates: :func:`violation_labels` of the pairs.
    """
    shielded, reference_shielded = np.asarray(shielded, dtype=bool), np.asarray(reference_shielded, dtype=bool)
    recall = float(shielded[reference_shielded].mean()) if reference_shielded.any() else float("nan")
    false_shields = float(shielded[~reference_shielded].mean()) if (~reference_shielded).any() else float("nan")
    errors = np.abs(np.asarray(q) - reference_q)
    return ShieldScores(
        mae=float(errors.mean()),
        max_error=float(errors.max()),
        agreement=float((shielded == reference_shielded).mean()),
        recall=recall,
        false_shields=false_shields,
        auc=roc_auc(q, violates),
    )


def rule_scores(
    rule: ShieldingRule,
    obs: np.ndarray,
    actions: np.ndarray,
    reference_q: np.ndarray,
    reference_shielded: np.ndarray,
    violates: np.ndarray,
) -> ShieldScores:
    """:class:`ShieldScores` of a rule on the pairs ``(obs, actions)`` (see :func:`scores_from_predictions`)."""
    q = rule.definition2_value(obs, actions)
    return scores_from_predictions(q, shielded_pairs(rule, obs, actions), reference_q, reference_shielded, violates)


def zero_scores(reference_q: np.ndarray, reference_shielded: np.ndarray, violates: np.ndarray) -> ShieldScores:
    """The scores of ``Q̄ ≡ 0``: it never shields, and ranks nothing (AUC 0.5)."""
    never = np.zeros(len(reference_q), dtype=bool)
    return scores_from_predictions(np.zeros(len(reference_q)), never, reference_q, reference_shielded, violates)


def distance_scores(
    distances: np.ndarray,
    reference_q: np.ndarray,
    reference_shielded: np.ndarray,
    violates: np.ndarray,
    fit_distances: np.ndarray,
    fit_q: np.ndarray,
) -> ShieldScores:
    """The scores of ``Q̄`` predicted from the distance of ``s`` to the unsafe set alone.

    ``Q̄`` is the reference's mean over the pairs of a fitting set whose distance falls in the same of
    :data:`DISTANCE_BINS` quantile bins (the best such predictor on that set). It cannot tell two actions in one state
    apart, so ``Ā ≡ 0`` and it never shields, as ``Q̄ ≡ 0``; its AUC is the ranking by distance alone.

    :param distances: distance of each evaluated pair's state to the unsafe set.
    :param reference_q: the reference's ``Q̄`` of the evaluated pairs.
    :param reference_shielded: the reference's decisions.
    :param violates: :func:`violation_labels` of the evaluated pairs.
    :param fit_distances: distances of the fitting pairs (others than the evaluated ones).
    :param fit_q: the reference's ``Q̄`` of the fitting pairs.
    """
    edges = np.unique(np.quantile(fit_distances, np.linspace(0.0, 1.0, DISTANCE_BINS + 1)))
    fit_bins = np.clip(np.searchsorted(edges, fit_distances, side="right") - 1, 0, len(edges) - 2)
    means = np.array([np.median(fit_q[fit_bins == b]) if (fit_bins == b).any() else 0.0 for b in range(len(edges) - 1)])
    bins = np.clip(np.searchsorted(edges, distances, side="right") - 1, 0, len(edges) - 2)
    never = np.zeros(len(reference_q), dtype=bool)
    scores = scores_from_predictions(means[bins], never, reference_q, reference_shielded, violates)
    return replace(scores, auc=roc_auc(-np.asarray(distances, dtype=np.float64), violates))
