"""The buffers of the cost-aware algorithms: SB3's ``RolloutBuffer`` plus costs and a learning mask (the on-policy
baselines), and SB3's ``ReplayBuffer`` plus costs (SACLag)."""

from __future__ import annotations

from collections.abc import Generator
from typing import Any, NamedTuple, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer, ReplayBuffer, RolloutBuffer
from stable_baselines3.common.vec_env import VecNormalize

from sppo_sb3.common.costs import costs_from_infos
from sppo_sb3.common.gae import compute_gae

BufferT = TypeVar("BufferT", bound=BaseBuffer)


def cost_buffer_class(given: type[BaseBuffer] | None, required: type[BufferT], algorithm: str, argument: str) -> type[BufferT]:
    """The buffer class a cost-aware algorithm uses: ``required`` where none is given, else the given one, which must
    subclass it (it stores the costs).

    :param given: the class the user passed (``rollout_buffer_class`` or ``replay_buffer_class``), or ``None``.
    :param required: the cost-aware buffer the algorithm needs.
    :param algorithm: the algorithm's name, for the message.
    :param argument: the argument's name, for the message.
    :raises TypeError: where ``given`` does not subclass ``required``.
    """
    if given is None:
        return required
    if not issubclass(given, required):
        raise TypeError(
            f"{algorithm} needs a {required.__name__} (it stores the costs); got {argument}={given.__name__}. "
            f"Leave {argument}=None or subclass {required.__name__}."
        )
    return given


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


class CostReplayBufferSamples(NamedTuple):
    """A minibatch of :class:`CostReplayBuffer`: SB3's ``ReplayBufferSamples`` fields (no n-step discounts) and costs.

    ``dones`` are 1 where the episode terminated (not where a time limit truncated it), as SB3's; ``rewards`` are
    normalised under ``VecNormalize``, ``costs`` never are.
    """

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    costs: th.Tensor


class CostReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer`` plus each transition's cost ``c(s, a) = info["cost"]``, read from the step's infos in
    :meth:`add` (``MissingCostError`` where an env does not report it). Arguments are SB3's ``ReplayBuffer``'s.

    :param buffer_size: the most transitions kept (over all envs).
    :param observation_space: observation space (not a Dict).
    :param action_space: action space.
    :param device: PyTorch device of the sampled tensors.
    :param n_envs: number of parallel envs.
    :param optimize_memory_usage: SB3's memory-efficient storage of the next observations.
    :param handle_timeout_termination: bootstrap the transitions cut by a time limit (SB3's, default).
    """

    costs: np.ndarray

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
    ) -> None:
        if isinstance(observation_space, spaces.Dict):
            raise TypeError("CostReplayBuffer stores flat observations; Dict observation spaces are not supported.")
        super().__init__(
            buffer_size, observation_space, action_space, device, n_envs, optimize_memory_usage, handle_timeout_termination
        )
        self.costs = np.zeros((self.buffer_size, self.n_envs), dtype=np.float32)

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        self.costs[self.pos] = costs_from_infos(infos)
        super().add(obs, next_obs, action, reward, done, infos)

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> CostReplayBufferSamples:  # type: ignore[override]
        """``batch_size`` transitions drawn uniformly, with their costs (SB3's ``sample``)."""
        samples = super().sample(batch_size, env)
        assert isinstance(samples, CostReplayBufferSamples)
        return samples

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> CostReplayBufferSamples:  # type: ignore[override]
        """SB3's transitions at ``batch_inds`` (a random env each) and their costs: drawn here, not by SB3's
        ``_get_samples``, so that the costs come from the same envs as the rest."""
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        if self.optimize_memory_usage:
            next_obs = self.observations[(batch_inds + 1) % self.buffer_size, env_indices, :]
        else:
            next_obs = self.next_observations[batch_inds, env_indices, :]
        terminated = self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(next_obs, env),
            terminated.reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
            self.costs[batch_inds, env_indices].reshape(-1, 1),
        )
        return CostReplayBufferSamples(*tuple(map(self.to_torch, data)))
