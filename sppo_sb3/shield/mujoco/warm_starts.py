"""The warm-started nominal plans of an MPC backup, kept between calls of a shielding rule."""

from __future__ import annotations

import numpy as np


class WarmStarts:
    """The MPC's warm-started nominal plans, each stored under the observation it starts from, with the state.

    After a shielded step the rule stores, under the predicted next observation, the plan it would follow from there
    and the predicted physics state; a later call whose observation matches that prediction (within ``tolerance``: the
    rebuilt state reproduces the env's step to about ``1e-13``) starts its MPC from it, and knows the state where the
    observation alone does not say it (clipped velocities). Any other observation — an episode's first, or one the
    rule did not predict — starts from the zero plan. Keying by the state, not by an env index, serves any caller:
    one batched call for all envs (SPPO) as one call per env (:class:`~sppo_sb3.shield.ShieldWrapper`).

    :param capacity: plans kept at most (the oldest go first): one per running env is needed.
    :param horizon: plan length ``H``.
    :param n_controls: controls per step.
    :param tolerance: largest absolute difference, per observation entry, of a match.
    """

    def __init__(self, capacity: int, horizon: int, n_controls: int, tolerance: float = 1e-5) -> None:
        if capacity < 1:
            raise ValueError(f"WarmStarts needs a capacity >= 1, got {capacity}.")
        self.capacity = capacity
        self.horizon = horizon
        self.n_controls = n_controls
        self.tolerance = tolerance
        self.clear()

    def clear(self) -> None:
        """Forget every plan."""
        self.keys = np.empty((0, 0))
        self.plans = np.empty((0, self.horizon, self.n_controls))
        self.states = np.empty((0, 0))

    def lookup(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The plans and states stored under ``obs``, or zero plans and NaN states.

        :param obs: ``(B, obs_dim)`` observations.
        :return: ``(B, H, n_controls)`` plans, ``(B,)`` the indices of the stored entries used (-1: none) and
            ``(B, nstate)`` the predicted states (NaN rows where none is stored; no columns before the first store).
        """
        plans = np.zeros((len(obs), self.horizon, self.n_controls))
        index = np.full(len(obs), -1)
        states = np.full((len(obs), self.states.shape[1]), np.nan)
        if len(self.keys) == 0 or self.keys.shape[1] != obs.shape[1]:
            return plans, index, states
        close = np.abs(obs[:, None, :] - self.keys[None, :, :]).max(axis=2) <= self.tolerance
        found = close.any(axis=1)
        index[found] = len(self.keys) - 1 - np.argmax(close[found, ::-1], axis=1)  # the newest match
        plans[found] = self.plans[index[found]]
        states[found] = self.states[index[found]]
        return plans, index, states

    def replace(self, used: np.ndarray, keys: np.ndarray, plans: np.ndarray, states: np.ndarray) -> None:
        """Drop the entries ``used`` (their states are left behind) and store ``plans`` and ``states`` under ``keys``.

        :param used: indices from :meth:`lookup` (-1 entries are ignored).
        :param keys: ``(B, obs_dim)`` the observations the plans start from, newest last.
        :param plans: ``(B, H, n_controls)`` the plans.
        :param states: ``(B, nstate)`` the physics states predicted for those observations.
        """
        keep = np.ones(len(self.keys), dtype=bool)
        keep[used[used >= 0]] = False
        old_keys = self.keys[keep] if len(self.keys) else np.empty((0, keys.shape[1]))
        old_states = self.states[keep] if len(self.states) else np.empty((0, states.shape[1]))
        self.keys = np.concatenate([old_keys, keys])[-self.capacity :]
        self.plans = np.concatenate([self.plans[keep], plans])[-self.capacity :]
        self.states = np.concatenate([old_states, states])[-self.capacity :]
