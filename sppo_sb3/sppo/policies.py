"""SPPO's policy: the world model TOLD (:mod:`~sppo_sb3.sppo.world_model`), its EMA target and their optimisers, as an
SB3 policy."""

from __future__ import annotations

import copy
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.type_aliases import PyTorchObs

from sppo_sb3.sppo.world_model import TOLD, TOLDName


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
    :param told: TOLD's variant, ``"paper"`` (TD-MPC's model, the default) or ``"tdmpc2"`` (see :class:`TOLD`);
        ``SPPO`` sets it from its ``told`` argument.
    :param intervention: give TOLD its intervention head (see :class:`TOLD`); ``SPPO`` sets it from its
        ``intervention_target``.
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
        told: TOLDName = "paper",
        intervention: bool = False,
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
        self.termination, self.told, self.intervention = termination, told, intervention
        obs_dim = int(spaces.flatdim(observation_space))
        action_dim = get_action_dim(action_space)  # TOLD acts on flat actions, whatever the Box's shape
        self.model = TOLD(obs_dim, action_dim, latent_dim, encoder_dim, hidden_dim, termination, told, intervention)
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
            told=self.told,
            intervention=self.intervention,
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
