"""CPO: Constrained Policy Optimization (Achiam, Held, Tamar & Abbeel, ICML 2017).

Each update solves the trust-region problem of Achiam et al.'s eq. 10 around the current parameters ``θ_k``
(``x = θ - θ_k``)::

    max_x  gᵀx    s.t.   c + bᵀx <= 0,   ½ xᵀHx <= δ

with ``g`` the gradient of the reward surrogate, ``b`` the gradient of the cost surrogate, ``H`` the Fisher matrix
(the KL's Hessian) and ``c = J_C(π_k) - d`` the constraint value. Its dual (Achiam's Appendix 10.2) is solved in
closed form by :func:`cpo_dual_solution`; the step is then checked by a backtracking line search on the true
KL, surrogate improvement and surrogate cost. When no point of the trust region satisfies the linearised constraint,
the update is the recovery step that decreases the cost the most: ``x = -sqrt(2δ / s)·H⁻¹b``.

The conjugate-gradient solver, the Fisher-vector product and the actor/KL gradients are sb3-contrib TRPO's.

Deviations from Achiam et al.: the reward and cost critics are regressed by Adam minibatches after each step (as
sb3-contrib's TRPO fits its critic), the constraint value ``c`` is the measured mean episode cost of the rollout's
finished episodes minus ``d`` (scaled per step for the surrogate), and no cost shaping is added. The cost limit is
the one shared with PDO and CSC (:data:`~sppo_sb3.common.lagrange.DEFAULT_COST_LIMIT`).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar, TypeVar

import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from sb3_contrib.common.utils import conjugate_gradient_solver, flat_grad
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.distributions import Distribution, kl_divergence
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import explained_variance

from sppo_sb3.common.cost_buffer import CostRolloutBuffer
from sppo_sb3.common.cost_policy import CostActorCriticPolicy, fit_critics
from sppo_sb3.common.keys import N_UPDATES_LOG_KEY
from sppo_sb3.common.lagrange import DEFAULT_COST_LIMIT
from sppo_sb3.common.on_policy import SafeOnPolicyMixin
from sppo_sb3.cpo.dual import CPO_CASES, CPOSolution, cpo_dual_solution
from sppo_sb3.cpo.policies import MlpPolicy

SelfCPO = TypeVar("SelfCPO", bound="CPO")


@dataclass(frozen=True)
class CPOBatch:
    """The rollout one CPO step is computed on, and the policy ``π_k`` that collected it.

    :param observations: observations (every ``sub_sampling_factor``-th sample of the rollout).
    :param actions: the actions taken (``long`` and flat for a ``Discrete`` action space).
    :param old_log_prob: ``log π_k(a|s)`` recorded in the rollout.
    :param advantages: reward advantages ``A`` (normalised if ``normalize_advantage``).
    :param cost_advantages: cost advantages ``A_C``, centred only (their scale must match ``c``).
    :param old_distribution: ``π_k``'s action distribution on ``observations``, without gradient.
    """

    observations: th.Tensor
    actions: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    cost_advantages: th.Tensor
    old_distribution: Distribution


@dataclass(frozen=True)
class CPOSurrogates:
    """The surrogates of the CPO update (Achiam et al. 2017, Section 5) at some parameters ``θ``, as 0-d tensors.

    :param reward: reward surrogate ``E[ratio·A]`` (``ratio = π_θ(a|s) / π_k(a|s)``).
    :param cost: cost surrogate ``E[ratio·A_C]``.
    :param kl: mean KL divergence ``D̄_KL(π_θ ‖ π_k)``.
    """

    reward: th.Tensor
    cost: th.Tensor
    kl: th.Tensor


class CPO(SafeOnPolicyMixin, TRPO):
    """Constrained Policy Optimization: TRPO's natural-gradient step with a linearised cost constraint.

    Each rollout: the measured mean episode cost ``J_C`` gives the constraint value ``c = (J_C - d) / T̄`` (``T̄``:
    mean episode length, which puts ``c`` in the per-step units of the cost surrogate ``E[ratio·A_C]``); ``g`` and
    ``b`` are the gradients of the reward and cost surrogates; ``H⁻¹g`` and ``H⁻¹b`` come from TRPO's conjugate
    gradient; :func:`cpo_dual_solution` gives the step; a backtracking line search accepts it when the KL is within
    ``target_kl``, the surrogate cost change is at most ``max(0, -c)`` and (unless recovering) the reward surrogate
    improves. Then ``V`` and ``V_C`` are regressed on their TD(λ) returns. Every other argument is sb3-contrib
    ``TRPO``'s.

    :param policy: the policy model ("MlpPolicy": :class:`~sppo_sb3.common.cost_policy.CostActorCriticPolicy`).
    :param env: the environment (must report ``info["cost"]``), or its registered id.
    :param learning_rate: learning rate of the two critics.
    :param n_steps: steps per env per rollout.
    :param batch_size: minibatch size of the critics' regression.
    :param gamma: discount of the reward and of the cost.
    :param cg_max_steps: conjugate-gradient iterations (for ``H⁻¹g`` and for ``H⁻¹b``).
    :param cg_damping: damping added to the Fisher-vector product.
    :param line_search_shrinking_factor: step shrinking factor of the line search.
    :param line_search_max_iter: line search iterations.
    :param n_critic_updates: passes of the critics' regression per rollout.
    :param gae_lambda: GAE ``λ`` of the reward and of the cost.
    :param use_sde: generalised state-dependent exploration.
    :param sde_sample_freq: gSDE noise resampling period.
    :param rollout_buffer_class: ``None`` or a subclass of :class:`~sppo_sb3.common.cost_buffer.CostRolloutBuffer`.
    :param rollout_buffer_kwargs: kwargs of the rollout buffer.
    :param normalize_advantage: normalise the reward advantage (the cost advantage is only centred, its scale
        must match ``c``).
    :param target_kl: trust-region size ``δ`` (``½ xᵀHx <= δ``, KL checked by the line search).
    :param sub_sampling_factor: use every k-th sample for the policy step.
    :param cost_limit: the limit ``d`` on the mean episode cost ``J_C`` (on tasks that terminate on a violation, the
        fraction of episodes allowed to end in one).
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
        learning_rate: float | Schedule = 1e-3,
        n_steps: int = 2048,
        batch_size: int = 128,
        gamma: float = 0.99,
        cg_max_steps: int = 15,
        cg_damping: float = 0.1,
        line_search_shrinking_factor: float = 0.8,
        line_search_max_iter: int = 10,
        n_critic_updates: int = 10,
        gae_lambda: float = 0.95,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        rollout_buffer_class: type[RolloutBuffer] | None = None,
        rollout_buffer_kwargs: dict[str, Any] | None = None,
        normalize_advantage: bool = True,
        target_kl: float = 0.01,
        sub_sampling_factor: int = 1,
        cost_limit: float = DEFAULT_COST_LIMIT,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            batch_size=batch_size,
            gamma=gamma,
            cg_max_steps=cg_max_steps,
            cg_damping=cg_damping,
            line_search_shrinking_factor=line_search_shrinking_factor,
            line_search_max_iter=line_search_max_iter,
            n_critic_updates=n_critic_updates,
            gae_lambda=gae_lambda,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            rollout_buffer_class=rollout_buffer_class,
            rollout_buffer_kwargs=rollout_buffer_kwargs,
            normalize_advantage=normalize_advantage,
            target_kl=target_kl,
            sub_sampling_factor=sub_sampling_factor,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.cost_limit = cost_limit
        self.last_solution: CPOSolution | None = None
        self._init_safety()
        if _init_setup_model:
            self._setup_model()

    def constraint_value(self) -> float:
        """``c = (J_C - d) / T̄``: the measured constraint value, in the per-step units of the cost surrogate."""
        return (self.cost_tracker.estimate() - self.cost_limit) / self.cost_tracker.mean_length()

    def _apply_step(self, params: list[th.nn.Parameter], originals: list[th.Tensor], step: th.Tensor) -> None:
        """Set ``params`` to ``originals + step``.

        :param params: the parameters to set.
        :param originals: their values at ``θ_k``.
        :param step: the flat step, in the order of ``params``.
        """
        start = 0
        for param, original in zip(params, originals, strict=True):
            n = param.numel()
            param.data = original + step[start : start + n].view(param.shape)
            start += n

    def _policy_batch(self) -> CPOBatch:
        """The whole rollout, every ``sub_sampling_factor``-th sample, with the advantages and ``π_k`` the step needs.

        The reward advantage is normalised (if ``normalize_advantage``); the cost advantage is only centred, so that
        the cost surrogate keeps the per-step units of the constraint value ``c``.

        :return: the batch the surrogates are computed on.
        """
        data = next(self.rollout_buffer.get(batch_size=None))
        sl = slice(None, None, self.sub_sampling_factor)
        obs, old_log_prob = data.observations[sl], data.old_log_prob[sl]
        actions = data.actions[sl]
        if isinstance(self.action_space, spaces.Discrete):
            actions = actions.long().flatten()
        advantages, cost_advantages = data.advantages[sl], data.cost_advantages[sl]
        if self.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        cost_advantages = cost_advantages - cost_advantages.mean()
        with th.no_grad():
            old_distribution = copy.copy(self.policy.get_distribution(obs))
        return CPOBatch(obs, actions, old_log_prob, advantages, cost_advantages, old_distribution)

    def _surrogates(self, batch: CPOBatch) -> CPOSurrogates:
        """The reward and cost surrogates and the mean KL to ``π_k`` at the current parameters.

        With ``ratio = π_θ(a|s) / π_k(a|s)``: the sample estimates ``E[ratio·A]`` and ``E[ratio·A_C]`` of the
        objective and constraint of the CPO update (Achiam et al. 2017, Section 5; their gradients at ``θ_k`` are
        eq. 10's ``g`` and ``b``) and ``D̄_KL(π_θ ‖ π_k)`` (whose Hessian at ``θ_k`` is ``H``). Differentiable
        unless called under ``th.no_grad()`` (the line search).

        :param batch: the rollout and ``π_k``.
        :return: the surrogates.
        """
        distribution = self.policy.get_distribution(batch.observations)
        ratio = th.exp(distribution.log_prob(batch.actions) - batch.old_log_prob)
        return CPOSurrogates(
            reward=(batch.advantages * ratio).mean(),
            cost=(batch.cost_advantages * ratio).mean(),
            kl=kl_divergence(distribution, batch.old_distribution).mean(),
        )

    def _step_direction(self, before: CPOSurrogates, c: float) -> tuple[list[th.nn.Parameter], th.Tensor, CPOSolution]:
        """The full CPO step ``x*`` of eq. 10 (Achiam et al. 2017, Section 6.1), before the line search.

        ``g``, ``b`` and the KL's gradient come from autograd, ``H⁻¹g`` and ``H⁻¹b`` from the conjugate gradient on
        the (damped) Fisher-vector product, and :func:`cpo_dual_solution` combines them (Appendix 10.2; the infeasible
        case is the recovery step of Section 6.2).

        :param before: the surrogates at ``θ_k``, with their graph.
        :param c: the constraint value ``c`` (per-step units of the cost surrogate).
        :return: the actor's parameters (those the KL depends on), the flat step on them, and the dual solution.
        """
        self.policy.optimizer.zero_grad()
        actor_params, g, grad_kl, _ = self._compute_actor_grad(before.kl, before.reward)
        b = flat_grad(before.cost, actor_params, retain_graph=True)
        fisher_product = partial(self.hessian_vector_product, actor_params, grad_kl)
        h_inv_g = conjugate_gradient_solver(fisher_product, g, max_iter=self.cg_max_steps)
        h_inv_b = conjugate_gradient_solver(fisher_product, b, max_iter=self.cg_max_steps)
        q, r, s = float(g @ h_inv_g), float(g @ h_inv_b), float(b @ h_inv_b)
        solution = cpo_dual_solution(q, r, s, c, self.target_kl)
        step = (solution.coef_g * h_inv_g + solution.coef_b * h_inv_b).detach()
        return actor_params, step, solution

    def _step_is_acceptable(self, trial: CPOSurrogates, before: CPOSurrogates, c: float, recovering: bool) -> bool:
        """The line search's test of a trial point, on the sample surrogates (Achiam et al. 2017, Section 6.1).

        Accepted when the KL stays within the trust region (``D̄_KL <= δ``, the true KL, not eq. 10's quadratic), the
        cost surrogate grows by at most ``max(0, -c)`` (the linearised constraint ``c + ΔJ_C <= 0``, relaxed to "no
        increase" while violated) and the reward surrogate does not decrease, except in the infeasible-recovery
        case (Section 6.2), whose step is meant to decrease the cost whatever it does to the reward.

        :param trial: the surrogates at the trial point (computed without gradient).
        :param before: the surrogates at ``θ_k``.
        :param c: the constraint value ``c``.
        :param recovering: the step is the infeasible case's recovery step: the reward test is skipped.
        :return: whether the trial point is accepted.
        """
        within_trust_region = trial.kl.item() <= self.target_kl
        cost_within_limit = (trial.cost - before.cost).item() <= max(0.0, -c)
        reward_improves = recovering or trial.reward.item() >= before.reward.item()
        return within_trust_region and cost_within_limit and reward_improves

    def _line_search(
        self,
        batch: CPOBatch,
        actor_params: list[th.nn.Parameter],
        step: th.Tensor,
        before: CPOSurrogates,
        c: float,
        recovering: bool,
    ) -> tuple[bool, float]:
        """Backtracking line search along the CPO step (Achiam et al. 2017, Section 6.1 and Algorithm 1).

        Tries ``θ_k + coef·step`` for ``coef = 1, f, f², ...`` (``f``: ``line_search_shrinking_factor``, at most
        ``line_search_max_iter`` points) and keeps the first that :meth:`_step_is_acceptable` accepts; a zero step
        is never accepted (nothing moved). When none is, the parameters go back to ``θ_k``.

        :param batch: the rollout and ``π_k``.
        :param actor_params: the parameters the step applies to, at ``θ_k``.
        :param step: the full step, flat over ``actor_params``.
        :param before: the surrogates at ``θ_k``.
        :param c: the constraint value ``c``.
        :param recovering: the step is the infeasible case's recovery step (no reward test).
        :return: whether a point was accepted, and its KL to ``π_k`` (``0.0`` when none was).
        """
        originals = [param.detach().clone() for param in actor_params]
        step_moves = bool(step.abs().sum() > 0)
        coef = 1.0
        with th.no_grad():
            for _ in range(self.line_search_max_iter):
                self._apply_step(actor_params, originals, coef * step)
                trial = self._surrogates(batch)
                if step_moves and self._step_is_acceptable(trial, before, c, recovering):
                    return True, trial.kl.item()
                coef *= self.line_search_shrinking_factor
            self._apply_step(actor_params, originals, th.zeros_like(step))
        return False, 0.0

    def _log_train(
        self,
        solution: CPOSolution,
        c: float,
        success: bool,
        kl_value: float,
        policy_objective: float,
        critic_logs: dict[str, float],
    ) -> None:
        """Record the update's ``train/`` logs.

        :param solution: the dual solution of the step problem.
        :param c: the constraint value ``c``.
        :param success: whether the line search accepted a point.
        :param kl_value: the accepted point's KL to ``π_k`` (``0.0`` when none was).
        :param policy_objective: the reward surrogate at ``θ_k``.
        :param critic_logs: the critics' regression logs, from :func:`~sppo_sb3.common.cost_policy.fit_critics`.
        """
        buf = self.rollout_buffer
        self.logger.record("train/cpo_case", CPO_CASES[solution.case])
        self.logger.record("train/constraint_value", c)
        if math.isfinite(solution.nu):
            self.logger.record("train/lagrange_nu", solution.nu)
        self.logger.record("train/is_line_search_success", float(success))
        self.logger.record("train/kl_divergence_loss", kl_value)
        self.logger.record("train/policy_objective", policy_objective)
        self.logger.record("train/explained_variance", explained_variance(buf.values.flatten(), buf.returns.flatten()))
        for key, value in critic_logs.items():
            self.logger.record(f"train/{key}", value)
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())
        self.logger.record(N_UPDATES_LOG_KEY, self._n_updates, exclude="tensorboard")

    def train(self) -> None:
        """One CPO update: the policy step of Achiam et al. 2017's Algorithm 1, then the critics' regression.

        The surrogates at ``θ_k`` give the step of eq. 10 (:meth:`_step_direction`), which the backtracking line
        search shortens until the sample surrogates accept it (:meth:`_line_search`); then ``V`` and ``V_C`` are
        regressed with the actor's parameters frozen.
        """
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        c = self.constraint_value()
        batch = self._policy_batch()
        before = self._surrogates(batch)

        actor_params, step, solution = self._step_direction(before, c)
        success, kl_value = self._line_search(batch, actor_params, step, before, c, recovering=solution.case == "infeasible")

        critic_logs = fit_critics(
            self.policy, self.rollout_buffer, self.n_critic_updates, self.batch_size, reward_critic=True, frozen=actor_params
        )
        self._n_updates += 1
        self._log_train(solution, c, success, kl_value, before.reward.item(), critic_logs)
        self.last_solution = solution

    def learn(
        self: SelfCPO,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "CPO",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfCPO:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )


__all__ = ["CPO", "CPO_CASES", "CPOSolution", "cpo_dual_solution"]
