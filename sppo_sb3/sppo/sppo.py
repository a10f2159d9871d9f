"""SPPO — Shielded Planning guided Policy Optimization (Alg. 1), as a Stable-Baselines3 off-policy algorithm.

Read top to bottom: ``collect_rollouts`` is Alg. 1's exploration phase (plan with MPPI, shield every executed
action, store ``B`` and its relabel ``B̃``); ``train`` is its training phase (TOPO on ``B̃``, EMA targets);
``predict`` is deployment (plan, then shield).
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, RolloutReturn, Schedule, TrainFreq
from stable_baselines3.common.utils import should_collect_more_steps
from stable_baselines3.common.vec_env import VecEnv

from sppo_sb3.common.action_repeat import check_held_steps_are_shielded
from sppo_sb3.common.costs import edit_count, intervention_count
from sppo_sb3.common.keys import (
    EDITS_KEY,
    ENV_STEPS_KEY,
    INTERVENED_KEY,
    INTERVENTIONS_KEY,
    N_UPDATES_LOG_KEY,
    PROPOSED_ACTION_KEY,
)
from sppo_sb3.common.lagrange import PIDLagrangian
from sppo_sb3.common.safety import SafetyTrackingMixin
from sppo_sb3.shield.base import ShieldingRule, make_permissive
from sppo_sb3.shield.intervention import OnIntervention, check_on_intervention, check_penalty
from sppo_sb3.shield.learned.base import RefinableRule
from sppo_sb3.shield.learned.latent import LatentModelRule
from sppo_sb3.shield.persistence import ShieldedLoadMixin
from sppo_sb3.shield.registry import resolve_shielding_rule
from sppo_sb3.sppo.buffers import SPPO_ON_INTERVENTION, ShieldedReplayBuffer
from sppo_sb3.sppo.compile import CompiledFunction, CompileMode, check_compile_mode, should_compile
from sppo_sb3.sppo.optim import init_optimizer_state, supports_tensor_step
from sppo_sb3.sppo.planner import MPPIConfig, MPPIPlanner
from sppo_sb3.sppo.policies import TOLDPolicy
from sppo_sb3.sppo.sizes import SizesName, named_sizes
from sppo_sb3.sppo.time_scale import resolve_gamma, task_terminates
from sppo_sb3.sppo.topo import TOPO_STATS, TOPOConfig, draw_target_heads, topo_update
from sppo_sb3.sppo.world_model import TOLDName, check_told_name

SelfSPPO = TypeVar("SelfSPPO", bound="SPPO")


INTERVENTION_RATE_WINDOW = 1000
"""Agent steps over which SPPO averages its shield's intervention rate for ``intervention_target`` (an EMA)."""


def check_spaces(observation_space: spaces.Space, action_space: spaces.Space) -> None:
    """Reject, with a message that says what to do, the spaces SPPO cannot handle."""
    if not isinstance(action_space, spaces.Box):
        raise TypeError(
            f"SPPO plans continuous actions and needs a Box action space, got {action_space}. "
            "For discrete actions use an algorithm such as SB3's DQN or PPO."
        )
    if not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
        raise ValueError(
            f"SPPO needs finite action bounds to rescale its [-1, 1] plans, got low={action_space.low}, "
            f"high={action_space.high}. Clip the action space (e.g. gymnasium.wrappers.ClipAction) first."
        )
    if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
        raise TypeError(
            f"SPPO's TOLD encoder is an MLP on flat state vectors, got observation space {observation_space}. "
            "Flatten Dict observations (gymnasium.wrappers.FlattenObservation); image observations are not supported."
        )


class SPPO(ShieldedLoadMixin, SafetyTrackingMixin, OffPolicyAlgorithm):
    """Shielded Planning guided Policy Optimization (Wang, Qin & Kan).

    Defaults are TD-MPC's (Hansen et al. 2022) but for the sizes, which default to ones a CPU runs (``sizes="cpu"``;
    TD-MPC's are ``sizes="tdmpc"``). ``planner_kwargs`` are fields of :class:`MPPIConfig`, ``topo_kwargs`` fields of
    :class:`TOPOConfig`; ``policy_kwargs`` set the TOLD sizes (``latent_dim``, ``encoder_dim``, ``hidden_dim``).

    :param policy: ``"TOLDPolicy"`` (alias ``"MlpPolicy"``) or a policy class.
    :param env: the environment (a gymnasium env, a registered id, or a VecEnv).
    :param learning_rate: Adam learning rate of the model and of the policy.
    :param buffer_size: replay buffer size (``B`` and ``B̃`` share it).
    :param learning_starts: warm-up steps with random (shielded) actions before planning and training.
    :param batch_size: sequences per TOPO update (``None``: the ``sizes``').
    :param tau: EMA coefficient of the target network (Alg. 3 line 13).
    :param gamma: discount of eqs. 10 and 16: a number (the paper's and TD-MPC's 0.99), or ``"auto"``: from the task's
        episode length, TD-MPC2's rule (:func:`~sppo_sb3.sppo.time_scale.episode_discount`: 0.99 for 500 steps, 0.995
        for 1000), so that the discount spans the same time on robots with short steps. Resolved once, at
        construction, into :attr:`gamma`, which the planner (eq. 10) and the TD target (eq. 16) both read; it is not a
        field of ``planner_kwargs`` or ``topo_kwargs``.
    :param train_freq: update the model every ``train_freq`` steps.
    :param gradient_steps: TOPO updates per rollout.
    :param horizon: length ``H`` of the sequences TOPO trains on, and of the plans (``None``: the ``sizes``').
    :param target_update_interval: update the EMA target every this many TOPO updates.
    :param shield: a :class:`ShieldingRule`, ``"auto"`` (the task's registered rule; where there is none, SPPO warns
        and runs unshielded), another registered rule's name (e.g. ``"SafePointCircle-v0:paper"``, the paper's Point
        rule) or ``None`` (unshielded, on purpose). The rule in use is :attr:`shield_rule` (``None``:
        unshielded); it is saved with the model, and ``SPPO.load`` raises where it cannot be rebuilt: pass it with
        ``custom_objects={"shield_rule": rule}``, or ``custom_objects={"shield": None}`` to load unshielded.
    :param permissive_shield: where the rule rejects a proposal, execute an accepted action near it instead of the
        backup's (a rule with edits: :class:`~sppo_sb3.shield.MujocoShieldingRule`'s ``permissive``); the edits are
        counted apart among the interventions (``info["shield_edits"]``). Not in the paper.
    :param on_intervention: what ``B̃`` records at an intervention, in the package's one vocabulary
        (:mod:`~sppo_sb3.shield.intervention`; :class:`ShieldedReplayBuffer`). ``"terminate"`` is the paper's ``M̃``
        (an absorbing terminal with reward ``R̃ = -penalty``, nothing more of the episode); ``"restart"`` (default)
        makes every intervention an absorbing terminal and restarts ``B̃`` at the next real state, since
        ``"terminate"`` keeps only one shielded example per episode, so the planner learns slowly which proposals the
        shield rejects. For tasks where a violation does not end the episode (CMDPs with a cost limit, e.g. the
        velocity tasks): ``"continue"`` keeps the proposal with the step's reward less ``penalty`` and bootstraps from
        the real next state, and ``"none"`` learns from the executed steps alone.
    :param penalty: what an intervention costs the learner, ``>= 0``: eq. 7's ``R̃ = -penalty`` (under
        ``"continue"``, subtracted from the step's reward); with ``intervention_target``, the price's starting value.
    :param intervention_target: price the shield's interventions instead of a hand-set ``penalty`` (not in the paper:
        SafeLOOP's and SafeDreamer's cost-aware planning and PID Lagrangian, applied to the shield's interventions).
        The price ``λ >= 0`` is a PID Lagrange multiplier (:class:`~sppo_sb3.common.lagrange.PIDLagrangian`) that holds
        the share of env steps the shield intervenes on (averaged over the last :data:`INTERVENTION_RATE_WINDOW` agent
        steps) at this target, starting from ``penalty``. It replaces ``penalty`` in ``B̃``'s relabel (``R̃ = -λ``,
        or ``r - λ`` under ``"continue"``; stored steps are priced when sampled, so the price of every stored
        intervention follows ``λ``), and TOLD learns an intervention head ``I(z, a)``, the probability that the shield
        rejects the proposal ``a``, so that eq. 10 and the policy prior's loss pay ``λ · P(I)`` on every imagined step.
        ``None`` (default): the paper's planner, which hears of the shield only through the relabel, at ``penalty``.
    :param termination_model: give TOLD a termination head, trained on ``B̃``'s terminal flags (absorbing
        interventions and real terminations, not time-limit truncations), and plan with it: eq. 10 adds no reward and
        no value after a predicted absorbing step. ``"auto"`` (default): on where the task ends episodes on its own
        (gymnasium's MuJoCo robots that fall: Hopper, Walker2d, Ant, Humanoid and their velocity tasks, see
        :func:`~sppo_sb3.sppo.time_scale.task_terminates`), off elsewhere. ``False`` is TD-MPC's model and the paper's,
        which plans as if no episode ended; the resolved value is :attr:`termination_model`.
    :param told: TOLD's networks (:class:`~sppo_sb3.sppo.world_model.TOLD`): ``"paper"`` (default) is TD-MPC's (v1)
        model, the paper's; ``"tdmpc2"`` adds TD-MPC2's robustness pieces: ``Linear → LayerNorm → Mish`` hidden
        layers, a SimNorm latent (softmax over groups of 8; ``latent_dim`` must be a multiple of 8) and five Q heads,
        whose TD target is the min of two drawn at random per update and whose mean the planner and the policy use.
        Not included: TD-MPC2's two-hot discrete regression of reward and value, its stochastic policy with entropy
        and percentile-scaled Q, and its larger sizes. Saved with the model (in ``policy_kwargs``).
    :param refine_shield: Alg. 1 line 12, ``G ← UpdateShieldingRule(B)``: the rule learns from the real transitions
        of ``B`` during :meth:`train` (as many minibatches of ``batch_size`` as TOPO updates). Needs a learnable rule
        (:class:`~sppo_sb3.shield.RefinableRule`): :class:`~sppo_sb3.shield.LearnedDynamicsRule` (a learned model,
        the task's constraint known), :class:`~sppo_sb3.shield.LatentModelRule` (``Q̄`` rolled on this model's TOLD)
        or :class:`~sppo_sb3.shield.LearnedCostCriticRule` (a cost critic, fitted on ``info["shaped_cost"]``). For
        tasks without a model to roll ``Q̄`` on: the backup policy ``ζ`` has to be known. ``"auto"`` (default)
        refines exactly the learnable rules: one that has learned nothing shields nothing, so a learned rule that is
        not refined never protects. ``False`` keeps a pre-trained rule as it is.
    :param refine_backup_fraction: with ``refine_shield``, the share of warm-up steps (before ``learning_starts``)
        that execute the backup ``ζ(s)`` instead of a uniform action. Every target of the learned ``Q̄`` reads it at
        ``(s', ζ(s'))``, and the backup's actions (e.g. full braking, a corner of the action box) are ones uniform
        actions almost never take: these steps put them in ``B``. Not in the paper (its Alg. 1 warms up uniformly).
    :param planner_kwargs: :class:`MPPIConfig` overrides.
    :param topo_kwargs: :class:`TOPOConfig` overrides.
    :param sizes: the TOLD, planner and batch sizes, by name (:mod:`~sppo_sb3.sppo.sizes`): ``"cpu"`` (default:
        TOLD 32 / 64 / 128, MPPI 64 samples × 3 iterations, batches of 128 sequences of 3 steps; about 2 ms per
        planned action on a CPU core) or ``"tdmpc"`` (TD-MPC's, for a GPU: 50 / 256 / 512, 512 × 6, 512 sequences of
        5 steps). ``policy_kwargs``, ``planner_kwargs``, ``batch_size`` and ``horizon`` override them. A run logs the
        sizes it uses (``verbose >= 1``).
    :param plan_at_predict: ``predict`` plans with MPPI (``True``) or acts with the policy prior alone (fast).
    :param shield_at_predict: ``predict`` passes its actions through the shield.
    :param replay_buffer_kwargs: extra arguments of :class:`ShieldedReplayBuffer` (e.g. ``handle_timeout_termination``;
        ``on_intervention`` and ``penalty`` come from the arguments above).
    :param optimize_memory_usage: SB3's replay-buffer option; ``B̃`` needs explicit next observations, so only
        ``False`` (SB3's default) is accepted.
    :param compile: compile the planner (all ``J`` iterations of Alg. 2) and the whole TOPO update (Alg. 3) with
        ``torch.compile`` (Inductor on CPU, CUDA graphs on CUDA): ``True``, ``False`` or ``"auto"`` (compile where
        ``torch.compile`` is available; see :func:`~sppo_sb3.sppo.compile.should_compile`). Each planning horizon
        of the schedule and each number of envs is compiled once, on first use: a run compiles ``H`` planner graphs
        for training (one per horizon; more for evaluation VecEnvs of other sizes) and one update graph, see
        :attr:`compile_stats`. The eager code is the reference and is used, after one warning, if compiling fails.
    :param stats_window_size: episodes averaged in the ``rollout/`` logs and the ``safety/ep_*_mean`` values.
    :param tensorboard_log: TensorBoard log folder (``None``: none).
    :param policy_kwargs: arguments of :class:`TOLDPolicy`: the TOLD sizes ``latent_dim``, ``encoder_dim``,
        ``hidden_dim`` and the optimiser's ``optimizer_class``, ``optimizer_kwargs`` (the variant comes from ``told``).
    :param verbose: 0 none, 1 info, 2 debug.
    :param seed: seed of the random generators (Python's, numpy's, torch's, the action space's and the envs').
    :param device: torch device: ``"cpu"``, ``"cuda"`` or ``"auto"`` (CUDA where available).
    :param _init_setup_model: build the networks now.

    The deviations from the paper are listed, with what was measured for each, on SPPO's documentation page
    (``docs/modules/sppo.md``, "Comments").
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"TOLDPolicy": TOLDPolicy, "MlpPolicy": TOLDPolicy}
    policy: TOLDPolicy
    replay_buffer: ShieldedReplayBuffer
    observation_space: spaces.Box  # checked by check_spaces
    action_space: spaces.Box

    def __init__(
        self,
        policy: str | type[TOLDPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 1_000_000,
        learning_starts: int = 5000,
        batch_size: int | None = None,
        tau: float = 0.01,
        gamma: float | Literal["auto"] = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        horizon: int | None = None,
        target_update_interval: int = 2,
        shield: ShieldingRule | str | None = "auto",
        permissive_shield: bool = False,
        on_intervention: OnIntervention = "restart",
        penalty: float = 1.0,
        intervention_target: float | None = None,
        termination_model: bool | Literal["auto"] = "auto",
        told: TOLDName = "paper",
        refine_shield: bool | Literal["auto"] = "auto",
        refine_backup_fraction: float = 0.25,
        planner_kwargs: dict[str, Any] | None = None,
        topo_kwargs: dict[str, Any] | None = None,
        sizes: SizesName = "cpu",
        plan_at_predict: bool = True,
        shield_at_predict: bool = True,
        compile: CompileMode = "auto",
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        if optimize_memory_usage:
            raise ValueError("SPPO's replay buffer keeps next observations explicitly: use optimize_memory_usage=False.")
        check_told_name(told)
        if termination_model not in (True, False, "auto"):
            raise ValueError(f'termination_model is True, False or "auto" (where the task ends), not {termination_model!r}.')
        if (given := (policy_kwargs or {}).get("told", told)) != told:
            raise ValueError(f"Choose TOLD's variant with SPPO's told argument (told={given!r}), not policy_kwargs.")
        check_discount_source(planner_kwargs, topo_kwargs)
        check_on_intervention(on_intervention, SPPO_ON_INTERVENTION, "SPPO")
        check_penalty(penalty, "SPPO")
        if gamma == "auto" and env is not None:  # the episode length is the env's: make it as SB3 would, once
            env = self._wrap_env(maybe_make_env(env, verbose), verbose)
        named = named_sizes(sizes)
        batch_size = named.batch_size if batch_size is None else batch_size
        horizon = named.horizon if horizon is None else horizon
        super().__init__(
            policy,
            env,
            learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=resolve_gamma(gamma, env if isinstance(env, VecEnv) else None),
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=ShieldedReplayBuffer,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            policy_kwargs={**named.policy_kwargs(), **(policy_kwargs or {}), "told": told},
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            support_multi_env=True,
        )
        self.horizon = horizon
        self.target_update_interval = target_update_interval
        self.shield = shield
        self.permissive_shield = permissive_shield
        self.on_intervention = on_intervention
        self.penalty = penalty
        if intervention_target is not None and not 0.0 <= intervention_target < 1.0:
            raise ValueError(
                "intervention_target is the share of env steps the shield may intervene on, in [0, 1); got "
                f"{intervention_target}."
            )
        self.intervention_target = intervention_target
        self.intervention_price = (
            None if intervention_target is None else PIDLagrangian.starting_at(intervention_target, penalty)
        )
        self.intervention_rate = 0.0
        self.policy_kwargs["intervention"] = intervention_target is not None
        if termination_model == "auto":
            termination_model = self.env is not None and task_terminates(self.env)
        self.termination_model = bool(termination_model)
        self.policy_kwargs["termination"] = self.termination_model
        self.told = told
        if refine_shield not in (True, False, "auto"):
            raise ValueError(f'refine_shield is True, False or "auto" (refine a learnable rule); got {refine_shield!r}.')
        self.refine_shield = refine_shield if refine_shield == "auto" else bool(refine_shield)
        if not 0.0 <= refine_backup_fraction <= 1.0:
            raise ValueError(
                f"refine_backup_fraction is a share of the warm-up steps, in [0, 1]; got {refine_backup_fraction}."
            )
        self.refine_backup_fraction = refine_backup_fraction
        self.sizes = sizes
        self.planner_config = MPPIConfig(**{"horizon": horizon, **named.planner_kwargs(), **(planner_kwargs or {})})
        self.topo_config = TOPOConfig(**(topo_kwargs or {}))
        self.plan_at_predict = plan_at_predict
        self.shield_at_predict = shield_at_predict
        check_compile_mode(compile)
        self.compile = compile
        self.shield_rule: ShieldingRule | None = None
        self.alternatives_executed = 0  # steps whose executed action was a planner's alternative (num_candidates > 1)
        self.planner_warm_start: np.ndarray | None = None  # training's plan mean, saved with the model (see save)
        self._init_safety(metrics_window=stats_window_size)
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up
    @staticmethod
    def _wrap_env(env: GymEnv, verbose: int = 0, monitor_wrapper: bool = True) -> VecEnv:
        check_spaces(env.observation_space, env.action_space)  # before SB3's own, less helpful, assertions
        return OffPolicyAlgorithm._wrap_env(env, verbose, monitor_wrapper)

    def _setup_model(self) -> None:
        check_spaces(self.observation_space, self.action_space)
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        policy = self.policy_class(self.observation_space, self.action_space, self.lr_schedule, **self.policy_kwargs)
        assert isinstance(policy, TOLDPolicy), "SPPO needs a TOLDPolicy"
        self.policy = policy.to(self.device)
        self._convert_train_freq()
        if self.shield_rule is None:
            self.shield_rule = resolve_shielding_rule(self.shield, self.env, required=False)
            if self.shield_rule is not None and self.permissive_shield:
                make_permissive(self.shield_rule)
        if self.shield_rule is not None and self.env is not None:
            check_held_steps_are_shielded(self.env, "SPPO's shield")
        learnable = isinstance(self.shield_rule, RefinableRule)
        if self.refine_shield is True and not learnable:
            raise ValueError(
                "refine_shield=True fits the shielding rule on the replay buffer, which needs a learnable rule "
                "(sppo_sb3.shield.LearnedDynamicsRule, LatentModelRule or LearnedCostCriticRule with your backup policy), "
                f'got {self.shield_rule!r}. Pass shield=LearnedDynamicsRule(...) or refine_shield="auto".'
            )
        if isinstance(self.shield_rule, LatentModelRule):  # it rolls Q̄ on this model's TOLD
            self.shield_rule.bind(self.policy.model, self._told_inputs)
        self._setup_planner_and_update()
        if self.verbose >= 1:
            print(self.sizes_summary())

    def sizes_summary(self) -> str:
        """The sizes this model runs at, in one line (printed at set-up with ``verbose >= 1``)."""
        told, plan = self.policy_kwargs, self.planner_config
        return (
            f"SPPO sizes ({self.sizes!r} and overrides): TOLD latent {told['latent_dim']}, encoder {told['encoder_dim']}, "
            f"hidden {told['hidden_dim']}; MPPI {plan.num_samples} samples, {plan.num_elites} elites, {plan.iterations} "
            f"iterations, horizon {plan.horizon}; batches of {self.batch_size} sequences of {self.horizon} steps"
        )

    @property
    def shield_is_learned(self) -> bool:
        """Whether :meth:`train` fits the rule on ``B``: a learnable rule, unless ``refine_shield=False``."""
        return isinstance(self.shield_rule, RefinableRule) and self.refine_shield is not False

    def _told_inputs(self, raw_obs: np.ndarray) -> np.ndarray:
        """Raw observations as TOLD reads them: normalised where the env is wrapped in ``VecNormalize``."""
        if self._vec_normalize_env is None:
            return raw_obs
        normalized = self._vec_normalize_env.normalize_obs(raw_obs)
        assert isinstance(normalized, np.ndarray)  # SPPO's spaces are flat Boxes
        return normalized

    def _setup_planner_and_update(self) -> None:
        """The planner, the TOPO update (compiled or eager, see ``compile``) and training's warm start."""
        compile = should_compile(self.compile, self.device)
        if compile and not (supports_tensor_step(self.policy.optimizer) and supports_tensor_step(self.policy.pi_optimizer)):
            if self.compile is True:
                raise ValueError("compile=True needs TOLDPolicy's default optimizer (Adam); pass compile=False for others.")
            compile = False
        self.planner = MPPIPlanner(self.planner_config, self.policy.model.action_dim, self.gamma, self.device, compile=compile)
        self._topo_update = CompiledFunction(topo_update, compile, self.device, "TOPO update")
        self._plan_mean = self._restore_warm_start()
        self._train_stats = th.zeros(len(TOPO_STATS), device=self.device)
        self._train_stats_count = 0

    @property
    def compile_stats(self) -> dict[str, float]:
        """How many graphs the planner and the TOPO update compiled so far, and the seconds that took."""
        functions = (self.planner.function, self._topo_update)
        return {
            "planner_graphs": self.planner.function.compilations,
            "update_graphs": self._topo_update.compilations,
            "seconds": sum(f.compile_seconds for f in functions),
        }

    def _restore_warm_start(self) -> th.Tensor:
        """Training's warm start as saved with the model, or a cold start if there is none or ``n_envs`` changed."""
        cold = self.planner.initial_mean(self.n_envs)
        saved = self.planner_warm_start
        return th.as_tensor(saved, device=self.device) if saved is not None and saved.shape == cold.shape else cold

    def _setup_replay_buffer(self) -> None:
        """Allocate ``B``/``B̃`` on the first ``learn``, so that loading a model to deploy it allocates nothing."""
        if self.replay_buffer is not None:
            return
        price = self._price()
        kwargs = {
            "on_intervention": self.on_intervention,
            "penalty": self.penalty if price is None else price,
            "optimize_memory_usage": self.optimize_memory_usage,
        }
        kwargs.update(self.replay_buffer_kwargs)
        self.replay_buffer = ShieldedReplayBuffer(
            self.buffer_size, self.observation_space, self.action_space, device=self.device, n_envs=self.n_envs, **kwargs
        )

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        self._setup_replay_buffer()
        for optimizer in (self.policy.optimizer, self.policy.pi_optimizer):  # the update's Adam state, once per learn
            init_optimizer_state(optimizer)
        envs_reset = reset_num_timesteps or self._last_obs is None  # SB3 resets the envs
        if envs_reset or self._plan_mean.shape[0] != self.n_envs:  # or set_env gave another number of envs
            self._plan_mean = self.planner.initial_mean(self.n_envs)  # plans start cold
        setup = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        if self.shield_rule is not None:  # probe the rule on the env's real observations before it decides anything
            raw_obs = self._last_original_obs if self._vec_normalize_env is not None else self._last_obs
            self.shield_rule.check_action_space(self.action_space, raw_obs)  # type: ignore[arg-type]
        return setup

    # ------------------------------------------------------------------ exploration phase (Alg. 1 lines 3–9)
    def _propose_actions(self, obs: np.ndarray, raw_obs: np.ndarray, learning_starts: int) -> np.ndarray:
        """The unshielded planner's flat ``(E, K, A)`` candidates in [-1, 1], best first: one uniform action during
        warm-up (some of them the backup's, with ``refine_shield``), MPPI's plan and its alternatives afterwards (Alg. 2;
        ``K`` is the planner's ``num_candidates``)."""
        if self.num_timesteps < learning_starts:
            warmup = np.random.uniform(-1.0, 1.0, size=(len(obs), self.planner.action_dim)).astype(np.float32)
            if self.shield_is_learned and self.refine_backup_fraction > 0.0:
                assert self.shield_rule is not None
                backup = np.random.random(len(obs)) < self.refine_backup_fraction
                if backup.any():
                    zeta = self.shield_rule.checked_backup(raw_obs[backup], self.planner.action_dim)
                    zeta = zeta.reshape(-1, *self.action_space.shape)  # type: ignore[misc]
                    warmup[backup] = self.policy.scale_action(zeta).reshape(int(backup.sum()), -1)
            return warmup[:, None]
        obs_tensor = th.as_tensor(obs, dtype=th.float32, device=self.device)
        plan = self.planner.plan(self.policy.model, obs_tensor, self._plan_mean, self.num_timesteps, penalty=self._price())
        self._plan_mean = plan.mean
        return plan.candidates.cpu().numpy()

    def _env_actions(self, scaled: np.ndarray) -> np.ndarray:
        """Flat ``(E, K, A)`` candidates in [-1, 1] (the planner's and TOLD's) in the env's units and shape,
        ``(E, K, *action_shape)``."""
        flat = scaled.reshape(-1, *self.action_space.shape)  # type: ignore[misc]
        return self.policy.unscale_action(flat).reshape(*scaled.shape[:2], *self.action_space.shape)  # type: ignore[misc]

    def _shield(self, raw_obs: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. 12 on every env at once, over each env's candidates best first
        (:meth:`~sppo_sb3.shield.ShieldingRule.shield_first_accepted`): the executed actions (env units and shape),
        where the shield intervened (accepted no candidate) and where its replacement was an edit."""
        if self.shield_rule is None:
            return candidates[:, 0], np.zeros(len(candidates), dtype=bool), np.zeros(len(candidates), dtype=bool)
        flat = candidates.reshape(*candidates.shape[:2], -1)  # rules act on flat actions
        decision, choice = self.shield_rule.shield_first_accepted(raw_obs, flat)
        self.alternatives_executed += int(np.sum(choice > 0))
        executed = decision.actions.reshape(candidates[:, 0].shape).astype(self.action_space.dtype)
        return executed, decision.intervened, decision.edits

    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        train_freq: TrainFreq,
        replay_buffer: ReplayBuffer,
        action_noise: Any = None,
        learning_starts: int = 0,
        log_interval: int | None = None,
    ) -> RolloutReturn:
        """Shielded planning in the real env (Alg. 1 lines 3–9): every executed action — warm-up ones too — is safe."""
        assert self._last_obs is not None
        self.policy.set_training_mode(False)
        num_collected_steps, num_collected_episodes = 0, 0
        callback.on_rollout_start()
        while should_collect_more_steps(train_freq, num_collected_steps, num_collected_episodes):
            raw_obs = self._last_original_obs if self._vec_normalize_env is not None else self._last_obs
            proposed = self._propose_actions(self._last_obs, raw_obs, learning_starts)  # type: ignore[arg-type]
            candidates = self._env_actions(proposed)
            actions, intervened, edited = self._shield(raw_obs, candidates)  # type: ignore[arg-type]

            new_obs, rewards, dones, infos = env.step(actions)
            assert isinstance(new_obs, np.ndarray)  # flat Box observations (check_spaces)
            check_finite(new_obs, rewards)
            for info, shielded, edit, wanted in zip(infos, intervened, edited, candidates[:, 0]):
                record_own_intervention(info, bool(shielded), bool(edit), wanted)
            self._update_intervention_price(infos)
            self.num_timesteps += env.num_envs
            num_collected_steps += 1
            callback.update_locals(locals())
            if not callback.on_step():
                return RolloutReturn(num_collected_steps * env.num_envs, num_collected_episodes, continue_training=False)

            self._record_safety(rewards, dones, infos, intervened, required=self.shield_rule is not None)
            self._update_info_buffer(infos, dones)
            self._store_transition(replay_buffer, self.policy.scale_action(actions), new_obs, rewards, dones, infos)
            self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
            self._plan_mean[th.as_tensor(dones, device=self.device)] = 0.0  # a new episode starts without a warm start
            for done in dones:
                if done:
                    num_collected_episodes += 1
                    self._episode_num += 1
                    if log_interval is not None and self._episode_num % log_interval == 0:
                        self.dump_logs()
        callback.on_rollout_end()
        return RolloutReturn(num_collected_steps * env.num_envs, num_collected_episodes, continue_training=True)

    def _price(self) -> float | None:
        """What a predicted intervention costs the planner and the prior now (``intervention_target``; None: nothing)."""
        return None if self.intervention_price is None else self.intervention_price.multiplier

    def _update_intervention_price(self, infos: list[dict[str, Any]]) -> None:
        """Average the share of env steps the shield intervened on, and step the PID multiplier toward the target."""
        if self.intervention_price is None:
            return
        env_steps = sum(int(info.get(ENV_STEPS_KEY, 1)) for info in infos)
        share = sum(intervention_count(info) for info in infos) / max(env_steps, 1)
        self.intervention_rate += (share - self.intervention_rate) / INTERVENTION_RATE_WINDOW
        self.intervention_price.update(self.intervention_rate)
        if self.replay_buffer is not None:  # B̃'s relabel reads the price when it samples
            self.replay_buffer.penalty = self.intervention_price.multiplier

    # ------------------------------------------------------------------ training phase (Alg. 1 lines 10–13)
    def train(self, gradient_steps: int, batch_size: int) -> None:
        """TOPO on sequences of ``B̃`` (Alg. 3), EMA target every ``target_update_interval`` updates.

        Losses stay on the device and are summed; :meth:`dump_logs` reads them once per log interval.
        """
        policy = self.policy
        policy.set_training_mode(True)
        self._update_learning_rate([policy.optimizer, policy.pi_optimizer])
        lr = th.tensor(policy.optimizer.param_groups[0]["lr"], device=self.device)
        models, optimizers = (policy.model, policy.model_target), (policy.optimizer, policy.pi_optimizer)
        for _ in range(gradient_steps):
            batch = self.replay_buffer.sample_sequences(batch_size, self.horizon, env=self._vec_normalize_env)
            noise = th.randn(batch.actions.shape, device=self.device)
            self._n_updates += 1
            ema = th.tensor(self.tau if self._n_updates % self.target_update_interval == 0 else 0.0, device=self.device)
            heads = draw_target_heads(policy.model, self.device)  # None (nothing drawn) for the paper's TOLD
            price = self._price()
            penalty = None if price is None else th.tensor(price, device=self.device)
            stats = self._topo_update(
                *models, *optimizers, batch, noise, lr, ema, self.topo_config, self.gamma, heads, penalty
            )
            self._train_stats += stats
            self._train_stats_count += 1
        self.logger.record(N_UPDATES_LOG_KEY, self._n_updates, exclude="tensorboard")  # as SB3's off-policy algorithms
        if self.shield_is_learned:
            self._fit_shield_rule(gradient_steps, batch_size)
        policy.set_training_mode(False)
        self.planner.mark_stale()

    def _fit_shield_rule(self, gradient_steps: int, batch_size: int) -> None:
        """Alg. 1 line 12: the learned rule learns from real transitions of ``B`` (:meth:`RefinableRule.refine`)."""
        rule = self.shield_rule
        assert isinstance(rule, RefinableRule)
        losses = []
        for _ in range(gradient_steps):
            t = self.replay_buffer.sample_cost_transitions(batch_size)
            env_actions = self._env_actions(t.actions[:, None])[:, 0]  # rules flatten whatever the Box shape
            losses.append(rule.refine(t._replace(actions=env_actions), batch_size))
        self.logger.record("train/shield_loss", float(np.mean(losses)))

    def _record_train_stats(self) -> None:
        """Means of the TOPO statistics since the last dump (one device-to-host copy per log interval)."""
        self.logger.record("train/horizon", self.planner_config.horizon_at(self.num_timesteps))
        self.logger.record("train/min_std", self.planner_config.min_std_at(self.num_timesteps))
        if self._train_stats_count:
            means = (self._train_stats / self._train_stats_count).tolist()
            for key, value in zip(TOPO_STATS, means):
                if (key != "termination" or self.termination_model) and (key != "intervention" or self.intervention_price):
                    self.logger.record(f"train/{key}", value)
            self._train_stats.zero_()
            self._train_stats_count = 0

    def dump_logs(self) -> None:
        self._record_safety_logs()
        if self.planner_config.num_candidates > 1:
            self.logger.record("safety/alternatives_executed", self.alternatives_executed)
        if self.intervention_price is not None:
            self.logger.record("safety/intervention_rate", self.intervention_rate)
            self.logger.record("train/intervention_price", self.intervention_price.multiplier)
        self._record_train_stats()
        super().dump_logs()

    # ------------------------------------------------------------------ deployment
    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """Plan with MPPI (or the policy prior if ``plan_at_predict`` is False), then shield.

        The planner's warm start is a recurrent state, as in SB3's ``RecurrentPPO``: pass the returned ``state`` to
        the next call (``evaluate_policy`` and ``EvalCallback`` do) and ``episode_start`` where an episode begins; with
        ``state=None`` the plan starts cold. Training keeps its own warm start, which ``predict`` never touches. A
        deterministic plan is a pure function of ``(observation, state)``: its sampling noise is drawn from a CPU
        generator seeded the same way on every call, so it is also the same on every device. The observation is one
        the env returns (normalised under ``VecNormalize``; the shield reads its unnormalised version).

        :return: the actions and the new state: ``(mean,)``, the ``(n_envs, horizon, action dims)`` plan mean, or None
            when ``plan_at_predict`` is False.
        """
        obs, vectorized = self._checked_observation(observation)
        raw_obs = self._vec_normalize_env.unnormalize_obs(obs) if self._vec_normalize_env is not None else obs
        assert isinstance(raw_obs, np.ndarray)
        obs_tensor = th.as_tensor(obs, dtype=th.float32, device=self.device)
        new_state: tuple[np.ndarray, ...] | None = None
        if self.plan_at_predict:
            prev_mean = self._warm_start_from_state(state, episode_start, len(obs))
            generator = th.Generator().manual_seed(0) if deterministic else None  # on the CPU: the same on every device
            model, step = self.policy.model, self.num_timesteps
            plan = self.planner.plan(model, obs_tensor, prev_mean, step, deterministic, generator, self._price())
            scaled, new_state = plan.candidates, (plan.mean.cpu().numpy(),)
        else:
            with th.no_grad():
                scaled = self.policy._predict(obs_tensor)[:, None]
        candidates = self._env_actions(scaled.cpu().numpy())
        actions = self._shield(raw_obs, candidates)[0] if self.shield_at_predict else candidates[:, 0]
        actions = np.clip(actions, self.action_space.low, self.action_space.high)
        return (actions if vectorized else actions[0]), new_state

    def _checked_observation(self, observation: Any) -> tuple[np.ndarray, bool]:
        """``(n_envs, obs_dim)`` float32 observations and whether they were batched, checked by SB3's own ``predict``
        path, with its messages: ``BasePolicy.predict``'s check for a Gym ``(obs, info)`` tuple, then
        ``obs_to_tensor``'s for the shape."""
        if isinstance(observation, tuple):
            self.policy.predict(observation)  # type: ignore[arg-type]  # SB3's check of the Gym/VecEnv API mix-up
        obs_tensor, vectorized = self.policy.obs_to_tensor(observation)
        assert isinstance(obs_tensor, th.Tensor)  # TOLDPolicy's observation space is a Box
        return obs_tensor.cpu().numpy().astype(np.float32, copy=False), vectorized

    def _warm_start_from_state(
        self, state: tuple[np.ndarray, ...] | None, episode_start: np.ndarray | None, n_envs: int
    ) -> th.Tensor:
        """``predict``'s state as the planner's previous mean, zeroed where an episode starts."""
        if state is None:
            return self.planner.initial_mean(n_envs)
        prev_mean = th.as_tensor(np.asarray(state[0], dtype=np.float32), device=self.device).clone()
        if episode_start is not None:
            starts = th.as_tensor(np.asarray(episode_start, dtype=bool).reshape(-1), device=self.device)
            if len(starts) == len(prev_mean):
                prev_mean[starts] = 0.0
        return prev_mean

    def learn(
        self: SelfSPPO,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "SPPO",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfSPPO:
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps, progress_bar)

    # ------------------------------------------------------------------ persistence
    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "planner", "_topo_update", "_plan_mean", "_train_stats"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer", "policy.pi_optimizer"], []

    def save(self, path: Any, exclude: Any = None, include: Any = None) -> None:
        """Save as SB3 does, with training's warm start, so that a resumed run plans exactly as the saved one would."""
        self.planner_warm_start = self._plan_mean.cpu().numpy()
        super().save(path, exclude, include)


def record_own_intervention(info: dict[str, Any], intervened: bool, edited: bool, proposal: np.ndarray) -> None:
    """Write SPPO's own shield decision into a step's info, beside an env-level shield's.

    SPPO shields the first env step of its action; where the env holds it for more (``ShieldWrapper(...,
    action_repeat=k)``), the wrapper has checked the later ones and counted its interventions in the info. The step is
    an intervention if either replaced the action, and the count is the sum (the wrapper accepts what SPPO executed on
    the first env step: an accepted proposal, or the backup's action).

    :param info: the step's info, as the env returned it.
    :param intervened: whether SPPO's own shield replaced its proposal.
    :param edited: whether that replacement was a permissive rule's edit (counted apart, among the interventions).
    :param proposal: the planner's proposal, in env units (what ``B̃`` relabels with).
    """
    count = int(intervened) + intervention_count(info)
    info[INTERVENED_KEY], info[INTERVENTIONS_KEY], info[PROPOSED_ACTION_KEY] = count > 0, count, proposal
    if edited or EDITS_KEY in info:
        info[EDITS_KEY] = int(edited) + edit_count(info)


def check_discount_source(planner_kwargs: dict[str, Any] | None, topo_kwargs: dict[str, Any] | None) -> None:
    """Reject a discount given to the planner or the update alone: SPPO's ``gamma`` is the one both read."""
    for name, kwargs in (("planner_kwargs", planner_kwargs), ("topo_kwargs", topo_kwargs)):
        if kwargs and "gamma" in kwargs:
            raise ValueError(
                f"SPPO's discount is its gamma argument, which the planner (eq. 10) and the update (eq. 16) both read: "
                f"remove 'gamma' from {name} and pass SPPO(..., gamma={kwargs['gamma']!r}) (or gamma='auto')."
            )


def check_finite(obs: np.ndarray, rewards: np.ndarray) -> None:
    """Stop with a clear error when the env returns NaN/inf, before it poisons the replay buffer."""
    if not (np.all(np.isfinite(obs)) and np.all(np.isfinite(rewards))):
        raise ValueError(
            "The environment returned a non-finite observation or reward. SPPO cannot learn from NaN/inf: check the "
            "env's dynamics or wrap it with stable_baselines3.common.vec_env.VecCheckNan to find the step."
        )
