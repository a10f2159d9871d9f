"""SAILR: Safe Advantage-based Intervention for Learning policies with Reinforcement (Wagener et al. 2021).

PPO learns in the *absorbing* MDP ``M̃`` induced by an advantage-based shielding rule (the paper's eqs. 5, 7, 12),
as SAILR's authors ran it (their public code, ``nolanwagener/safe_rl``, is the reference for the facts):

- every executed action is shielded (``a_safe = a`` unless ``Ā(s, a) > η``, else the backup action ``ζ(s)``); after
  the first intervention ``T`` of an episode the backup policy keeps control until the episode ends;
- for learning, step ``T`` is the absorbing transition ``(s_T, a_T)`` — the proposed action — with reward 0 and
  intervention cost 1, after which the agent sits in ``s†``, which costs 1 at every step: the cost value is
  bootstrapped at its maximum ``1 / (1 - γ)``. The env's own costs are not learned from (the violations are what the
  shield prevents), and the steps after ``T`` are masked out of the advantages and of every loss;
- the policy follows the advantage ``(A_R - κ·A_C) / (1 + κ)`` of a fixed penalty ``κ`` (2 on Point, 30 on
  Half-Cheetah in the authors' configurations) with a learned cost critic ``V_C`` beside ``V``.

Deviations from the authors' code, all in SB3's PPO rather than in SAILR itself: one Adam optimizer for the actor and
both critics (theirs: learning rates 3e-4 and 1e-3, 80 critic steps), the critics regressed by MSE on unscaled
returns (theirs: Huber loss on returns scaled by ``100·(1 - γ)`` and clamped to the value range), a state-independent
log-std (theirs: predicted by the actor), gradient clipping at ``max_grad_norm``, and the post-intervention steps of
the backup count towards ``n_steps`` (theirs: an epoch counts only the steps the agent chose), so that every
algorithm is compared at the same number of env steps.
"""

from __future__ import annotations

import warnings
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

from sppo_sb3.common.cost_buffer import CostRolloutBuffer
from sppo_sb3.common.cost_policy import CostActorCriticPolicy
from sppo_sb3.common.keys import INTERVENED_KEY
from sppo_sb3.common.on_policy import SafeOnPolicyMixin
from sppo_sb3.sailr.policies import MlpPolicy
from sppo_sb3.shield.base import ShieldingRule
from sppo_sb3.shield.intervention import OnIntervention, check_on_intervention, check_penalty
from sppo_sb3.shield.persistence import ShieldedLoadMixin
from sppo_sb3.shield.registry import resolve_shielding_rule
from sppo_sb3.shield.wrapper import ShieldWrapper

#: the values of ``on_intervention`` SAILR implements (:mod:`~sppo_sb3.shield.intervention`): its authors' takeover
SAILR_ON_INTERVENTION: tuple[OnIntervention, ...] = ("takeover",)

SelfSAILR = TypeVar("SelfSAILR", bound="SAILR")


def shield_vec_env(env: VecEnv, rule: ShieldingRule, on_intervention: OnIntervention = "takeover") -> VecEnv:
    """Wrap every env of ``env`` in :class:`~sppo_sb3.shield.ShieldWrapper`, in place; return ``env``.

    The shield must see the raw observations and replace the action the env executes, so it sits at the gym
    level, below any ``VecEnvWrapper`` (``VecNormalize``...): the gym envs of the underlying ``DummyVecEnv`` are
    wrapped in place. Envs already wrapped in a ``ShieldWrapper`` are left as they are. Sub-process VecEnvs cannot
    be re-wrapped from here: build them with the shield (``make_vec_env(..., wrapper_class=ShieldWrapper,
    wrapper_kwargs=dict(rule=rule))``).

    :param env: the VecEnv to shield.
    :param rule: the shielding rule.
    :param on_intervention: the wrapper's mode; SAILR's ``"takeover"``: the backup policy runs the rest of an
        episode after its first intervention.
    :return: the same VecEnv, shielded.
    :raises TypeError: when ``env`` has unshielded envs in another process.
    """
    if all(env.env_is_wrapped(ShieldWrapper)):
        return env
    base: VecEnv = env
    while isinstance(base, VecEnvWrapper):
        base = base.venv
    if not isinstance(base, DummyVecEnv):
        raise TypeError(
            f"SAILR can only shield the envs of a DummyVecEnv in place, got {type(base).__name__} whose envs are not "
            "wrapped in ShieldWrapper. Build it with make_vec_env(env_id, n_envs, vec_env_cls=SubprocVecEnv, "
            "wrapper_class=sppo_sb3.shield.ShieldWrapper, wrapper_kwargs=dict(rule=rule, on_intervention='takeover')) "
            "and pass shield=None."
        )
    for idx, gym_env in enumerate(base.envs):
        if not is_wrapped(gym_env, ShieldWrapper):
            base.envs[idx] = ShieldWrapper(gym_env, rule, on_intervention=on_intervention)
    return env


class SAILR(ShieldedLoadMixin, SafeOnPolicyMixin, PPO):
    """PPO under an advantage-based shield, learning in the absorbing MDP (Wagener et al. 2021, Alg. 1).

    The training envs are wrapped in :class:`~sppo_sb3.shield.ShieldWrapper` at the gym level (see
    :func:`shield_vec_env`), so the executed action is always the safe one — also in ``predict`` rollouts that use
    ``model.get_env()`` — and after an episode's first intervention the backup policy runs the rest of it. For
    learning, the first intervened step is stored with the agent's proposed action, reward 0, the cost of the
    absorbing state ``s†`` (``1 / (1 - γ)``: 1 per step forever) and a terminal flag; the later steps of the episode are
    masked out. PPO follows ``(A_R - κ·A_C) / (1 + κ)``. The defaults are the authors' (``n_steps`` 4000, full-batch
    updates for up to 80 epochs with early stopping at ``1.5·target_kl``, GAE ``λ`` 0.97, entropy bonus 0.001); the
    module docstring lists what differs from their code.

    :param policy: the policy model ("MlpPolicy": :class:`~sppo_sb3.common.cost_policy.CostActorCriticPolicy`).
    :param env: the environment (must report ``info["cost"]``), or its registered id.
    :param shield: the shielding rule; ``"auto"``: the rule registered for the env's id
        (:func:`~sppo_sb3.shield.default_shielding_rule`); another string: the rule registered under that name (an env id, or a
        variant such as ``"SafePointCircle-v0:paper"``, the paper's Point rule);
        ``None``: the envs are already wrapped in ``ShieldWrapper`` (else SAILR runs as plain PPO, with a warning).
        ``"auto"`` without a registered rule is an error. The rule in use is ``model.shield_rule``; it is saved with
        the model, and ``SAILR.load`` raises where it cannot be rebuilt: pass it with
        ``custom_objects={"shield_rule": rule}``, or ``custom_objects={"shield": None}`` to load unshielded.
    :param on_intervention: what the learner is told of an intervention, in the package's one vocabulary
        (:mod:`~sppo_sb3.shield.intervention`): ``"takeover"``, the one SAILR implements (the proposal is the absorbing
        step, the backup runs the rest of the episode, masked out of learning).
    :param penalty: what an intervention costs the learner, ``>= 0``: the fixed weight ``κ`` of the intervention
        cost's advantage (the authors use 2 on Point and 30 on Half-Cheetah; 0 learns from the reward alone, and the
        absorbing transition then only ends the return).
    :param learning_rate: learning rate.
    :param n_steps: steps per env per rollout.
    :param batch_size: minibatch size.
    :param n_epochs: passes over each rollout.
    :param gamma: discount.
    :param gae_lambda: GAE ``λ``.
    :param clip_range: PPO clipping parameter.
    :param clip_range_vf: clipping of the value update (``None``: no clipping).
    :param normalize_advantage: normalise the advantage per minibatch.
    :param ent_coef: entropy coefficient.
    :param vf_coef: value loss coefficient.
    :param max_grad_norm: gradient clipping norm.
    :param use_sde: generalised state-dependent exploration.
    :param sde_sample_freq: gSDE noise resampling period.
    :param rollout_buffer_class: ``None`` or a subclass of :class:`~sppo_sb3.common.cost_buffer.CostRolloutBuffer`.
    :param rollout_buffer_kwargs: kwargs of the rollout buffer.
    :param target_kl: PPO's early-stopping KL.
    :param stats_window_size: episodes averaged in the rollout logs.
    :param tensorboard_log: TensorBoard log folder (``None``: none).
    :param policy_kwargs: policy kwargs.
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
        shield: ShieldingRule | str | None = "auto",
        on_intervention: OnIntervention = "takeover",
        penalty: float = 1.0,
        learning_rate: float | Schedule = 3e-4,
        n_steps: int = 4000,
        batch_size: int = 4000,
        n_epochs: int = 80,
        gamma: float = 0.99,
        gae_lambda: float = 0.97,
        clip_range: float | Schedule = 0.2,
        clip_range_vf: float | Schedule | None = None,
        normalize_advantage: bool = True,
        ent_coef: float = 0.001,
        vf_coef: float = 0.5,
        max_grad_norm: float = 0.5,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        rollout_buffer_class: type[RolloutBuffer] | None = None,
        rollout_buffer_kwargs: dict[str, Any] | None = None,
        target_kl: float | None = 0.01,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        check_on_intervention(on_intervention, SAILR_ON_INTERVENTION, "SAILR")
        check_penalty(penalty, "SAILR", "It weights the intervention cost κ (the authors use 2 on Point, 30 on Half-Cheetah).")
        self.on_intervention = on_intervention
        self.shield = shield
        self.shield_rule: ShieldingRule | None = shield if isinstance(shield, ShieldingRule) else None
        self.penalty = penalty
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
        self._post_intervention = np.zeros(self.n_envs if self.env is not None else 1, dtype=bool)
        if _init_setup_model:
            self._setup_model()

    # --- shielding of the training envs -------------------------------------------------------------------------

    def _shield_env(self) -> None:
        """Shield ``self.env`` with the rule (resolved on first use, then saved with the model)."""
        if self.env is None:
            return
        if self.shield_rule is None:
            self.shield_rule = resolve_shielding_rule(self.shield, self.env, required=True)
        if self.shield_rule is not None:
            shield_vec_env(self.env, self.shield_rule, self.on_intervention)
        elif all(self.env.env_is_wrapped(ShieldWrapper)):
            self.shield_rule = self.env.get_attr("rule", indices=[0])[0]
        else:
            warnings.warn(
                "SAILR got shield=None and envs without ShieldWrapper: nothing is shielded, it runs as plain PPO.",
                stacklevel=3,
            )

    def _setup_model(self) -> None:
        super()._setup_model()
        self._shield_env()

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """SB3's ``set_env``, then the new envs are shielded with the model's rule."""
        super().set_env(env, force_reset)
        self._shield_env()

    @property
    def absorbing_cost(self) -> float:
        """Learning cost of the absorbing transition: 1, plus ``γ·V_C(s†)`` bootstrapped at its maximum ``1 / (1 - γ)``."""
        return 1.0 / (1.0 - self.gamma)

    # --- learning in the absorbing MDP --------------------------------------------------------------------------

    def _on_env_reset(self) -> None:
        super()._on_env_reset()
        assert self.env is not None
        self._post_intervention = np.zeros(self.env.num_envs, dtype=bool)

    def _learning_transition(
        self, rewards: np.ndarray, costs: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The absorbing MDP (eq. 7): the first intervention of an episode ends the learning data.

        :return: rewards, 0 at first interventions; costs, :attr:`absorbing_cost` at first interventions and 0
            elsewhere (the env's costs are not learned from); ``absorbed`` where a first intervention happened;
            mask 0 on the steps after the first intervention of their episode.
        """
        intervened = np.array([bool(info.get(INTERVENED_KEY, False)) for info in infos])
        if len(self._post_intervention) != len(rewards):
            self._post_intervention = np.zeros(len(rewards), dtype=bool)
        mask = (~self._post_intervention).astype(np.float32)
        absorbed = intervened & ~self._post_intervention
        rewards = np.where(absorbed, 0.0, rewards).astype(np.float32)
        costs = np.where(absorbed, self.absorbing_cost, 0.0).astype(np.float32)
        self._post_intervention = (self._post_intervention | absorbed) & ~np.asarray(dones, dtype=bool)
        return rewards, costs, absorbed, mask

    def train(self) -> None:
        """PPO's update of ``(A_R - κ·A_C) / (1 + κ)`` on the unmasked steps, then the cost critic's regression.

        A rollout without unmasked steps is skipped, with a log entry.
        """
        n_learnable = self.rollout_buffer.n_learnable
        self.logger.record("train/learnable_fraction", n_learnable / (self.n_steps * self.n_envs))
        if n_learnable == 0:
            return
        self._train_on_penalised_advantage(self.penalty)

    def learn(
        self: SelfSAILR,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "SAILR",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfSAILR:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
