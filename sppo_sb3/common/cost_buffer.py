"""The rollout buffer of the cost-aware on-policy algorithms: SB3's ``RolloutBuffer`` plus costs and a learning mask."""

from __future__ import annotations

from collections.abc import Generator
from typing import NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.vec_env import VecNormalize

from sppo_sb3.common.gae import compute_gae


class CostRolloutBufferSamples(NamedTuple):
    """A minibatch of :class:`CostRolloutBuffer`; the first six fields are SB3's ``RolloutBufferSamples``."""

    observations: th.Tensor
    actions: th.Tensor
    old_values: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    returns: th.Tensor
    old_cost_values: th.Tensor
    cost_advantages: th.Tensor
    cost_returns: th.Tensor


class CostRolloutBuffer(RolloutBuffer):
    """SB3's ``RolloutBuffer`` plus the cost signal: costs, cost values ``V_C``, cost GAE ``A_C`` and cost returns.

    It also keeps a per-step learning mask: :meth:`get` only yields the steps whose mask is 1 (SAILR masks the
    steps that follow an intervention within an episode). Minibatches are drawn among those steps only, so
    advantage normalisation and every loss ignore the masked ones.

    :param buffer_size: steps per env per rollout (``n_steps``).
    :param observation_space: observation space.
    :param action_space: action space.
    :param device: PyTorch device.
    :param gae_lambda: GAE ``λ``, shared by the reward and the cost.
    :param gamma: discount ``γ``, shared by the reward and the cost.
    :param n_envs: number of parallel envs.
    """

    costs: np.ndarray
    cost_values: np.ndarray
    cost_advantages: np.ndarray
    cost_returns: np.ndarray
    masks: np.ndarray

    def reset(self) -> None:
        shape = (self.buffer_size, self.n_envs)
        self.costs = np.zeros(shape, dtype=np.float32)
        self.cost_values = np.zeros(shape, dtype=np.float32)
        self.cost_advantages = np.zeros(shape, dtype=np.float32)
        self.cost_returns = np.zeros(shape, dtype=np.float32)
        self.masks = np.ones(shape, dtype=np.float32)
        super().reset()

    def add(  # type: ignore[override]
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        episode_start: np.ndarray,
        value: th.Tensor,
        log_prob: th.Tensor,
        cost: np.ndarray | None = None,
        cost_value: th.Tensor | None = None,
        mask: np.ndarray | None = None,
    ) -> None:
        """Store one VecEnv step.

        :param cost: ``(n_envs,)`` cost of the step (``info["cost"]``, plus the timeout bootstrap); 0 if ``None``.
        :param cost_value: ``(n_envs,)`` ``V_C(s)``; 0 if ``None``.
        :param mask: ``(n_envs,)`` 1 where the step is learned from, 0 where it is masked out; 1 if ``None``.
        """
        pos = self.pos
        self.costs[pos] = 0.0 if cost is None else np.asarray(cost)
        self.cost_values[pos] = 0.0 if cost_value is None else cost_value.clone().cpu().numpy().flatten()
        self.masks[pos] = 1.0 if mask is None else np.asarray(mask, dtype=np.float32)
        super().add(obs, action, reward, episode_start, value, log_prob)

    def compute_returns_and_advantage(  # type: ignore[override]
        self, last_values: th.Tensor, dones: np.ndarray, last_cost_values: th.Tensor | None = None
    ) -> None:
        """Reward GAE (SB3's) and cost GAE (:func:`compute_gae`) of the rollout.

        :param last_values: ``V(s)`` of the state after the last step, one per env.
        :param dones: whether the last step ended its episode (for learning), one per env.
        :param last_cost_values: ``V_C(s)`` of the state after the last step; 0 if ``None``.
        """
        super().compute_returns_and_advantage(last_values, dones)
        last_c = np.zeros(self.n_envs, dtype=np.float32) if last_cost_values is None else last_cost_values.cpu().numpy()
        self.cost_advantages, self.cost_returns = compute_gae(
            self.costs, self.cost_values, self.episode_starts, last_c.flatten(), dones, self.gamma, self.gae_lambda
        )

    @property
    def n_learnable(self) -> int:
        """Number of stored steps with mask 1 (the ones :meth:`get` yields)."""
        return int(self.masks.sum())

    def get(self, batch_size: int | None = None) -> Generator[CostRolloutBufferSamples, None, None]:  # type: ignore[override]
        """Minibatches, in random order, of the unmasked steps; ``batch_size=None``: all of them at once."""
        assert self.full, "The rollout buffer is not full yet."
        if not self.generator_ready:
            for name in (
                "observations",
                "actions",
                "values",
                "log_probs",
                "advantages",
                "returns",
                "cost_values",
                "cost_advantages",
                "cost_returns",
                "masks",
            ):
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
            self.generator_ready = True
        indices = np.random.permutation(np.flatnonzero(self.masks.reshape(-1) > 0))
        if batch_size is None:
            batch_size = max(len(indices), 1)
        for start in range(0, len(indices), batch_size):
            yield self._get_samples(indices[start : start + batch_size])

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> CostRolloutBufferSamples:  # type: ignore[override]
        data = (
            self.observations[batch_inds],
            self.actions[batch_inds].astype(np.float32, copy=False),
            self.values[batch_inds].flatten(),
            self.log_probs[batch_inds].flatten(),
            self.advantages[batch_inds].flatten(),
            self.returns[batch_inds].flatten(),
            self.cost_values[batch_inds].flatten(),
            self.cost_advantages[batch_inds].flatten(),
            self.cost_returns[batch_inds].flatten(),
        )
        return CostRolloutBufferSamples(*tuple(map(self.to_torch, data)))
