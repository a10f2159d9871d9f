"""SB3's actor-critic policy with a cost value head ``V_C(s)``, the cost critic of PDO and CPO, and its regression."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.common.utils import explained_variance
from torch import nn
from torch.nn import functional as F

from sppo_sb3.common.cost_buffer import CostRolloutBuffer


class CostActorCriticPolicy(ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` with an extra cost value head ``V_C(s)`` (the cost critic of PDO and CPO).

    The cost critic is its own MLP on the critic's features (``cost_value_net``), so it shares no weights with the
    actor. Its parameter names contain ``"value"``, which keeps it out of sb3-contrib TRPO's natural-gradient step.
    Every other argument is ``ActorCriticPolicy``'s.

    :param cost_net_arch: hidden layers of the cost critic; ``None``: the same as the value network's.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.Tanh,
        *args: Any,
        cost_net_arch: list[int] | None = None,
        **kwargs: Any,
    ) -> None:
        self.cost_net_arch = cost_net_arch
        super().__init__(observation_space, action_space, lr_schedule, net_arch, activation_fn, *args, **kwargs)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        if self.cost_net_arch is None:
            arch = self.net_arch.get("vf", []) if isinstance(self.net_arch, dict) else list(self.net_arch)
            self.cost_net_arch = list(arch)
        features_dim = self.vf_features_extractor.features_dim
        self.cost_value_net = nn.Sequential(*create_mlp(features_dim, 1, self.cost_net_arch, self.activation_fn))
        if self.ortho_init:
            self.cost_value_net.apply(lambda module: self.init_weights(module, gain=np.sqrt(2)))
            last = self.cost_value_net[-1]
            assert isinstance(last, nn.Linear)
            self.init_weights(last, gain=1.0)
        # the optimiser built by ActorCriticPolicy does not know the new head yet
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]

    def predict_cost_values(self, obs: th.Tensor) -> th.Tensor:
        """``V_C(s)``: the expected discounted cost-to-go of the current policy, shape ``(batch, 1)``."""
        features = super(ActorCriticPolicy, self).extract_features(obs, self.vf_features_extractor)
        return self.cost_value_net(features)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(cost_net_arch=self.cost_net_arch)
        return data


def fit_critics(
    policy: CostActorCriticPolicy,
    rollout_buffer: CostRolloutBuffer,
    n_epochs: int,
    batch_size: int,
    reward_critic: bool,
    frozen: Iterable[nn.Parameter] = (),
) -> dict[str, float]:
    """Regress ``V_C`` (and ``V`` if ``reward_critic``) on the rollout's TD(λ) returns, by minibatch MSE.

    :param policy: the policy whose critics are fitted, with its optimizer.
    :param rollout_buffer: the rollout, with its cost returns computed.
    :param n_epochs: passes over the rollout.
    :param batch_size: minibatch size.
    :param reward_critic: also fit the reward value ``V`` (CPO; PDO fits it inside PPO's loss).
    :param frozen: parameters whose gradients are dropped before each step (the actor's, for TRPO/CPO).
    :return: mean losses and the cost critic's explained variance, for the ``train/`` logs.
    """
    frozen = list(frozen)
    cost_losses, value_losses = [], []
    for _ in range(n_epochs):
        for data in rollout_buffer.get(batch_size):
            loss = F.mse_loss(data.cost_returns, policy.predict_cost_values(data.observations).flatten())
            cost_losses.append(loss.item())
            if reward_critic:
                value_loss = F.mse_loss(data.returns, policy.predict_values(data.observations).flatten())
                value_losses.append(value_loss.item())
                loss = loss + value_loss
            policy.optimizer.zero_grad()
            loss.backward()
            for param in frozen:
                param.grad = None
            policy.optimizer.step()
    buf = rollout_buffer
    out = {"cost_value_loss": float(np.mean(cost_losses)) if cost_losses else float("nan")}
    out["cost_explained_variance"] = float(explained_variance(buf.cost_values.flatten(), buf.cost_returns.flatten()))
    if reward_critic:
        out["value_loss"] = float(np.mean(value_losses)) if value_losses else float("nan")
    return out
