"""What the learned shielding rules share: a known backup ``ζ``, real transitions of ``B``, and their refinement.

Alg. 1 line 12 (``G ← UpdateShieldingRule(B)``, optional) lets a rule learn where no model exists: the backup
policy ``ζ`` is known (the user's safe fallback, e.g. "brake") and what the rule does not know is learned from the
real transitions of ``B``. :class:`RefinableRule` is the base of the three learned rules: the cost critic
(:mod:`~sppo_sb3.shield.learned.critic`), the learned dynamics (:mod:`~sppo_sb3.shield.learned.dynamics`) and the
latent rule on SPPO's own TOLD (:mod:`~sppo_sb3.shield.learned.latent`).
"""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Callable
from typing import NamedTuple

import gymnasium as gym
import numpy as np
from stable_baselines3.common.running_mean_std import RunningMeanStd

from sppo_sb3.shield.base import ShieldingRule

BackupPolicy = Callable[[np.ndarray], np.ndarray]
#: added to the observations' running variance before its square root (as SB3's VecNormalize)
OBS_EPSILON = 1e-8
#: the critic's logit before learning: ``Q̄ = γ·σ(INITIAL_LOGIT) ≈ 0.001·γ`` everywhere
INITIAL_LOGIT = math.log(1e-3 / (1.0 - 1e-3))


def bounds_scaler(space: gym.spaces.Box) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half-width mapping ``space`` onto ``[-1, 1]`` per dimension (identity where a bound is infinite)."""
    low, high = space.low.astype(np.float64).ravel(), space.high.astype(np.float64).ravel()
    finite = np.isfinite(low) & np.isfinite(high) & (high > low)
    centre = np.where(finite, (high + low) / 2.0, 0.0)
    half = np.where(finite, (high - low) / 2.0, 1.0)
    return centre, half


class CostTransitions(NamedTuple):
    """Real transitions of ``B`` for fitting a shielding rule's ``Q̄`` (Alg. 1 line 12), as float64 numpy arrays.

    :param observations: ``(B, obs_dim)`` raw states ``s``.
    :param actions: ``(B, A)`` executed actions (a rule's :meth:`~RefinableRule.refine` takes them in env units;
        SPPO's buffer stores them in [-1, 1] and rescales them).
    :param shaped_costs: ``(B,)`` ``ĉ`` of eq. 18 (``info["shaped_cost"]``).
    :param violations: ``(B,)`` the violation indicator ``c`` (``info["cost"]``).
    :param next_observations: ``(B, obs_dim)`` raw next states ``s'``.
    :param terminations: ``(B,)`` 1 where the episode terminated (not a time-limit truncation).
    """

    observations: np.ndarray
    actions: np.ndarray
    shaped_costs: np.ndarray
    violations: np.ndarray
    next_observations: np.ndarray
    terminations: np.ndarray


class RefinableRule(ShieldingRule):
    """A rule that learns from the real transitions of ``B`` (Alg. 1 line 12) with a known backup ``ζ``.

    What its learners share: the spaces, the user's backup, ``γ``, the observations' running statistics, the checks of
    a batch's shapes and the minibatch sampling. SPPO (``refine_shield="auto"``) calls :meth:`refine` on a minibatch of
    ``B`` once per TOPO update.

    :param observation_space: the env's flat Box observation space; the rule reads raw observations.
    :param action_space: the env's Box action space.
    :param backup_policy: the known backup ``ζ``: ``(B, obs_dim)`` observations → ``(B, act_dim)`` actions in env units.
    :param gamma: discount of ``Q̄``.
    :param eta: advantage threshold ``η >= 0``.
    :param seed: seeds the minibatch sampling (``None``: not seeded).
    """

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Space,
        backup_policy: BackupPolicy,
        gamma: float,
        eta: float,
        seed: int | None,
    ) -> None:
        super().__init__(eta=eta)
        if not isinstance(observation_space, gym.spaces.Box):
            raise TypeError(f"{type(self).__name__} needs a flat Box observation space, got {observation_space}.")
        if not isinstance(action_space, gym.spaces.Box):
            raise TypeError(f"Shielding rules act on Box action spaces, got {action_space}.")
        if not callable(backup_policy):
            raise TypeError(
                f"backup_policy must be a callable obs (B, obs_dim) -> actions (B, act_dim), got {backup_policy!r}"
            )
        if not 0.0 < gamma < 1.0:
            raise ValueError(f"gamma must be in (0, 1), got {gamma}.")
        self.observation_space = observation_space
        self.action_space = action_space
        self.backup_policy = backup_policy
        self.gamma = float(gamma)
        self.obs_dim = int(np.prod(observation_space.shape))
        self.act_dim = int(np.prod(action_space.shape))
        self.obs_rms = RunningMeanStd(shape=(self.obs_dim,))
        self._act_centre, self._act_half = bounds_scaler(action_space)
        self._rng = np.random.default_rng(seed)

    def flat_pairs(self, obs: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(B, obs_dim)`` and ``(B, act_dim)`` float64 arrays of a batch, or a clear error for another task's."""
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        actions = np.asarray(actions, dtype=np.float64).reshape(len(actions), -1)
        if obs.shape[1] != self.obs_dim or actions.shape[1] != self.act_dim or len(obs) != len(actions):
            raise ValueError(
                f"{type(self).__name__} was built for observations of size {self.obs_dim} and actions of size "
                f"{self.act_dim}, got a batch of {obs.shape} and {actions.shape}."
            )
        return obs, actions

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """The user's backup ``ζ(s)`` for a batch, as a float64 ``(B, act_dim)`` array (checked by ``check_action_space``)."""
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        return np.asarray(self.backup_policy(obs), dtype=np.float64)

    def scaled_inputs(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``[s, a]`` of a checked batch: ``s`` standardised by :attr:`obs_rms`, ``a`` rescaled to ``[-1, 1]``."""
        obs = (obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + OBS_EPSILON)
        return np.concatenate([obs, (actions - self._act_centre) / self._act_half], axis=1)

    def minibatch(self, n: int, batch_size: int) -> np.ndarray:
        """Indices of a minibatch of ``batch_size`` of ``n`` transitions, without replacement (all of them if fewer)."""
        return self._rng.choice(n, size=batch_size, replace=False) if n > batch_size else np.arange(n)

    @abstractmethod
    def refine(self, transitions: CostTransitions, batch_size: int) -> float:
        """One learning step on a minibatch of real transitions of ``B`` (Alg. 1 line 12, actions in env units);
        returns its loss."""
