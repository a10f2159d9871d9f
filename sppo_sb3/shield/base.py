"""The advantage-based shielding rule ``G = (Q̄, ζ, Ā, η, I)`` of Section III-B, on batches.

A rule answers two questions on a batch of raw (un-normalised) observations:

- ``cost_value(obs, actions)``: ``Q̄(s, a)``, the discounted (shaped) cost of taking ``a`` in ``s`` and following the
  backup policy ``ζ`` afterwards;
- ``backup_action(obs)``: the backup policy's action ``ζ(s)``, in the env's action units.

Everything else — the advantage ``Ā``, the shielding set ``I`` and the shielded action of eqs. 5/12 — follows here,
once, for every algorithm of the package. Subclass :class:`ShieldingRule` to bring your own task.

The shield fails closed: a state, proposal or ``Q̄`` it cannot evaluate (NaN, inf) is treated as unsafe and the
backup action is executed; where the backup action itself is not finite, :class:`ShieldFailure` is raised. The
proposal is never executed on a value the rule could not compute.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import gymnasium as gym
import numpy as np


class ShieldFailure(ValueError):
    """The shield could not compute a safe action: the backup action ``ζ(s)`` itself is not finite."""


@dataclass
class ShieldDecision:
    """Outcome of shielding a batch of proposed actions (eq. 12).

    :param actions: the executed actions ``a_safe`` (proposed where allowed, backup where shielded).
    :param intervened: ``True`` where ``(s, a) ∈ I`` and the backup action replaced the proposal.
    :param advantage: ``Ā(s, a)`` of each proposal (NaN where it could not be computed).
    :param edited: where the proposal was replaced by an *edit*, an action near it that the rule accepted, instead of
        the backup's (a permissive rule's; ``None``: no edits, every replacement is the backup's).
    """

    actions: np.ndarray
    intervened: np.ndarray
    advantage: np.ndarray
    edited: np.ndarray | None = None

    @property
    def edits(self) -> np.ndarray:
        """Where the executed action is an edit (all ``False`` for a rule without edits)."""
        return np.zeros(len(self.intervened), dtype=bool) if self.edited is None else np.asarray(self.edited, dtype=bool)


#: relative tolerance of ``Ā`` on the scale of its two ``Q̄`` terms: a difference within it is rounding (two sums of
#: the same costs in other orders), so ``Ā`` is 0 there and the action is not shielded. It widens ``η`` by at most
#: ``2 · ADVANTAGE_RTOL · max Q̄`` (2e-10 on the shaped scale's ``[0, γ / (1 - γ)]``), far below any cost that matters.
ADVANTAGE_RTOL = 1e-12


def advantage_from_values(q_action: np.ndarray, q_backup: np.ndarray) -> np.ndarray:
    """``Ā = Q̄(s, a) - Q̄(s, ζ(s))``, exactly 0 where the two agree up to rounding (:data:`ADVANTAGE_RTOL`); NaN stays."""
    advantage = q_action - q_backup
    rounding = np.abs(advantage) <= ADVANTAGE_RTOL * (np.abs(q_action) + np.abs(q_backup))
    return np.where(rounding, 0.0, advantage)


def in_shielding_set(advantage: np.ndarray, eta: float) -> np.ndarray:
    """Membership test of the shielding set: ``(s, a) ∈ I  ⇔  Ā(s, a) > η`` (Section III-B, used by eq. 12).

    A non-finite advantage (NaN, ±inf: a ``Q̄`` the rule could not compute) counts as inside ``I``: fail closed.
    """
    advantage = np.asarray(advantage)
    return ~np.isfinite(advantage) | (advantage > eta)


def finite_rows(array: np.ndarray) -> np.ndarray:
    """``True`` for the rows of a ``(B, ...)`` array whose entries are all finite."""
    return np.isfinite(array.reshape(len(array), -1)).all(axis=1)


ShieldMethod = Callable[[Any, np.ndarray, np.ndarray], ShieldDecision]


def fails_closed(shield: ShieldMethod) -> ShieldMethod:
    """Guard a ``shield`` method so that no value it could not compute lets a proposal through (eq. 12, fail closed).

    After ``shield`` decides, every row whose observation, proposal or advantage is not finite is shielded; the
    executed action of every shielded row must be finite, else :class:`ShieldFailure` is raised. Applied to
    :meth:`ShieldingRule.shield` and, automatically, to every subclass that overrides it.
    """

    @functools.wraps(shield)
    def guarded(rule: ShieldingRule, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        actions = np.asarray(actions, dtype=np.float64).reshape(len(obs), -1)
        decision = shield(rule, obs, actions)
        return rule.close_failures(obs, actions, decision)

    guarded.fails_closed = True  # type: ignore[attr-defined]
    return guarded


class ShieldingRule(ABC):
    """Advantage-based shielding rule ``G = (Q̄, ζ, Ā, η, I)`` (Section III-B).

    With ``η >= 0`` the backup action is never shielded (Proposition 1), so the shielded policy always has an
    admissible action. The shield fails closed (see the module docstring); a subclass that overrides :meth:`shield`
    keeps that guarantee (:func:`fails_closed` wraps the override).

    The contract of a subclass: :meth:`cost_value` returns a float array of shape ``(B,)``, :meth:`backup_action` a
    float array of shape ``(B, act_dim)`` inside the action space, both from raw observations ``(B, obs_dim)`` and
    actions in the env's units. Outputs of another shape are rejected with a message that names the fix.

    **Two scales of** ``Q̄`` (:attr:`value_scale`). The built-in model-based rules return the discounted *shaped*
    cost of eq. 18 along "``a``, then ``ζ``", with the absorbing tail ``γ^(t+1) / (1 - γ)`` where the roll enters the
    unsafe set (``ĉ = 1`` forever there): values in ``[0, γ / (1 - γ)]``, so a violation is worth about
    ``1 / (1 - γ)`` and ``η`` is measured in those units. Definition 2 takes ``Q̄ ∈ [0, γ]``, where a violation ``T``
    steps ahead is worth ``γ^T``: :meth:`definition2_value` is ``(1 - γ)`` times the shaped value, and
    :attr:`definition2_eta` ``= (1 - γ) η`` the same threshold on that scale — scaling both sides of ``Ā > η`` by
    ``1 - γ`` leaves every decision unchanged. Theorem 1's bound (:mod:`sppo_sb3.shield.analysis.bounds`) is stated on
    Definition 2's scale. A learned critic (:class:`~sppo_sb3.shield.learned.critic.LearnedCostCriticRule`) is fitted on
    that scale directly.

    :param eta: advantage threshold ``η``; ``(s, a)`` is shielded iff ``Ā(s, a) > η`` (on the rule's own scale).
    """

    value_scale: ClassVar[Literal["shaped", "definition2"]] = "shaped"
    """Scale of :meth:`cost_value`: ``"shaped"`` (``[0, γ / (1 - γ)]``, absorbing tail) or ``"definition2"`` (``[0, γ]``)."""

    def __init__(self, eta: float = 0.0) -> None:
        if eta < 0:
            raise ValueError(f"The advantage threshold eta must be >= 0 (Proposition 1), got {eta}.")
        self.eta = eta

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        override = cls.__dict__.get("shield")
        if override is not None and not getattr(override, "fails_closed", False):
            cls.shield = fails_closed(override)  # type: ignore[method-assign]

    @abstractmethod
    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` for a batch: ``obs`` of shape ``(B, obs_dim)``, ``actions`` ``(B, act_dim)`` → ``(B,)``."""

    @abstractmethod
    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """The backup policy ``ζ(s)`` for a batch of observations → ``(B, act_dim)`` in env action units."""

    @property
    def discount(self) -> float:
        """``γ`` of ``Q̄``: the rule's ``gamma`` attribute (every built-in rule has one)."""
        gamma = getattr(self, "gamma", None)
        if gamma is None:
            raise AttributeError(
                f"{type(self).__name__} has no attribute 'gamma': set self.gamma, the discount of its Q̄, to use "
                "Definition 2's scale and the bounds of sppo_sb3.shield.analysis.bounds."
            )
        return float(gamma)

    def definition2_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` on Definition 2's scale ``[0, γ]``: ``(1 - γ)`` times a shaped value (see the class docstring)."""
        q = self.checked_cost_value(np.asarray(obs, dtype=np.float64), np.asarray(actions, dtype=np.float64))
        return q if self.value_scale == "definition2" else (1.0 - self.discount) * q

    @property
    def definition2_eta(self) -> float:
        """``η`` on Definition 2's scale: the threshold that gives the same decisions with :meth:`definition2_value`."""
        return self.eta if self.value_scale == "definition2" else (1.0 - self.discount) * self.eta

    def advantage(self, obs: np.ndarray, actions: np.ndarray, backup: np.ndarray | None = None) -> np.ndarray:
        """``Ā(s, a) = Q̄(s, a) - Q̄(s, ζ(s))``, both terms evaluated in one batched call of :meth:`cost_value`.

        ``Ā`` is 0 where the two terms agree up to rounding (:func:`advantage_from_values`) and where ``a = ζ(s)``.
        """
        if backup is None:
            backup = self.checked_backup(obs, actions.shape[1])
        n = len(obs)
        q = self.checked_cost_value(np.concatenate([obs, obs]), np.concatenate([actions, backup]))
        adv = advantage_from_values(q[:n], q[n:])
        # Ā(s, ζ(s)) = 0 by definition (Proposition 1); a batched network may differ in the last bit by row position
        adv[np.all(actions == backup, axis=1)] = 0.0
        return adv

    @fails_closed
    def shield(self, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        """Shielded action of eq. 12: keep ``a`` where ``(s, a) ∉ I``, else execute the backup action ``a_ζ``.

        :param obs: ``(B, obs_dim)`` raw observations.
        :param actions: ``(B, act_dim)`` proposed actions in env action units.
        :raises ShieldFailure: where a shielded row's backup action is not finite.
        """
        backup = self.checked_backup(obs, actions.shape[1])
        adv = np.full(len(obs), np.nan)
        known = finite_rows(obs) & finite_rows(actions)  # the rest is shielded without asking the rule
        if known.any():
            adv[known] = self.advantage(obs[known], actions[known], backup[known])
        intervened = in_shielding_set(adv, self.eta)
        safe = np.where(intervened[:, None], backup, actions)
        return ShieldDecision(actions=safe, intervened=intervened, advantage=adv)

    def shield_first_accepted(self, obs: np.ndarray, candidates: np.ndarray) -> tuple[ShieldDecision, np.ndarray]:
        """Eq. 12 over ranked proposals: execute each row's first candidate that :meth:`shield` accepts, the backup
        action where it accepts none.

        Each candidate is asked through :meth:`shield` (fail closed), the later ones only in the rows that rejected
        every earlier one; an accepted candidate is one the rule itself let through, so the guarantee of eq. 12 holds
        for whichever is executed. Where none is accepted, the backup action is the one the first call chose (a rule
        with memory, such as :class:`~sppo_sb3.shield.MujocoShieldingRule`'s warm plans, answers the later calls
        without the memory the first one used: more conservatively, never less safely).

        :param obs: ``(B, obs_dim)`` raw observations.
        :param candidates: ``(B, K, act_dim)`` proposals in env action units, best first.
        :return: the decision (``intervened``: no candidate accepted; ``advantage``: the executed candidate's, else
            the first's) and ``(B,)`` the index of the executed candidate (-1: the backup).
        """
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        candidates = np.asarray(candidates, dtype=np.float64).reshape(len(obs), -1, candidates.shape[-1])
        decision = self.shield(obs, candidates[:, 0])
        choice = np.where(decision.intervened, -1, 0)
        for k in range(1, candidates.shape[1]):
            rows = np.flatnonzero(choice < 0)
            if len(rows) == 0:
                break
            tried = self.shield(obs[rows], candidates[rows, k])
            accepted = rows[~tried.intervened]
            decision.actions[accepted] = tried.actions[~tried.intervened]
            decision.advantage[accepted] = tried.advantage[~tried.intervened]
            choice[accepted] = k
        decision.intervened = choice < 0
        if decision.edited is not None:  # an edit stays where no candidate was accepted
            decision.edited = decision.edits & decision.intervened
        return decision, choice

    def close_failures(self, obs: np.ndarray, actions: np.ndarray, decision: ShieldDecision) -> ShieldDecision:
        """Fail closed after a decision: shield every row with a non-finite observation, proposal or ``Ā``.

        :param obs: ``(B, obs_dim)`` raw observations.
        :param actions: ``(B, act_dim)`` proposed actions.
        :param decision: the decision of :meth:`shield`.
        :raises ShieldFailure: where a shielded row's executed (backup) action is not finite.
        """
        executed = np.array(decision.actions, dtype=np.float64).reshape(actions.shape)
        advantage = np.asarray(decision.advantage, dtype=np.float64).reshape(len(obs))
        unknown = ~(finite_rows(obs) & finite_rows(actions) & np.isfinite(advantage))
        missing = unknown & (~np.asarray(decision.intervened, dtype=bool) | decision.edits)  # the backup's action there
        if missing.any():
            executed[missing] = self.checked_backup(obs[missing], actions.shape[1])
        intervened = np.asarray(decision.intervened, dtype=bool) | unknown
        broken = intervened & ~finite_rows(executed)
        if broken.any():
            raise ShieldFailure(
                f"{type(self).__name__} cannot shield {int(broken.sum())} of {len(obs)} states: the backup action is "
                f"not finite there (observations {obs[broken][:3].tolist()}...). The shield never executes a proposal "
                "it could not evaluate. Check the env's observations for NaN/inf (stable_baselines3's VecCheckNan "
                "finds the step) and that backup_action returns finite actions for every valid observation."
            )
        edited = None if decision.edited is None else decision.edits & ~unknown
        return ShieldDecision(actions=executed, intervened=intervened, advantage=advantage, edited=edited)

    # --- checks of the rule's outputs ---------------------------------------------------------------------------

    def checked_backup(self, obs: np.ndarray, act_dim: int) -> np.ndarray:
        """``ζ(obs)`` as a ``(B, act_dim)`` float array; a wrong shape or type is an error that names the fix."""
        backup = self.backup_action(obs)
        name = f"{type(self).__name__}.backup_action"
        check_array(backup, name)
        expected = (len(obs), act_dim)
        if backup.shape == expected:
            return backup.astype(np.float64, copy=False)
        if backup.shape == (len(obs),) and act_dim == 1:
            fix = "add the action axis (e.g. return a[:, None])"
        else:
            fix = f"return one action of {act_dim} values per observation (is the rule written for another task?)"
        raise ValueError(f"{name} returned shape {backup.shape} for {len(obs)} observations; return shape {expected}: {fix}.")

    def checked_cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(obs, actions)`` as a ``(B,)`` float array; a wrong shape or type is an error that names the fix."""
        q = self.cost_value(obs, actions)
        name = f"{type(self).__name__}.cost_value"
        check_array(q, name)
        n = len(obs)
        if q.shape == (n,):
            return q.astype(np.float64, copy=False)
        fix = "drop the last axis (e.g. q[:, 0])" if q.shape == (n, 1) else "return one value per (observation, action) pair"
        raise ValueError(f"{name} returned shape {q.shape} for {n} (observation, action) pairs; return shape ({n},): {fix}.")

    def check_action_space(self, action_space: gym.spaces.Space, obs: np.ndarray) -> None:
        """Probe the rule once on real observations (e.g. the first ``reset``'s) and fail early with a clear message.

        Checks that ``ζ(s)`` and ``Q̄(s, a)`` have the contract's shapes and dtypes (:meth:`checked_backup`,
        :meth:`checked_cost_value`), that ``ζ(s)`` lies in ``action_space`` and that ``ζ(s)``, ``Q̄(s, ζ(s))`` and
        ``Q̄(s, a)`` at the action space's centre are finite.

        :param action_space: the env's action space.
        :param obs: a batch of valid raw observations to probe the rule with.
        """
        if not isinstance(action_space, gym.spaces.Box):
            raise TypeError(f"Shielding rules act on Box action spaces, got {action_space}.")
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        probe = np.concatenate([obs, obs])  # at least two rows: a squeezed batch axis shows up
        backup = self.checked_backup(probe, int(np.prod(action_space.shape)))
        if not finite_rows(backup).all():
            raise ValueError(
                f"{type(self).__name__}.backup_action returned NaN/inf at the env's observations {obs.tolist()}: the "
                "backup policy must return a finite action in every state the env can reach."
            )
        low, high = action_space.low.reshape(-1) - 1e-6, action_space.high.reshape(-1) + 1e-6  # rules act on flat actions
        if np.any(backup < low) or np.any(backup > high):
            raise ValueError(
                f"{type(self).__name__}.backup_action returned actions outside the env's action space "
                f"[{action_space.low}, {action_space.high}]: clip the backup policy's output to the bounds."
            )
        centre = np.broadcast_to((action_space.low + action_space.high).reshape(-1) / 2.0, backup.shape)
        q = self.checked_cost_value(np.concatenate([probe, probe]), np.concatenate([backup, centre]))
        if not np.isfinite(q).all():
            raise ValueError(
                f"{type(self).__name__}.cost_value returned NaN/inf at the env's observations {obs.tolist()}: Q̄ must "
                "be finite for every valid (observation, action); the shield would intervene at every step."
            )


def make_permissive(rule: ShieldingRule) -> None:
    """Turn on a rule's edits (``permissive``), or say which rules have them."""
    if not hasattr(rule, "permissive"):
        raise ValueError(
            f"{type(rule).__name__} has no edits: permissive=True needs a rule that finds accepted actions near a rejected "
            "proposal (sppo_sb3.shield.MujocoShieldingRule and the registered navigation, velocity and Half-Cheetah rules)."
        )
    rule.permissive = True


def check_array(value: Any, name: str) -> None:
    """Reject an output that is not a real numeric numpy array, with a message that says what to return."""
    if not isinstance(value, np.ndarray):
        raise TypeError(f"{name} returned a {type(value).__name__}; return a numpy array (e.g. np.asarray(x)).")
    if not (np.issubdtype(value.dtype, np.floating) or np.issubdtype(value.dtype, np.integer)):
        raise TypeError(f"{name} returned an array of dtype {value.dtype}; return floats (e.g. x.astype(np.float64)).")
