"""SAILR: Safe Advantage-based Intervention for Learning policies with Reinforcement (Wagener et al. 2021).

PPO learns in the *absorbing* MDP ``M̃`` induced by an advantage-based shielding rule (the paper's eqs. 5, 7, 12):
every executed action is shielded (``a_safe = a`` unless ``Ā(s, a) > η``, else the backup action ``ζ(s)``), and
for learning, the first intervention ``T`` of an episode becomes the absorbing transition ``(s_T, a_T, R̃)`` — the
proposed action, the penalty ``R̃ <= 0``, no bootstrap — after which the agent sits in ``s†`` with zero reward: the
rest of that real episode is not learned from (masked out of the advantages and of every loss).
"""

from __future__ import annotations

import warnings
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

from sppo_sb3.common.cost_buffer import CostRolloutBuffer
from sppo_sb3.common.on_policy import SafeOnPolicyMixin
from sppo_sb3.common.safety import INTERVENED_KEY
from sppo_sb3.shield import ShieldingRule, ShieldWrapper, resolve_shielding_rule
from sppo_sb3.shield.persistence import ShieldedLoadMixin

SelfSAILR = TypeVar("SelfSAILR", bound="SAILR")


def shield_vec_env(env: VecEnv, rule: ShieldingRule) -> VecEnv:
    """Wrap every env of ``env`` in :class:`~sppo_sb3.shield.ShieldWrapper`, in place; return ``env``.

    The shield must see the raw observations and replace the action the env executes, so it sits at the gym
    level, below any ``VecEnvWrapper`` (``VecNormalize``...): the gym envs of the underlying ``DummyVecEnv`` are
    wrapped in place. Envs already wrapped in a ``ShieldWrapper`` are left as they are. Sub-process VecEnvs cannot
    be re-wrapped from here: build them with the shield (``make_vec_env(..., wrapper_class=ShieldWrapper,
    wrapper_kwargs=dict(rule=rule))``).

    :param env: the VecEnv to shield.
    :param rule: the shielding rule.
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
            "wrapper_class=sppo_sb3.shield.ShieldWrapper, wrapper_kwargs=dict(rule=rule)) and pass shield=None."
        )
    for idx, gym_env in enumerate(base.envs):
        if not is_wrapped(gym_env, ShieldWrapper):
            base.envs[idx] = ShieldWrapper(gym_env, rule)
    return env


class SAILR(ShieldedLoadMixin, SafeOnPolicyMixin, PPO):
    """PPO under an advantage-based shield, learning in the absorbing MDP (Wagener et al. 2021, Alg. 1).

    The training envs are wrapped in :class:`~sppo_sb3.shield.ShieldWrapper` at the gym level (see
    :func:`shield_vec_env`), so the executed action is always the safe one — also in ``predict`` rollouts that use
    ``model.get_env()``. For learning, the first intervened step of an episode is stored with the agent's proposed
    action, reward ``penalty`` and a terminal flag (no bootstrap); the later steps of that episode are masked out
    of the advantages and losses. Every other argument is SB3 ``PPO``'s.

    :param policy: the policy model ("MlpPolicy": SB3's ``ActorCriticPolicy``).
    :param env: the environment (must report ``info["cost"]``), or its registered id.
    :param shield: the shielding rule; ``"auto"``: the rule registered for the env's id
        (:func:`~sppo_sb3.shield.default_shielding_rule`); another string: the rule registered for that env id;
        ``None``: the envs are already wrapped in ``ShieldWrapper`` (else SAILR runs as plain PPO, with a warning).
        ``"auto"`` without a registered rule is an error. The rule in use is ``model.shield_rule``; it is saved with
        the model, and ``SAILR.load`` raises where it cannot be rebuilt: pass it with
        ``custom_objects={"shield_rule": rule}``, or ``custom_objects={"shield": None}`` to load unshielded.
    :param penalty: reward ``R̃ <= 0`` of the absorbing transition; ``None``: the rule's ``penalty`` (default -1).
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

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": ActorCriticPolicy}
    uses_cost_critic = False
    rollout_buffer: CostRolloutBuffer

    def __init__(
        self,
        policy: str | type[ActorCriticPolicy],
        env: GymEnv | str,
        shield: ShieldingRule | str | None = "auto",
        penalty: float | None = None,
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
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        if penalty is not None and penalty > 0:
            raise ValueError(f"The absorbing penalty R̃ must be <= 0 (eq. 7), got {penalty}.")
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
            shield_vec_env(self.env, self.shield_rule)
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
    def absorbing_penalty(self) -> float:
        """The reward ``R̃`` of the absorbing transition: ``penalty``, else the rule's, else -1."""
        if self.penalty is not None:
            return self.penalty
        return self.shield_rule.penalty if self.shield_rule is not None else -1.0

    # --- learning in the absorbing MDP --------------------------------------------------------------------------

    def _on_env_reset(self) -> None:
        super()._on_env_reset()
        assert self.env is not None
        self._post_intervention = np.zeros(self.env.num_envs, dtype=bool)

    def _learning_transition(
        self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The absorbing MDP (eq. 7): the first intervention of an episode ends the learning data with ``R̃``.

        :return: rewards with ``R̃`` at first interventions; ``absorbed`` where a first intervention happened;
            mask 0 on the steps after the first intervention of their episode.
        """
        intervened = np.array([bool(info.get(INTERVENED_KEY, False)) for info in infos])
        if len(self._post_intervention) != len(rewards):
            self._post_intervention = np.zeros(len(rewards), dtype=bool)
        mask = (~self._post_intervention).astype(np.float32)
        absorbed = intervened & ~self._post_intervention
        rewards = np.where(absorbed, np.float32(self.absorbing_penalty), rewards).astype(np.float32)
        self._post_intervention = (self._post_intervention | absorbed) & ~np.asarray(dones, dtype=bool)
        return rewards, absorbed, mask

    def train(self) -> None:
        """PPO's update on the unmasked steps (skipped, with a log entry, when the rollout has none)."""
        n_learnable = self.rollout_buffer.n_learnable
        self.logger.record("train/learnable_fraction", n_learnable / (self.n_steps * self.n_envs))
        if n_learnable == 0:
            return
        super().train()

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
