"""Policies of SACLag: SB3's SAC policy (squashed Gaussian actor, twin reward critics) plus a cost critic ``Q_C``."""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.sac.policies import SACPolicy
from torch import nn

__all__ = ["MlpPolicy", "SACLagPolicy"]


class SACLagPolicy(SACPolicy):
    """SB3's ``SACPolicy`` plus a cost critic ``Q_C(s, a)``, its target copy ``Q_C'`` and its own optimizer.

    The actor, the reward critics, their targets and their optimizers are exactly SB3's. The cost critic is an SB3
    ``ContinuousCritic`` of ``n_cost_critics`` Q-networks (their maximum, the pessimistic estimate, is
    :meth:`cost_value`); it has its own features extractor unless ``share_features_extractor`` (then it shares the
    actor's, as the reward critics do, and its optimizer leaves the extractor to the actor). The optimizer is
    ``cost_critic.optimizer``, at the learning rate of the others.

    :param observation_space: observation space.
    :param action_space: action space (a Box with finite bounds).
    :param lr_schedule: learning rate schedule of every optimizer.
    :param net_arch: hidden layers of the actor and the reward critics (SB3's; default ``[256, 256]``).
    :param activation_fn: activation of every network.
    :param use_sde: generalised state-dependent exploration.
    :param log_std_init: initial log standard deviation (gSDE).
    :param use_expln: ``expln`` instead of ``exp`` for the gSDE standard deviation.
    :param clip_mean: clipping of the mean action (gSDE).
    :param features_extractor_class: features extractor of every network.
    :param features_extractor_kwargs: its keyword arguments.
    :param normalize_images: divide image observations by 255.
    :param optimizer_class: optimizer of every network.
    :param optimizer_kwargs: its keyword arguments (learning rate excluded).
    :param n_critics: number of reward Q-networks (their minimum is SAC's clipped double-Q estimate).
    :param share_features_extractor: the critics share the actor's features extractor.
    :param cost_net_arch: hidden layers of the cost Q-networks (``None``: the reward critics').
    :param n_cost_critics: number of cost Q-networks (1: OmniSafe's single cost critic).
    :raises ValueError: when ``n_cost_critics < 1``.
    """

    cost_critic: ContinuousCritic
    cost_critic_target: ContinuousCritic

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        use_sde: bool = False,
        log_std_init: float = -3,
        use_expln: bool = False,
        clip_mean: float = 2.0,
        features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        n_critics: int = 2,
        share_features_extractor: bool = False,
        cost_net_arch: list[int] | None = None,
        n_cost_critics: int = 1,
    ) -> None:
        if n_cost_critics < 1:
            raise ValueError(f"n_cost_critics must be >= 1 (the cost critic's Q-networks), got {n_cost_critics}")
        self.cost_net_arch = None if cost_net_arch is None else list(cost_net_arch)
        self.n_cost_critics = n_cost_critics
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=net_arch,
            activation_fn=activation_fn,
            use_sde=use_sde,
            log_std_init=log_std_init,
            use_expln=use_expln,
            clip_mean=clip_mean,
            features_extractor_class=features_extractor_class,
            features_extractor_kwargs=features_extractor_kwargs,
            normalize_images=normalize_images,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            n_critics=n_critics,
            share_features_extractor=share_features_extractor,
        )

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)  # actor, reward critics, their target and optimizers
        shared = self.actor.features_extractor if self.share_features_extractor else None
        self.cost_critic = self.make_cost_critic(features_extractor=shared)
        trained = [p for name, p in self.cost_critic.named_parameters() if shared is None or "features_extractor" not in name]
        self.cost_critic.optimizer = self.optimizer_class(trained, lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]
        self.cost_critic_target = self.make_cost_critic(features_extractor=None)  # a target never shares
        self.cost_critic_target.load_state_dict(self.cost_critic.state_dict())
        self.cost_critic_target.set_training_mode(False)

    def make_cost_critic(self, features_extractor: BaseFeaturesExtractor | None = None) -> ContinuousCritic:
        """A cost critic: the reward critics' settings with ``cost_net_arch`` and ``n_cost_critics``.

        :param features_extractor: the extractor to share (``None``: a new one).
        """
        net_arch = self.critic_kwargs["net_arch"] if self.cost_net_arch is None else self.cost_net_arch
        kwargs = {**self.critic_kwargs, "net_arch": net_arch, "n_critics": self.n_cost_critics}
        return ContinuousCritic(**self._update_features_extractor(kwargs, features_extractor)).to(self.device)

    def cost_value(self, obs: PyTorchObs, actions: th.Tensor, target: bool = False) -> th.Tensor:
        """``Q_C(s, a)``, ``(batch, 1)``: the largest of the cost Q-networks (the only one when ``n_cost_critics=1``).

        :param obs: observations (preprocessed by the critic's features extractor).
        :param actions: actions scaled to [-1, 1], ``(batch, action_dim)``.
        :param target: use the target critic ``Q_C'`` of the Bellman backup.
        """
        critic = self.cost_critic_target if target else self.cost_critic
        return th.cat(critic(obs, actions), dim=1).max(dim=1, keepdim=True).values

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(cost_net_arch=self.cost_net_arch, n_cost_critics=self.n_cost_critics)
        return data

    def set_training_mode(self, mode: bool) -> None:
        super().set_training_mode(mode)
        self.cost_critic.set_training_mode(mode)


MlpPolicy = SACLagPolicy
