"""SACLag: SAC on the Lagrangian of the constrained problem, with a learned cost critic (OmniSafe's SACLag baseline).

The CMDP ``max_π J_R(π)  s.t.  J_C(π) <= d`` of the paper's Section II-B is solved on its Lagrangian
``L(π, λ) = J_R(π) - λ·(J_C(π) - d)``, ``λ >= 0``, with SB3's SAC as the primal solver:

- a cost critic ``Q_C(s, a)`` regressed, as SAC's reward critics are, on the Bellman target
  ``c + γ_C (1 - done) Q_C'(s', a')`` with ``a' ~ π(·|s')`` and its own Polyak-averaged target ``Q_C'``
  (:func:`td_target`; no entropy term: ``Q_C`` is the discounted cost alone);
- the actor loss ``E[α log π(a|s) - min_i Q_i(s, a) + λ·Q_C(s, a)] / (1 + λ)``, ``a ~ π(·|s)`` reparameterised
  (:func:`lagrangian_actor_loss`): SAC's entropy-regularised loss plus the penalty, scaled so that its size does not
  grow with ``λ``;
- before each round of gradient steps, one projected dual step ``λ ← max(0, λ + η_λ·(J_C - d))``
  (:class:`~sppo_sb3.common.lagrange.LagrangianMixin`, shared with PDO and CSC) on the measured mean cost ``J_C`` of
  the last ``cost_window`` finished episodes (:meth:`EpisodeCostTracker.recent_estimate`).

Everything else (entropy coefficient, reward critics, replay, warm-up, targets) is SB3's ``SAC``. The deviations from
OmniSafe's SACLag are listed in ``docs/modules/saclag.md``.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy, ContinuousCritic
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, PyTorchObs, Schedule
from stable_baselines3.common.utils import get_parameters_by_name, polyak_update
from torch.nn import functional as F

from sppo_sb3.common.cost_buffer import CostReplayBuffer, CostReplayBufferSamples, cost_buffer_class
from sppo_sb3.common.keys import N_UPDATES_LOG_KEY, TRAIN_LOG_PREFIX
from sppo_sb3.common.lagrange import DEFAULT_COST_LIMIT, LagrangianMixin
from sppo_sb3.common.safety import SafetyTrackingMixin
from sppo_sb3.saclag.policies import MlpPolicy, SACLagPolicy

SelfSACLag = TypeVar("SelfSACLag", bound="SACLag")

__all__ = ["SACLag", "fit_q_networks", "lagrangian_actor_loss", "td_target"]


def td_target(signal: th.Tensor, dones: th.Tensor, next_values: th.Tensor, discount: float) -> th.Tensor:
    """The one-step Bellman target ``signal + discount·(1 - done)·next_value`` (reward or cost), ``(batch, 1)``.

    :param signal: ``(batch, 1)`` rewards, or costs ``c``.
    :param dones: ``(batch, 1)`` 1 where the episode terminated (not where a time limit cut it: those bootstrap).
    :param next_values: ``(batch, 1)`` the target critic's value of ``(s', a')``.
    :param discount: ``γ`` (rewards) or ``γ_C`` (costs).
    """
    return signal + discount * (1.0 - dones) * next_values


def lagrangian_actor_loss(
    entropy_term: th.Tensor, reward_q: th.Tensor, cost_q: th.Tensor, lagrange_multiplier: float
) -> th.Tensor:
    """SACLag's actor loss ``mean(α log π - Q_R + λ·Q_C) / (1 + λ)`` on actions drawn from ``π`` (reparameterised).

    :param entropy_term: ``(batch, 1)`` ``α·log π(a|s)``.
    :param reward_q: ``(batch, 1)`` ``min_i Q_i(s, a)`` of the reward critics.
    :param cost_q: ``(batch, 1)`` ``Q_C(s, a)``.
    :param lagrange_multiplier: ``λ >= 0``.
    """
    lam = lagrange_multiplier
    return ((entropy_term - reward_q + lam * cost_q) / (1.0 + lam)).mean()


def fit_q_networks(critic: ContinuousCritic, obs: PyTorchObs, actions: th.Tensor, target: th.Tensor) -> float:
    """One gradient step of every Q-network of ``critic`` on ``½·Σ_i MSE(Q_i(s, a), target)`` (SB3's SAC critic loss).

    :param critic: the critic, with its ``optimizer``.
    :param obs: observations.
    :param actions: the executed actions, scaled to [-1, 1].
    :param target: ``(batch, 1)`` Bellman target (no gradient).
    :return: the loss before the step.
    """
    loss = 0.5 * sum(F.mse_loss(q_values, target) for q_values in critic(obs, actions))
    assert isinstance(loss, th.Tensor)
    critic.optimizer.zero_grad()
    loss.backward()
    critic.optimizer.step()
    return loss.item()


class SACLag(LagrangianMixin, SafetyTrackingMixin, SAC):
    """SAC-Lagrangian: SB3's SAC with a cost critic ``Q_C`` and a Lagrange multiplier ``λ`` on an episode-cost limit.

    Costs are read from ``info["cost"]`` (``MissingCostError`` otherwise) into the replay buffer
    (:class:`~sppo_sb3.common.cost_buffer.CostReplayBuffer`); ``self.safety_metrics`` is fed every env step and logged
    under ``safety/``. Each call of :meth:`train` takes one dual step on ``λ``, then ``gradient_steps`` steps of the
    reward critics, the cost critic and the actor on ``(α log π - Q_R + λ·Q_C) / (1 + λ)``. Every argument not listed
    under the cost is SB3 ``SAC``'s; SAC's n-step returns (``n_steps``) and ``HerReplayBuffer`` are not supported.

    :param policy: the policy model ("MlpPolicy": :class:`~sppo_sb3.saclag.policies.SACLagPolicy`).
    :param env: the environment (must report ``info["cost"]``; Box actions), or its registered id.
    :param learning_rate: learning rate of the actor, the reward critics, the cost critic and the entropy coefficient.
    :param buffer_size: capacity of the replay buffer (transitions).
    :param learning_starts: env steps of uniformly random actions before learning starts.
    :param batch_size: minibatch size of every gradient step.
    :param tau: Polyak coefficient of the target critics (reward and cost).
    :param gamma: discount of the rewards.
    :param train_freq: train every ``train_freq`` env steps (or ``(n, "episode")``).
    :param gradient_steps: gradient steps per training round (-1: as many as env steps collected).
    :param action_noise: extra exploration noise (``None``: none).
    :param replay_buffer_class: ``None`` or a subclass of :class:`~sppo_sb3.common.cost_buffer.CostReplayBuffer`.
    :param replay_buffer_kwargs: kwargs of the replay buffer.
    :param optimize_memory_usage: SB3's memory-efficient replay buffer (needs
        ``replay_buffer_kwargs=dict(handle_timeout_termination=False)``).
    :param ent_coef: entropy coefficient ``α`` ("auto": learned towards ``target_entropy``; "auto_0.1": from 0.1).
    :param target_update_interval: update the target critics every this many gradient steps.
    :param target_entropy: target entropy of the learned ``α`` ("auto": ``-dim(A)``).
    :param use_sde: generalised state-dependent exploration.
    :param sde_sample_freq: gSDE noise resampling period.
    :param use_sde_at_warmup: gSDE instead of uniform actions before ``learning_starts``.
    :param cost_limit: the limit ``d`` on the mean episode cost ``J_C`` (on tasks that end an episode at its first
        violation, the fraction of episodes allowed to end in one; on the velocity tasks, violating steps per episode).
    :param cost_gamma: discount ``γ_C`` of the cost critic's target (``None``: ``gamma``).
    :param lagrange_lr: dual step size ``η_λ >= 0``, per training round (0 keeps ``λ`` at ``lagrange_init``).
    :param lagrange_init: initial multiplier ``λ_0 >= 0``.
    :param cost_window: finished episodes whose mean cost is the ``J_C`` of the dual step.
    :param stats_window_size: episodes averaged in the rollout logs and the ``safety/ep_*_mean`` values.
    :param tensorboard_log: TensorBoard log folder (``None``: none).
    :param policy_kwargs: policy kwargs (e.g. ``net_arch``, ``cost_net_arch``, ``n_cost_critics``).
    :param verbose: 0 none, 1 info, 2 debug.
    :param seed: random seed.
    :param device: torch device.
    :param _init_setup_model: build the networks now.
    :raises ValueError: on a negative ``cost_limit``, ``lagrange_lr`` or ``lagrange_init``, a ``cost_gamma`` outside
        [0, 1] or a ``cost_window`` below 1.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: SACLagPolicy
    replay_buffer: CostReplayBuffer
    cost_critic: ContinuousCritic
    cost_critic_target: ContinuousCritic

    def __init__(
        self,
        policy: str | type[SACLagPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 3e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 100,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        ent_coef: str | float = "auto",
        target_update_interval: int = 1,
        target_entropy: str | float = "auto",
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        use_sde_at_warmup: bool = False,
        cost_limit: float = DEFAULT_COST_LIMIT,
        cost_gamma: float | None = None,
        lagrange_lr: float = 1e-4,
        lagrange_init: float = 0.0,
        cost_window: int = 10,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        self._init_lagrange(cost_limit, lagrange_init, lagrange_lr)
        self.cost_gamma = check_cost_settings(gamma, cost_gamma, cost_window)
        self.cost_window = cost_window
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            ent_coef=ent_coef,
            target_update_interval=target_update_interval,
            target_entropy=target_entropy,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            use_sde_at_warmup=use_sde_at_warmup,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self._init_safety(metrics_window=stats_window_size, cost_window=cost_window)
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up
    def _setup_model(self) -> None:
        given = self.replay_buffer_class
        self.replay_buffer_class = cost_buffer_class(given, CostReplayBuffer, "SACLag", "replay_buffer_class")
        if not issubclass(self.policy_class, SACLagPolicy):
            raise TypeError(
                f"SACLag learns a cost critic: its policy must be a SACLagPolicy (use 'MlpPolicy' or subclass "
                f"sppo_sb3.saclag.SACLagPolicy), got {self.policy_class.__name__}."
            )
        super()._setup_model()
        self.cost_batch_norm_stats = get_parameters_by_name(self.cost_critic, ["running_"])
        self.cost_batch_norm_stats_target = get_parameters_by_name(self.cost_critic_target, ["running_"])

    def _create_aliases(self) -> None:
        super()._create_aliases()
        self.cost_critic = self.policy.cost_critic
        self.cost_critic_target = self.policy.cost_critic_target

    # ------------------------------------------------------------------ collecting
    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: np.ndarray | dict[str, np.ndarray],
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """SB3's storage of the step (the replay buffer reads its cost), after feeding it to the safety metrics."""
        self._record_safety(reward, dones, infos)
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)

    def measured_episode_cost(self) -> float:
        """``J_C``: the mean cost of the last ``cost_window`` finished episodes (before any ends, of the running ones)."""
        return self.cost_tracker.recent_estimate()

    # ------------------------------------------------------------------ training
    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """One dual step on ``λ``, then ``gradient_steps`` steps of the critics and the actor (:meth:`_gradient_step`)."""
        lam = self.update_lagrange_multiplier()
        self.cost_tracker.start_rollout()  # only the window is read: keep the tracker's per-rollout list short
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer, self.cost_critic.optimizer]
        self._update_learning_rate(optimizers if self.ent_coef_optimizer is None else [*optimizers, self.ent_coef_optimizer])
        stats: dict[str, list[float]] = defaultdict(list)
        for gradient_step in range(gradient_steps):
            for key, value in self._gradient_step(batch_size, lam).items():
                stats[key].append(value)
            if gradient_step % self.target_update_interval == 0:
                self._update_targets()
        self._n_updates += gradient_steps
        self.logger.record(N_UPDATES_LOG_KEY, self._n_updates, exclude="tensorboard")
        for key, values in stats.items():
            self.logger.record(f"{TRAIN_LOG_PREFIX}{key}", float(np.mean(values)))

    def _gradient_step(self, batch_size: int, lagrange_multiplier: float) -> dict[str, float]:
        """Entropy coefficient, reward critics, cost critic, then the actor, on one minibatch.

        :return: the step's statistics, by log name.
        """
        data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
        if self.use_sde:
            self.actor.reset_noise()
        actions_pi, log_prob = self.actor.action_log_prob(data.observations)
        log_prob = log_prob.reshape(-1, 1)
        ent_coef, stats = self._entropy_coefficient(log_prob)
        reward_target, cost_target = self._bellman_targets(data, ent_coef)
        stats["critic_loss"] = fit_q_networks(self.critic, data.observations, data.actions, reward_target)
        stats["cost_critic_loss"] = fit_q_networks(self.cost_critic, data.observations, data.actions, cost_target)
        reward_q = th.cat(self.critic(data.observations, actions_pi), dim=1).min(dim=1, keepdim=True).values
        cost_q = self.policy.cost_value(data.observations, actions_pi)
        actor_loss = lagrangian_actor_loss(ent_coef * log_prob, reward_q, cost_q, lagrange_multiplier)
        self.actor.optimizer.zero_grad()
        actor_loss.backward()
        self.actor.optimizer.step()
        return {**stats, "actor_loss": actor_loss.item(), "cost_q": cost_q.mean().item()}

    def _entropy_coefficient(self, log_prob: th.Tensor) -> tuple[th.Tensor, dict[str, float]]:
        """SAC's ``α`` for this step; when it is learned, one step of its loss ``-log α·(log π + H_target)``.

        :param log_prob: ``(batch, 1)`` ``log π(a|s)`` of the actor's actions.
        :return: ``α`` (no gradient) and its statistics.
        """
        if self.ent_coef_optimizer is None or self.log_ent_coef is None:
            return self.ent_coef_tensor, {"ent_coef": self.ent_coef_tensor.item()}
        ent_coef = th.exp(self.log_ent_coef.detach())
        assert isinstance(self.target_entropy, float)
        loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
        self.ent_coef_optimizer.zero_grad()
        loss.backward()
        self.ent_coef_optimizer.step()
        return ent_coef, {"ent_coef": ent_coef.item(), "ent_coef_loss": loss.item()}

    def _bellman_targets(self, data: CostReplayBufferSamples, ent_coef: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """The reward critics' soft target and the cost critic's target, on the same next action ``a' ~ π(·|s')``.

        :return: ``r + γ(1 - done)(min_i Q_i'(s', a') - α log π(a'|s'))`` and ``c + γ_C(1 - done) Q_C'(s', a')``.
        """
        with th.no_grad():
            next_actions, next_log_prob = self.actor.action_log_prob(data.next_observations)
            next_q = th.cat(self.critic_target(data.next_observations, next_actions), dim=1).min(dim=1, keepdim=True).values
            soft_next_q = next_q - ent_coef * next_log_prob.reshape(-1, 1)
            next_cost_q = self.policy.cost_value(data.next_observations, next_actions, target=True)
            return (
                td_target(data.rewards, data.dones, soft_next_q, self.gamma),
                td_target(data.costs, data.dones, next_cost_q, self.cost_gamma),
            )

    def _update_targets(self) -> None:
        """Polyak steps of the reward and cost target critics (batch-norm statistics copied, as SB3's SAC does)."""
        polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
        polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)
        polyak_update(self.cost_critic.parameters(), self.cost_critic_target.parameters(), self.tau)
        polyak_update(self.cost_batch_norm_stats, self.cost_batch_norm_stats_target, 1.0)

    # ------------------------------------------------------------------ logging, learning, persistence
    def dump_logs(self) -> None:
        """Write the ``safety/`` figures and the measured episode cost, then SB3's logs."""
        self._record_safety_logs()
        super().dump_logs()

    def learn(
        self: SelfSACLag,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "SACLag",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfSACLag:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _excluded_save_params(self) -> list[str]:
        aliases = ["cost_critic", "cost_critic_target", "cost_batch_norm_stats", "cost_batch_norm_stats_target"]
        return [*super()._excluded_save_params(), *aliases]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "cost_critic.optimizer"], variables


def check_cost_settings(gamma: float, cost_gamma: float | None, cost_window: int) -> float:
    """Check the cost critic's discount and the dual step's window.

    :param gamma: the reward discount.
    :param cost_gamma: ``γ_C`` (``None``: ``gamma``).
    :param cost_window: finished episodes averaged into ``J_C``.
    :return: ``γ_C``.
    :raises ValueError: on ``γ_C`` outside [0, 1] or ``cost_window < 1``.
    """
    cost_gamma = gamma if cost_gamma is None else cost_gamma
    if not 0.0 <= cost_gamma <= 1.0:
        raise ValueError(f"cost_gamma is a discount in [0, 1], got {cost_gamma}")
    if cost_window < 1:
        raise ValueError(f"cost_window must be >= 1 (finished episodes averaged into J_C), got {cost_window}")
    return cost_gamma
