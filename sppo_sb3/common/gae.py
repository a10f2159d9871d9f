"""Generalised advantage estimation of any per-step signal: the reward's and the cost's advantage ``A_C``."""

from __future__ import annotations

import numpy as np


def compute_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    episode_starts: np.ndarray,
    last_values: np.ndarray,
    dones: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation, GAE(γ, λ) (Schulman et al. 2016, eq. 16), of any per-step signal.

    ``δ_t = x_t + γ·(1 - done_t)·V(s_(t+1)) - V(s_t)`` and ``A_t = δ_t + γλ·(1 - done_t)·A_(t+1)``, where ``done_t``
    is ``episode_starts[t + 1]`` (``dones`` for the last step). Used with ``x = r`` for the reward and ``x = c`` for
    the cost (the cost advantage ``A_C`` of PDO and CPO). Same convention as SB3's ``RolloutBuffer``.

    :param rewards: ``(T, n_envs)`` per-step signal (reward or cost).
    :param values: ``(T, n_envs)`` value estimates of the states.
    :param episode_starts: ``(T, n_envs)`` whether step ``t`` starts an episode.
    :param last_values: ``(n_envs,)`` value of the state after the last step.
    :param dones: ``(n_envs,)`` whether the last step ended its episode.
    :param gamma: discount ``γ``.
    :param gae_lambda: GAE ``λ`` (1: Monte-Carlo with bootstrap, 0: one-step TD).
    :return: ``(advantages, returns)``, both ``(T, n_envs)`` float32; ``returns = advantages + values`` (TD(λ)).
    """
    rewards = np.asarray(rewards, dtype=np.float32)
    values = np.asarray(values, dtype=np.float32)
    n_steps = rewards.shape[0]
    advantages = np.zeros_like(rewards)
    last_gae = np.zeros(rewards.shape[1:], dtype=np.float32)
    for step in reversed(range(n_steps)):
        if step == n_steps - 1:
            next_non_terminal = 1.0 - np.asarray(dones, dtype=np.float32)
            next_values = np.asarray(last_values, dtype=np.float32).reshape(rewards.shape[1:])
        else:
            next_non_terminal = 1.0 - np.asarray(episode_starts[step + 1], dtype=np.float32)
            next_values = values[step + 1]
        delta = rewards[step] + gamma * next_values * next_non_terminal - values[step]
        last_gae = delta + gamma * gae_lambda * next_non_terminal * last_gae
        advantages[step] = last_gae
    return advantages, advantages + values
