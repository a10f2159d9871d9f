"""Policy of CSC: SB3's Gaussian actor-critic plus a conservative cost critic ``Q_C(s, a)`` and the action sampler.

Bharadhwaj et al., "Conservative Safety Critics for Exploration", ICLR 2021 (the "CSC paper" below).
"""

from __future__ import annotations

import copy
from typing import Any, NamedTuple, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor, create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

# Seed of the generator that draws the fallback candidates of a deterministic ``predict`` (see ``CSCPolicy``).
DETERMINISTIC_SAMPLER_SEED = 0


class RejectionSample(NamedTuple):
    """Result of :func:`rejection_sample_actions`.

    :param actions: ``(n_envs, action_dim)`` the executed candidates.
    :param sample_index: ``(n_envs,)`` which candidate was executed.
    :param first_rejected: ``(n_envs,)`` whether the first candidate had ``Q_C > threshold`` (an "intervention").
    :param admissible: ``(n_envs,)`` whether any candidate had ``Q_C <= threshold`` (else the argmin was executed).
    :param q_value: ``(n_envs,)`` ``Q_C`` of the executed candidates.
    """

    actions: th.Tensor
    sample_index: th.Tensor
    first_rejected: th.Tensor
    admissible: th.Tensor
    q_value: th.Tensor


def rejection_sample_actions(candidates: th.Tensor, q_values: th.Tensor, threshold: float) -> RejectionSample:
    """The action-rejection step of the CSC paper (Alg. 1): execute ``a ~ π(·|s)`` only if ``Q_C(s, a) <= ε``, else
    resample, up to ``n_samples`` times; if no sample is admissible, execute the one with the lowest ``Q_C``.

    All samples are drawn up front and the first admissible one is taken, which has the same distribution as
    resampling one at a time, with no Python loop over samples or envs.

    :param candidates: ``(n_samples, n_envs, action_dim)`` i.i.d. samples of ``π(·|s)`` per env, in sampling order.
    :param q_values: ``(n_samples, n_envs)`` ``Q_C(s, candidate)``.
    :param threshold: the admissibility threshold ``ε`` on ``Q_C``.
    :return: a :class:`RejectionSample`.
    """
    if candidates.ndim != 3 or q_values.shape != candidates.shape[:2]:
        raise ValueError(
            f"Expected candidates (n_samples, n_envs, action_dim) and q_values (n_samples, n_envs), got "
            f"{tuple(candidates.shape)} and {tuple(q_values.shape)}"
        )
    admissible = q_values <= threshold
    any_admissible = admissible.any(dim=0)
    # argmax returns the first maximal index: the first admissible sample
    first_admissible = admissible.to(th.uint8).argmax(dim=0)
    index = th.where(any_admissible, first_admissible, q_values.argmin(dim=0))
    n_envs, action_dim = candidates.shape[1:]
    actions = candidates.gather(0, index.view(1, n_envs, 1).expand(1, n_envs, action_dim))[0]
    q_value = q_values.gather(0, index.view(1, n_envs))[0]
    return RejectionSample(actions, index, ~admissible[0], any_admissible, q_value)


class CostCritic(nn.Module):
    """``Q_C(s, a) = q_max · sigmoid(f(s, a))``: a bounded, non-negative estimate of the discounted cost-to-go.

    Bounding the critic keeps the CQL push-up of the CSC paper's eq. 2 finite on actions far from the data.

    :param features_dim: size of the observation features.
    :param action_dim: size of the (normalised, [-1, 1]) action.
    :param net_arch: hidden layer sizes.
    :param activation_fn: activation between hidden layers.
    :param q_max: upper bound of ``Q_C``.
    :param init_value: value of ``Q_C`` at initialisation, as a fraction of ``q_max`` (small: an untrained critic
        lets the policy's samples through instead of forcing the argmin everywhere).
    """

    def __init__(
        self,
        features_dim: int,
        action_dim: int,
        net_arch: list[int],
        activation_fn: type[nn.Module],
        q_max: float,
        init_value: float = 0.05,
    ) -> None:
        super().__init__()
        layers = create_mlp(features_dim + action_dim, 1, net_arch, activation_fn)
        self.net = nn.Sequential(*layers)
        self.q_max = q_max
        last = self.net[-1]
        assert isinstance(last, nn.Linear)
        nn.init.uniform_(last.weight, -3e-3, 3e-3)
        nn.init.constant_(last.bias, float(np.log(init_value / (1.0 - init_value))))

    def forward(self, features: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """:return: ``Q_C`` with the leading shape of ``actions`` (features broadcast over leading sample dims)."""
        features = features.expand(*actions.shape[:-1], features.shape[-1])
        return self.q_max * th.sigmoid(self.net(th.cat([features, actions], dim=-1)).squeeze(-1))


class CSCPolicy(ActorCriticPolicy):
    """Actor-critic policy (SB3's ``MlpPolicy``) with a conservative cost critic and a target copy of it.

    The actor, the reward value head and their optimizer are exactly SB3's. The cost critic has its own features
    extractor and optimizer (``cost_optimizer``), and sees actions clipped to the Box and rescaled to [-1, 1].

    ``predict`` applies the rejection sampler when ``reject_in_predict`` is set: with ``deterministic=True`` the
    mean action is the first candidate and the fallback candidates are drawn from a generator with a fixed seed,
    so the deterministic action stays a function of the observation and the weights.

    :param use_sde: must be False (gSDE is not supported); accepted because SB3's on-policy setup passes it.
    :param cost_net_arch: hidden layer sizes of the cost critic (default: ``[64, 64]``).
    :param cost_critic_max: upper bound ``q_max`` of ``Q_C``: 1 fits a 0/1 failure indicator that ends the
        episode (the CSC paper's setting and ``SafePointCircle-v0``); use ``c_max / (1 - gamma)`` otherwise.
    :param cost_threshold: admissibility threshold ``ε`` of the sampler.
    :param n_action_samples: the most candidates drawn per state (100 in the CSC paper).
    :param reject_in_predict: whether ``predict`` applies the sampler.
    :param cost_learning_rate: learning rate of the cost critic's optimizer.
    :param cost_init_value: ``Q_C`` at initialisation as a fraction of ``cost_critic_max`` (below the threshold,
        so that an untrained critic lets the policy's first sample through rather than forcing the argmin).
    See SB3's ``ActorCriticPolicy`` for the other parameters.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.Tanh,
        ortho_init: bool = True,
        use_sde: bool = False,
        log_std_init: float = 0.0,
        features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        share_features_extractor: bool = True,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        cost_net_arch: list[int] | None = None,
        cost_critic_max: float = 1.0,
        cost_threshold: float = 0.1,
        n_action_samples: int = 100,
        reject_in_predict: bool = True,
        cost_learning_rate: float = 1e-3,
        cost_init_value: float = 0.05,
    ) -> None:
        if (
            not isinstance(action_space, spaces.Box)
            or not np.all(np.isfinite(action_space.low))
            or not np.all(np.isfinite(action_space.high))
        ):
            raise ValueError(
                f"CSC needs a Box action space with finite bounds (its cost critic sees actions rescaled to [-1, 1]), "
                f"got {action_space}. Clip or rescale the actions with a wrapper (e.g. gymnasium.wrappers.RescaleAction)."
            )
        if use_sde:
            raise ValueError("CSC does not support gSDE (use_sde=True): its sampler draws i.i.d. Gaussian actions.")
        if n_action_samples < 1:
            raise ValueError(f"n_action_samples must be >= 1, got {n_action_samples}")
        self.cost_net_arch = [64, 64] if cost_net_arch is None else list(cost_net_arch)
        self.cost_critic_max = cost_critic_max
        self.cost_threshold = cost_threshold
        self.n_action_samples = n_action_samples
        self.reject_in_predict = reject_in_predict
        self.cost_learning_rate = cost_learning_rate
        if not 0.0 < cost_init_value < 1.0:
            raise ValueError(f"cost_init_value is a fraction of cost_critic_max in (0, 1), got {cost_init_value}")
        self.cost_init_value = cost_init_value
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=net_arch,
            activation_fn=activation_fn,
            ortho_init=ortho_init,
            log_std_init=log_std_init,
            features_extractor_class=features_extractor_class,
            features_extractor_kwargs=features_extractor_kwargs,
            share_features_extractor=share_features_extractor,
            normalize_images=normalize_images,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
        )
        assert isinstance(self.action_dist, DiagGaussianDistribution)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)  # actor, value head and ``self.optimizer`` (without the cost critic)
        assert isinstance(self.action_space, spaces.Box)
        # copies (th.tensor, not th.as_tensor): set_parameters/load must not write into the env's action space;
        # flat, as the Gaussian's actions are (``(..., action_dim)`` also for a Box of shape (2, 2))
        self.register_buffer("action_low", th.tensor(self.action_space.low.reshape(-1), dtype=th.float32))
        self.register_buffer("action_high", th.tensor(self.action_space.high.reshape(-1), dtype=th.float32))
        self.cost_features_extractor = self.make_features_extractor()
        action_dim = int(np.prod(self.action_space.shape))
        self.cost_critic = CostCritic(
            self.cost_features_extractor.features_dim,
            action_dim,
            self.cost_net_arch,
            nn.ReLU,
            self.cost_critic_max,
            self.cost_init_value,
        )
        self.cost_critic_target = copy.deepcopy(self.cost_critic)
        self.cost_critic_target.requires_grad_(False)
        cost_params = list(self.cost_features_extractor.parameters()) + list(self.cost_critic.parameters())
        self.cost_optimizer = self.optimizer_class(cost_params, lr=self.cost_learning_rate, **self.optimizer_kwargs)  # type: ignore[call-arg]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        for key in ("squash_output", "full_std", "use_expln"):
            data.pop(key, None)
        data.update(
            cost_net_arch=self.cost_net_arch,
            cost_critic_max=self.cost_critic_max,
            cost_threshold=self.cost_threshold,
            n_action_samples=self.n_action_samples,
            reject_in_predict=self.reject_in_predict,
            cost_learning_rate=self.cost_learning_rate,
            cost_init_value=self.cost_init_value,
            share_features_extractor=self.share_features_extractor,
        )
        return data

    def set_training_mode(self, mode: bool) -> None:
        super().set_training_mode(mode)
        self.cost_critic_target.train(False)

    @staticmethod
    def gaussian(distribution: Any) -> th.distributions.Normal:
        """The diagonal Gaussian ``π(·|s)`` behind SB3's action distribution."""
        gaussian = distribution.distribution
        assert isinstance(gaussian, th.distributions.Normal), "CSC needs a Gaussian policy on a Box action space"
        return gaussian

    def normalize_actions(self, actions: th.Tensor) -> th.Tensor:
        """Clip raw policy actions to the Box and rescale them to [-1, 1], the cost critic's action input.

        :param actions: ``(..., action_dim)`` flat actions, as the policy's distribution samples them.
        """
        low, high = cast(th.Tensor, self.action_low), cast(th.Tensor, self.action_high)
        actions = actions.to(low.dtype)  # the critic is float32, whatever the action space's dtype (e.g. float64)
        return 2.0 * (th.clamp(actions, low, high) - low) / (high - low) - 1.0

    def cost_features(self, obs: PyTorchObs) -> th.Tensor:
        """Observation features of the cost critic, ``(batch, features_dim)``."""
        return BaseModel.extract_features(self, obs, self.cost_features_extractor)  # type: ignore[return-value]

    def cost_values(self, obs: PyTorchObs, normalized_actions: th.Tensor, target: bool = False) -> th.Tensor:
        """``Q_C(s, a)`` for ``normalized_actions`` of shape ``(*sample_dims, batch, action_dim)``.

        :param target: use the target critic ``Q_C⁻`` of the Bellman backup.
        """
        critic = self.cost_critic_target if target else self.cost_critic
        return critic(self.cost_features(obs), normalized_actions)

    def draw_candidates(self, mean: th.Tensor, std: th.Tensor, n_samples: int, deterministic: bool) -> th.Tensor:
        """``n_samples`` raw actions per state from ``N(mean, std²)``, ``(n_samples, batch, action_dim)``.

        With ``deterministic`` the first candidate is the mean and the others come from a fixed-seed generator.
        """
        shape = (n_samples, *mean.shape)
        if not deterministic:
            return mean + std * th.randn(shape, device=mean.device)
        generator = th.Generator(device=mean.device).manual_seed(DETERMINISTIC_SAMPLER_SEED)
        noise = th.randn(shape, device=mean.device, generator=generator)
        noise[0] = 0.0
        return mean + std * noise

    def sample_safe_actions(
        self, obs: PyTorchObs, deterministic: bool = False, threshold: float | None = None, n_samples: int | None = None
    ) -> tuple[RejectionSample, Any]:
        """Draw candidates from ``π(·|s)``, score them with ``Q_C`` and pick with :func:`rejection_sample_actions`.

        :return: the sample (raw, unclipped actions) and the action distribution ``π(·|s)``.
        """
        distribution = self.get_distribution(obs)
        gaussian = self.gaussian(distribution)
        n_samples = self.n_action_samples if n_samples is None else n_samples
        candidates = self.draw_candidates(gaussian.mean, gaussian.stddev, n_samples, deterministic)
        q_values = self.cost_values(obs, self.normalize_actions(candidates))
        threshold = self.cost_threshold if threshold is None else threshold
        return rejection_sample_actions(candidates, q_values, threshold), distribution

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        if not self.reject_in_predict:
            return super()._predict(observation, deterministic)
        return self.sample_safe_actions(observation, deterministic)[0].actions
