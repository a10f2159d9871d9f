"""PDO: primal-dual optimisation with PPO as the primal solver ("PPO-Lagrangian").

Chow et al. 2017 / Tessler et al. 2019 / Ray et al. 2019: the constrained problem ``max J_R(π)  s.t.  J_C(π) <= d``
is solved on its Lagrangian ``L(π, λ) = J_R(π) - λ·(J_C(π) - d)``, ``λ >= 0``: a PPO step on ``π`` with the advantage
``(A_R - λ·A_C) / (1 + λ)`` (the ``1 + λ`` keeps its scale as ``λ`` grows), and a projected (dual) gradient step on
``λ``: ``λ ← max(0, λ + η_λ·(J_C - d))``. The paper uses it as its "PDO" baseline ([25], Section V-A.3).

Deviations: none from the scheme; the choices the papers leave open are SB3's PPO (one optimizer for the actor and
the reward critic, minibatch epochs), a cost critic ``V_C`` regressed after the PPO step, and a plain projected
gradient step on ``λ`` driven by the measured mean episode cost (SAILR's authors' PDO steps ``log λ`` with Adam). The
cost limit is the one shared with CPO and CSC (:data:`~sppo_sb3.common.lagrange.DEFAULT_COST_LIMIT`).
"""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sppo_sb3.common.cost_buffer import CostRolloutBuffer
from sppo_sb3.common.cost_policy import CostActorCriticPolicy
from sppo_sb3.common.lagrange import DEFAULT_COST_LIMIT, LagrangianMixin
from sppo_sb3.common.on_policy import SafeOnPolicyMixin
from sppo_sb3.pdo.policies import MlpPolicy

SelfPDO = TypeVar("SelfPDO", bound="PDO")


class PDO(LagrangianMixin, SafeOnPolicyMixin, PPO):
    """PPO-Lagrangian (primal-dual optimisation) with a learned cost critic and cost GAE.

    Costs are read from ``info["cost"]``; the mean episode cost ``J_C`` of each rollout drives the multiplier
    (:class:`~sppo_sb3.common.lagrange.LagrangianMixin`), then PPO optimises the clipped surrogate of
    ``(A_R - λ·A_C) / (1 + λ)`` and the cost critic ``V_C`` is regressed on the cost TD(λ) returns. Every other
    argument is SB3 ``PPO``'s.

    :param policy: the policy model ("MlpPolicy": :class:`~sppo_sb3.common.cost_policy.CostActorCriticPolicy`).
    :param env: the environment (must report ``info["cost"]``), or its registered id.
    :param learning_rate: learning rate of the actor and both critics.
    :param n_steps: steps per env per rollout.
    :param batch_size: minibatch size.
    :param n_epochs: passes over each rollout, for the policy and for the cost critic.
    :param gamma: discount of the reward and of the cost.
    :param gae_lambda: GAE ``λ`` of the reward and of the cost.
    :param clip_range: PPO clipping parameter.
    :param clip_range_vf: clipping of the reward value update (``None``: no clipping).
    :param normalize_advantage: normalise the combined advantage per minibatch.
    :param ent_coef: entropy coefficient.
    :param vf_coef: reward value loss coefficient.
    :param max_grad_norm: gradient clipping norm.
    :param use_sde: generalised state-dependent exploration.
    :param sde_sample_freq: gSDE noise resampling period.
    :param rollout_buffer_class: ``None`` or a subclass of :class:`~sppo_sb3.common.cost_buffer.CostRolloutBuffer`.
    :param rollout_buffer_kwargs: kwargs of the rollout buffer.
    :param target_kl: PPO's early-stopping KL.
    :param cost_limit: the limit ``d`` on the mean episode cost ``J_C`` (on tasks that terminate on a violation, the
        fraction of episodes allowed to end in one).
    :param lagrange_lr: dual step size ``η_λ >= 0``.
    :param lagrange_init: initial multiplier ``λ_0 >= 0``.
    :param stats_window_size: episodes averaged in the rollout logs.
    :param tensorboard_log: TensorBoard log folder (``None``: none).
    :param policy_kwargs: policy kwargs (e.g. ``net_arch``, ``cost_net_arch``).
    :param verbose: 0 none, 1 info, 2 debug.
    :param seed: random seed.
    :param device: torch device.
    :param _init_setup_model: build the networks now.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: CostActorCriticPolicy
    rollout_buffer: CostRolloutBuffer

    def __init__(
        self,
        policy: str | type[CostActorCriticPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 3e-4,
        n_steps: int = 2048,
        batch_size: int = 64,
        n_epochs: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        clip_range_vf: float | Schedule | None = None,
        normalize_advantage: bool = True,
        ent_coef: float = 0.0,
        vf_coef: float = 0.5,
        max_grad_norm: float = 0.5,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        rollout_buffer_class: type[RolloutBuffer] | None = None,
        rollout_buffer_kwargs: dict[str, Any] | None = None,
        target_kl: float | None = None,
        cost_limit: float = DEFAULT_COST_LIMIT,
        lagrange_lr: float = 0.05,
        lagrange_init: float = 0.0,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        self._init_lagrange(cost_limit, lagrange_init, lagrange_lr)
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            batch_size=batch_size,
            n_epochs=n_epochs,
            gamma=gamma,
            gae_lambda=gae_lambda,
            clip_range=clip_range,
            clip_range_vf=clip_range_vf,
            normalize_advantage=normalize_advantage,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=max_grad_norm,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            rollout_buffer_class=rollout_buffer_class,
            rollout_buffer_kwargs=rollout_buffer_kwargs,
            target_kl=target_kl,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self._init_safety()
        if _init_setup_model:
            self._setup_model()

    def train(self) -> None:
        """Dual step on ``λ``, PPO step on ``(A_R - λ·A_C) / (1 + λ)``, then the cost critic's regression."""
        self._train_on_penalised_advantage(self.update_lagrange_multiplier())

    def learn(
        self: SelfPDO,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "PDO",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfPDO:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
