"""TOLD — the task-oriented latent dynamics model of eq. 9 — and SPPO's policy wrapper around it.

Five deterministic MLPs (TD-MPC sizes by default): encoder ``h(s) → z``, latent dynamics ``d(z, a) → z'``,
reward ``R(z, a)``, twin value ``Q(z, a)`` and policy ``π(z) → a ∈ [-1, 1]``; optionally a sixth, the termination
head ``T(z, a)``: the logit of the probability that ``(z, a)`` ends the episode of the absorbing MDP ``M̃`` (eq. 8: a
shielded proposal, a violation or a real termination), so that planning adds nothing after it (eq. 10).
"""

from __future__ import annotations

import copy
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.type_aliases import PyTorchObs
from torch import nn

from sppo_sb3.common.networks import mlp


class ELU(nn.ELU):
    """ELU (α = 1) whose no-grad forward takes ``max(x, exp(min(x, 0)) - 1)``: four vectorised passes.

    The planner evaluates ELU on every hidden layer of every rollout step, and PyTorch's CPU ELU kernel is slower than
    these four passes on the planner's shapes (measured in ``docs/results.md``). With autograd on it is ``F.elu``.
    """

    def forward(self, x: th.Tensor) -> th.Tensor:
        if th.is_grad_enabled() or self.alpha != 1.0:
            return super().forward(x)
        negative = th.clamp(x, max=0.0).exp_().sub_(1.0)
        return th.maximum(x, negative, out=negative)


def q_network(in_dim: int, hidden_dim: int) -> nn.Sequential:
    """TD-MPC's value head: ``Linear → LayerNorm → Tanh → Linear → ELU → Linear``."""
    return nn.Sequential(
        nn.Linear(in_dim, hidden_dim),
        nn.LayerNorm(hidden_dim),
        nn.Tanh(),
        nn.Linear(hidden_dim, hidden_dim),
        ELU(),
        nn.Linear(hidden_dim, 1),
    )


def orthogonal_init(module: nn.Module) -> None:
    """Orthogonal weights and zero biases on every Linear layer (TD-MPC's initialisation)."""
    if isinstance(module, nn.Linear):
        nn.init.orthogonal_(module.weight)
        nn.init.zeros_(module.bias)


def zero_last_layer(net: nn.Sequential, bias: float = 0.0) -> None:
    """Zero the output layer's weights, so the head starts at the constant ``bias`` (0: reward and values)."""
    last = net[-1]
    assert isinstance(last, nn.Linear)
    nn.init.zeros_(last.weight)
    nn.init.constant_(last.bias, bias)


INITIAL_TERMINATION_LOGIT = -4.6
"""``log(0.01 / 0.99)``: the untrained termination head predicts that 1% of steps end the episode."""


class TOLD(nn.Module):
    """The TOLD model of eq. 9.

    :param obs_dim: flat observation size.
    :param action_dim: action size (actions live in [-1, 1]).
    :param latent_dim: size of the latent state ``z``.
    :param encoder_dim: hidden width of the encoder ``h``.
    :param hidden_dim: hidden width of ``d``, ``R``, ``π`` (two layers each) and ``Q``.
    :param termination: add the termination head ``T(z, a)`` (two hidden layers, like ``R``); without it TOLD is
        TD-MPC's model and plans as if no episode ever ended.
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        latent_dim: int = 50,
        encoder_dim: int = 256,
        hidden_dim: int = 512,
        termination: bool = False,
    ):
        super().__init__()
        self.latent_dim, self.action_dim = latent_dim, action_dim
        self.encoder = mlp(obs_dim, [encoder_dim], latent_dim, ELU)
        self.dynamics = mlp(latent_dim + action_dim, [hidden_dim, hidden_dim], latent_dim, ELU)
        self.reward = mlp(latent_dim + action_dim, [hidden_dim, hidden_dim], 1, ELU)
        self.pi = mlp(latent_dim, [hidden_dim, hidden_dim], action_dim, ELU)
        self.q1 = q_network(latent_dim + action_dim, hidden_dim)
        self.q2 = q_network(latent_dim + action_dim, hidden_dim)
        self.termination = mlp(latent_dim + action_dim, [hidden_dim, hidden_dim], 1, ELU) if termination else None
        self.apply(orthogonal_init)
        for net in (self.reward, self.q1, self.q2):
            zero_last_layer(net)
        if self.termination is not None:
            zero_last_layer(self.termination, INITIAL_TERMINATION_LOGIT)

    def encode(self, obs: th.Tensor) -> th.Tensor:
        """Representation ``z = h(s)``."""
        return self.encoder(obs)

    def next(self, z: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """Latent dynamics and reward: ``(d(z, a), R(z, a))``; the reward has shape ``(..., 1)``."""
        za = th.cat([z, action], dim=-1)
        return self.dynamics(za), self.reward(za)

    def next_latent(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Latent dynamics ``d(z, a)`` alone."""
        return self.dynamics(th.cat([z, action], dim=-1))

    def predicted_reward(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Reward ``R(z, a)`` of shape ``(..., 1)``."""
        return self.reward(th.cat([z, action], dim=-1))

    def termination_logit(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Logit of ``P(the step (z, a) ends the episode of M̃)``, shape ``(..., 1)``; needs the termination head."""
        assert self.termination is not None, "TOLD was built without a termination head"
        return self.termination(th.cat([z, action], dim=-1))

    def continuation(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """``1 - P(termination)`` of shape ``(...,)``: ones without a termination head (TD-MPC)."""
        if self.termination is None:
            return th.ones(z.shape[:-1], dtype=z.dtype, device=z.device)
        return th.sigmoid(-self.termination_logit(z, action)).squeeze(-1)

    def policy(self, z: th.Tensor, std: float = 0.0, noise: th.Tensor | None = None) -> th.Tensor:
        """``π(z)`` squashed to [-1, 1]; with ``std > 0`` adds clipped Gaussian exploration noise (TD-MPC).

        :param noise: standard normal draws of the action's shape; drawn here when not given. Passing them makes the
            result a pure function of the inputs (what compiled and eager code must agree on).
        """
        action = th.tanh(self.pi(z))
        if std > 0:
            noise = th.randn_like(action) if noise is None else noise
            action = (action + (noise * std).clamp(-0.3, 0.3)).clamp(-1.0, 1.0)
        return action

    def q(self, z: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """Twin state-action values ``(Q1(z, a), Q2(z, a))``, each of shape ``(B, 1)``."""
        za = th.cat([z, action], dim=-1)
        return self.q1(za), self.q2(za)

    def min_q(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """``min(Q1, Q2)`` — the pessimistic value used by the planner and the policy loss."""
        return th.min(*self.q(z, action))


class TOLDPolicy(BasePolicy):
    """SPPO's policy: the online TOLD model, its EMA target and their optimisers.

    ``predict`` on the policy alone acts with the policy prior ``π(h(s))`` (fast deployment); ``SPPO.predict``
    plans with MPPI and shields.

    :param observation_space: a flat Box observation space.
    :param action_space: a Box action space.
    :param lr_schedule: learning-rate schedule (constant in TD-MPC).
    :param latent_dim: size of ``z``.
    :param encoder_dim: encoder hidden width.
    :param hidden_dim: hidden width of the other networks.
    :param termination: give TOLD its termination head (see :class:`TOLD`); ``SPPO`` sets it from its
        ``termination_model`` argument (False: TD-MPC's model).
    :param normalize_images: SB3's policy argument, saved by ``_get_constructor_parameters``; TOLD's inputs are flat
        state vectors, so it must be False.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        lr_schedule: Any,
        latent_dim: int = 50,
        encoder_dim: int = 256,
        hidden_dim: int = 512,
        *,
        termination: bool,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = False,
    ) -> None:
        if normalize_images:
            raise ValueError("TOLDPolicy encodes flat state vectors, not images: normalize_images must be False.")
        super().__init__(
            observation_space,
            action_space,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            squash_output=True,
            normalize_images=False,
        )
        self.latent_dim, self.encoder_dim, self.hidden_dim = latent_dim, encoder_dim, hidden_dim
        self.termination = termination
        obs_dim = int(spaces.flatdim(observation_space))
        action_dim = get_action_dim(action_space)  # TOLD acts on flat actions, whatever the Box's shape
        self.model = TOLD(obs_dim, action_dim, latent_dim, encoder_dim, hidden_dim, termination)
        self.model_target = copy.deepcopy(self.model)
        self.model_target.requires_grad_(False)
        model_params = [p for name, p in self.model.named_parameters() if not name.startswith("pi.")]
        lr = lr_schedule(1)
        self.optimizer = optimizer_class(model_params, lr=lr, **self.optimizer_kwargs)  # type: ignore[call-arg]
        self.pi_optimizer = optimizer_class(self.model.pi.parameters(), lr=lr, **self.optimizer_kwargs)  # type: ignore[call-arg]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            latent_dim=self.latent_dim,
            encoder_dim=self.encoder_dim,
            hidden_dim=self.hidden_dim,
            termination=self.termination,
            lr_schedule=self._dummy_schedule,
            optimizer_class=self.optimizer_class,
            optimizer_kwargs=self.optimizer_kwargs,
        )
        return data

    @staticmethod
    def _dummy_schedule(_: float) -> float:
        return 0.0

    def forward(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self._predict(obs, deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        """The policy prior ``π(h(s))`` in [-1, 1] (no planning)."""
        assert isinstance(observation, th.Tensor)
        return self.model.policy(self.model.encode(observation.float()))

    def set_training_mode(self, mode: bool) -> None:
        """Only the flag: no TOLD layer (no dropout, no batch norm) behaves differently in training, and walking all
        modules on every env step (SB3 switches modes around each update) costs more than the plan itself."""
        self.training = mode


MlpPolicy = TOLDPolicy
