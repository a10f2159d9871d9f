"""The advantage-based shielding rule ``G = (Q̄, ζ, Ā, η, I)`` of Section III-B, on batches.

A rule answers two questions on a batch of raw (un-normalised) observations:

- ``cost_value(obs, actions)``: ``Q̄(s, a)``, the discounted (shaped) cost of taking ``a`` in ``s`` and following the
  backup policy ``ζ`` afterwards;
- ``backup_action(obs)``: the backup policy's action ``ζ(s)``, in the env's action units.

Everything else — the advantage ``Ā``, the shielding set ``I`` and the shielded action of eqs. 5/12 — follows here,
once, for every algorithm of the package. Subclass :class:`ShieldingRule` to bring your own task.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import gymnasium as gym
import numpy as np


@dataclass
class ShieldDecision:
    """Outcome of shielding a batch of proposed actions (eq. 12).

    :param actions: the executed actions ``a_safe`` (proposed where allowed, backup where shielded).
    :param intervened: ``True`` where ``(s, a) ∈ I`` and the backup action replaced the proposal.
    :param advantage: ``Ā(s, a)`` of each proposal.
    """

    actions: np.ndarray
    intervened: np.ndarray
    advantage: np.ndarray


def in_shielding_set(advantage: np.ndarray, eta: float) -> np.ndarray:
    """Membership test of the shielding set: ``(s, a) ∈ I  ⇔  Ā(s, a) > η`` (Section III-B, used by eq. 12)."""
    return np.asarray(advantage) > eta


class ShieldingRule(ABC):
    """Advantage-based shielding rule ``G = (Q̄, ζ, Ā, η, I)`` (Section III-B).

    With ``η >= 0`` the backup action is never shielded (Proposition 1), so the shielded policy always has an
    admissible action.

    :param eta: advantage threshold ``η``; ``(s, a)`` is shielded iff ``Ā(s, a) > η``.
    :param penalty: reward ``R̃ <= 0`` of the absorbing transition that replaces a shielded step in the
        absorbing MDP (eq. 7).
    """

    def __init__(self, eta: float = 0.0, penalty: float = -1.0) -> None:
        if eta < 0:
            raise ValueError(f"The advantage threshold eta must be >= 0 (Proposition 1), got {eta}.")
        if penalty > 0:
            raise ValueError(f"The absorbing penalty R̃ must be <= 0 (eq. 7), got {penalty}.")
        self.eta = eta
        self.penalty = penalty

    @abstractmethod
    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` for a batch: ``obs`` of shape ``(B, obs_dim)``, ``actions`` ``(B, act_dim)`` → ``(B,)``."""

    @abstractmethod
    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """The backup policy ``ζ(s)`` for a batch of observations → ``(B, act_dim)`` in env action units."""

    def advantage(self, obs: np.ndarray, actions: np.ndarray, backup: np.ndarray | None = None) -> np.ndarray:
        """``Ā(s, a) = Q̄(s, a) - Q̄(s, ζ(s))``, both terms evaluated in one batched call of :meth:`cost_value`."""
        if backup is None:
            backup = self.backup_action(obs)
        n = len(obs)
        q = self.cost_value(np.concatenate([obs, obs]), np.concatenate([actions, backup]))
        adv = q[:n] - q[n:]
        # Ā(s, ζ(s)) = 0 by definition (Proposition 1); a batched network may differ in the last bit by row position
        adv[np.all(actions == backup, axis=1)] = 0.0
        return adv

    def shield(self, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        """Shielded action of eq. 12: keep ``a`` where ``(s, a) ∉ I``, else execute the backup action ``a_ζ``.

        :param obs: ``(B, obs_dim)`` raw observations.
        :param actions: ``(B, act_dim)`` proposed actions in env action units.
        """
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        actions = np.asarray(actions, dtype=np.float64).reshape(len(obs), -1)
        backup = self.backup_action(obs)
        adv = self.advantage(obs, actions, backup)
        intervened = in_shielding_set(adv, self.eta)
        safe = np.where(intervened[:, None], backup, actions)
        return ShieldDecision(actions=safe, intervened=intervened, advantage=adv)

    def check_action_space(self, action_space: gym.spaces.Space, obs: np.ndarray) -> None:
        """Fail early, with a clear message, when the backup policy is not usable in ``action_space``.

        :param action_space: the env's action space.
        :param obs: a batch of valid observations to probe the backup policy with.
        """
        if not isinstance(action_space, gym.spaces.Box):
            raise TypeError(f"Shielding rules act on Box action spaces, got {action_space}.")
        backup = self.backup_action(np.asarray(obs, dtype=np.float64).reshape(len(obs), -1))
        if backup.shape[1:] != action_space.shape:
            raise ValueError(
                f"{type(self).__name__}.backup_action returns actions of shape {backup.shape[1:]}, but the env's "
                f"action space has shape {action_space.shape}: the rule was written for another task."
            )
        low, high = action_space.low - 1e-6, action_space.high + 1e-6
        if np.any(backup < low) or np.any(backup > high):
            raise ValueError(
                f"{type(self).__name__}.backup_action returned actions outside the env's action space "
                f"[{action_space.low}, {action_space.high}]: clip the backup policy's output to the bounds."
            )
