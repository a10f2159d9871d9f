"""The paper's safety guarantees, instantiated: ``β`` of Definition 2 and the bound of Theorem 1, on ``Q̄ ∈ [0, γ]``.

Definition 2: a rule is β-adoptable if for all safe ``s`` and all ``a``,
``Q̄(s, a) + β >= c(s, a) + γ E[Q̄(s', ζ)]`` with ``c(s, a) = 1{s = s▷}`` (0 on safe states).
Theorem 1: the shielded planning policy ``π'`` then has ``V̄^π' <= Q̄^ζ + min{β + η, 2γ} / (1 - γ)``, where ``V̄``
is the expected discounted violation, ``E[γ^T]`` for a first violation at step ``T`` (0 without one), and ``Q̄^ζ``
the backup's value at the start state. Everything here is on Definition 2's scale
(:meth:`~sppo_sb3.shield.base.ShieldingRule.definition2_value`).

What the guarantees assume: ``S_unsafe`` absorbing with reward 0 (the tasks terminate there), a rule that is
β-adoptable *on the states the agent visits* — :func:`adoptability_gap` measures ``β`` on sampled transitions of the
true dynamics, so it is an estimate from below of the supremum — and, for the bound, the known start state(s).
"""

from __future__ import annotations

import numpy as np

from sppo_sb3.shield.base import ShieldingRule


def adoptability_gap(
    rule: ShieldingRule, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray, next_unsafe: np.ndarray
) -> float:
    """The smallest ``β >= 0`` for which Definition 2's inequality (eq. 6) holds on the given transitions.

    ``β = max(0, max_i [γ Q̄(s'_i, ζ(s'_i)) - Q̄(s_i, a_i)])`` over transitions from safe states ``s_i`` (where
    ``c(s_i, a_i) = 0``); a transition into the unsafe set contributes ``γ · γ`` (``Q̄ = γ`` there: the violation is
    the next step of any continuation).

    :param rule: the shielding rule.
    :param obs: ``(B, obs_dim)`` safe states ``s``.
    :param actions: ``(B, act_dim)`` actions ``a`` in env units.
    :param next_obs: ``(B, obs_dim)`` next states ``s'`` of the true dynamics.
    :param next_unsafe: ``(B,)`` whether ``s'`` is in the unsafe set.
    """
    gamma = rule.discount
    q = rule.definition2_value(obs, actions)
    next_q = rule.definition2_value(next_obs, rule.checked_backup(np.asarray(next_obs, dtype=np.float64), actions.shape[1]))
    next_q = np.where(np.asarray(next_unsafe, dtype=bool), gamma, next_q)
    return float(max(0.0, np.max(gamma * next_q - q)))


def theorem1_bound(backup_value: float, beta: float, eta: float, gamma: float) -> float:
    """Theorem 1: ``V̄^π' <= Q̄^ζ + min{β + η, 2γ} / (1 - γ)`` (all on Definition 2's scale).

    :param backup_value: ``Q̄^ζ`` at the start state (:meth:`ShieldingRule.definition2_value` of ``(s_0, ζ(s_0))``).
    :param beta: ``β`` of Definition 2 (:func:`adoptability_gap`).
    :param eta: the shield's ``η`` on Definition 2's scale (:attr:`ShieldingRule.definition2_eta`).
    :param gamma: discount.
    """
    return backup_value + min(beta + eta, 2.0 * gamma) / (1.0 - gamma)


def discounted_violation(violation_steps: list[int | None], gamma: float) -> float:
    """The measured ``V̄``: the mean over episodes of ``γ^T`` for a first violation at step ``T >= 1`` (0 if none).

    :param violation_steps: per episode, the 1-based step of its first violation, or None.
    """
    return float(np.mean([0.0 if t is None else gamma**t for t in violation_steps]))
