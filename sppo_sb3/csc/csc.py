"""CSC: Conservative Safety Critics (Bharadhwaj et al., "Conservative Safety Critics for Exploration", ICLR 2021).

The paper compares SPPO with CSC, "the variant of PDO [...] in which well-learned conservative critics are applied
to filter unsafe behaviors" ([28], Section V-A.3). The policy optimiser is on-policy, as in the CSC paper (which
takes a natural-gradient step on a Lagrangian): here a PPO clipped step, which is SB3's and the simplest to get
right. Around it:

* a conservative cost critic ``Q_C(s, a)`` trained off-policy from a replay buffer of every executed transition
  ``(s, a, c, s', done)``, with the CQL-style objective of the CSC paper's eq. 2: the Bellman error to
  ``c + γ_C(1 - done) Q_C⁻(s', a' ~ π)`` plus ``α_cql (E_{(s,a)~D}[Q_C] - E_{s~D, a~π}[Q_C])`` — pushing ``Q_C``
  up on the policy's actions and down on the executed ones, so it over-estimates cost where the data is thin;
* the action-rejection sampler of the CSC paper's Alg. 1 on every executed step (``rejection_sample_actions``);
* the primal-dual update: the PPO advantage is ``(A_R - λ A_C) / (1 + λ)`` with the critic's cost advantage
  ``A_C(s, a) = Q_C(s, a) - E_{a'~π_old}[Q_C(s, a')]`` (the gradient of the Lagrangian's ``λ E_{a~π}[Q_C]`` term),
  and ``λ ≥ 0`` by dual ascent on the measured episode cost: ``λ ← max(0, λ + η_λ (Ĵ_C - χ))``, the multiplier of PDO
  (:class:`~sppo_sb3.common.lagrange.LagrangianMixin`).

Rollouts are the shared cost-aware loop (:class:`~sppo_sb3.common.on_policy.SafeOnPolicyMixin`) with two hooks: the
sampler chooses the executed actions, and every transition also goes to the cost critic's replay buffer.

Deviations from Bharadhwaj et al.: the PPO clipped step in place of their natural-gradient step (above); CQL's
push-up term uses policy actions only, not uniform ones (see :meth:`CSC.train_cost_critic`); the dual step is the
projected gradient step shared with PDO. ``hyperparams/csc.yml`` holds the settings of SAILR's authors' CSC runs on
these tasks. On the Point Robot no configuration tried learned to keep an episode safe within 100k env steps (CSC's
documentation page says why).
"""

from __future__ import annotations

import io
import pathlib
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.save_util import load_from_pkl, save_to_pkl
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import obs_as_tensor, polyak_update
from stable_baselines3.common.vec_env import VecEnv
from torch.nn import functional as F

from sppo_sb3.common.lagrange import DEFAULT_COST_LIMIT, LagrangianMixin, lagrangian_advantage
from sppo_sb3.common.on_policy import ActionChoice, SafeOnPolicyMixin
from sppo_sb3.csc.policies import CSCPolicy

SelfCSC = TypeVar("SelfCSC", bound="CSC")


class CSC(LagrangianMixin, SafeOnPolicyMixin, PPO):
    """Conservative Safety Critics on top of PPO (see the module docstring for the design).

    Costs are read from ``info["cost"]`` (``MissingCostError`` otherwise). ``self.safety_metrics`` is fed every
    env step; a step whose first policy sample was rejected by the critic counts as an intervention.

    :param policy: the policy model ("MlpPolicy" = :class:`CSCPolicy`).
    :param env: the environment (Box observations, Box action space with finite bounds, ``info["cost"]``).
    :param learning_rate: learning rate of the actor and reward value head (PPO).
    :param n_steps: env steps per env per rollout (PPO).
    :param batch_size: PPO minibatch size.
    :param n_epochs: PPO epochs per rollout.
    :param gamma: discount of the rewards.
    :param gae_lambda: GAE λ of the reward advantage ``A_R``.
    :param clip_range: PPO clipping of the policy ratio (stands in for the paper's KL trust region).
    :param clip_range_vf: PPO clipping of the value function, or None.
    :param normalize_advantage: normalise the combined advantage per minibatch (PPO).
    :param ent_coef: entropy bonus (PPO).
    :param vf_coef: value loss weight (PPO).
    :param max_grad_norm: gradient clipping of the PPO update.
    :param target_kl: early stopping of the PPO epochs on this KL, or None.
    :param cost_limit: the limit ``χ`` of the expected episode cost of the CSC paper's constrained problem.
    :param cost_gamma: discount of the cost critic's Bellman target (None: ``gamma``, as in the CSC paper). A
        shorter horizon (e.g. 0.95) makes ``Q_C`` a critic of nearer failures.
    :param cost_threshold: the sampler's admissibility threshold ``ε`` on ``Q_C`` (CSC paper Alg. 1); None gives
        ``(1 - cost_gamma) χ``, the paper's per-step share of the episode limit, which is very strict for small ``χ``.
    :param n_action_samples: the most samples drawn per executed step (100 in the CSC paper).
    :param reject_in_predict: whether ``predict`` also applies the sampler (``deterministic=True``: the mean
        action first, then fixed-seed fallback samples, see :class:`CSCPolicy`).
    :param cql_alpha: weight ``α`` of the conservative regulariser of eq. 2 (0 gives a plain TD critic).
    :param n_cql_actions: policy samples per state in the regulariser.
    :param cost_learning_rate: learning rate of the cost critic.
    :param cost_buffer_size: capacity of the cost critic's replay buffer (transitions).
    :param cost_batch_size: minibatch size of the cost critic.
    :param cost_gradient_steps: cost critic gradient steps per rollout.
    :param cost_tau: Polyak coefficient of the target cost critic ``Q_C⁻``.
    :param n_cost_baseline_samples: samples of ``π_old`` that estimate ``E_{a~π_old}[Q_C(s, a)]`` in ``A_C``.
    :param lagrange_init: initial multiplier ``λ``.
    :param lagrange_lr: dual step size ``η_λ``.
    :param stats_window_size: window of the rollout logging averages.
    :param tensorboard_log: TensorBoard log folder, or None.
    :param policy_kwargs: extra arguments of the policy (e.g. ``net_arch``, ``cost_net_arch``, ``cost_critic_max``).
    :param verbose: 0 silent, 1 info, 2 debug.
    :param seed: seed of the pseudo random generators.
    :param device: "cpu", "cuda" or "auto".
    :param _init_setup_model: whether to build the networks on creation.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": CSCPolicy}
    uses_cost_critic = False  # its cost critic is Q_C(s, a) of CSCPolicy, not the V_C(s) head of the shared loop
    policy: CSCPolicy
    _cost_buffer: ReplayBuffer | None

    def __init__(
        self,
        policy: str | type[CSCPolicy],
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
        target_kl: float | None = None,
        cost_limit: float = DEFAULT_COST_LIMIT,
        cost_gamma: float | None = None,
        cost_threshold: float | None = 0.1,
        n_action_samples: int = 100,
        reject_in_predict: bool = True,
        cql_alpha: float = 0.5,
        n_cql_actions: int = 4,
        cost_learning_rate: float = 1e-3,
        cost_buffer_size: int = 1_000_000,
        cost_batch_size: int = 256,
        cost_gradient_steps: int = 128,
        cost_tau: float = 0.005,
        n_cost_baseline_samples: int = 16,
        lagrange_init: float = 0.0,
        lagrange_lr: float = 0.05,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        self._init_lagrange(cost_limit, lagrange_init, lagrange_lr)
        if cql_alpha < 0:
            raise ValueError(f"cql_alpha must be >= 0, got {cql_alpha}")
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
            target_kl=target_kl,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        if self.env is not None:
            if not isinstance(self.action_space, spaces.Box):
                raise ValueError(
                    f"CSC supports Box action spaces only (Gaussian policy, continuous cost critic), got {self.action_space}"
                )
            if not isinstance(self.observation_space, spaces.Box):
                raise ValueError(
                    f"CSC supports Box observations only, got {self.observation_space}; "
                    "flatten Dict observations with gymnasium.wrappers.FlattenObservation."
                )
        self.cost_gamma = gamma if cost_gamma is None else cost_gamma
        self.cost_threshold = (1.0 - self.cost_gamma) * cost_limit if cost_threshold is None else cost_threshold
        self.n_action_samples = n_action_samples
        self.reject_in_predict = reject_in_predict
        self.cql_alpha = cql_alpha
        self.n_cql_actions = n_cql_actions
        self.cost_learning_rate = cost_learning_rate
        self.cost_buffer_size = cost_buffer_size
        self.cost_batch_size = cost_batch_size
        self.cost_gradient_steps = cost_gradient_steps
        self.cost_tau = cost_tau
        self.n_cost_baseline_samples = n_cost_baseline_samples
        self._init_safety()
        if _init_setup_model:
            self._setup_model()

    # ----------------------------------------------------------------------------------------------- setup
    def _setup_model(self) -> None:
        super()._setup_model()
        self._sync_policy()
        self._cost_buffer = None

    @property
    def cost_buffer(self) -> ReplayBuffer:
        """The cost critic's replay buffer, allocated on first use (a model loaded to deploy allocates none), and anew
        for a new env with another number of envs (the old transitions cannot be kept)."""
        if self._cost_buffer is None or self._cost_buffer.n_envs != self.n_envs:
            self._cost_buffer = self._make_cost_buffer()
        return self._cost_buffer

    @cost_buffer.setter
    def cost_buffer(self, buffer: ReplayBuffer) -> None:
        self._cost_buffer = buffer

    def _make_cost_buffer(self) -> ReplayBuffer:
        action_shape = self.action_space.shape
        return ReplayBuffer(
            self.cost_buffer_size,
            self.observation_space,
            spaces.Box(-1.0, 1.0, shape=action_shape, dtype=np.float32),  # normalised clipped actions
            device=self.device,
            n_envs=self.n_envs,
            handle_timeout_termination=True,
        )

    def _sync_policy(self) -> None:
        """Hand the sampler settings (attributes of the algorithm, saved with it) to the policy."""
        self.policy.cost_threshold = self.cost_threshold
        self.policy.n_action_samples = self.n_action_samples
        self.policy.reject_in_predict = self.reject_in_predict

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_cost_buffer"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer", "policy.cost_optimizer"], []

    def save_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """Save the cost critic's replay buffer (not part of ``save``, like SB3's off-policy replay buffers)."""
        save_to_pkl(path, self.cost_buffer, self.verbose)

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """Load a replay buffer saved by :meth:`save_replay_buffer`."""
        buffer = load_from_pkl(path, self.verbose)
        if not isinstance(buffer, ReplayBuffer):
            raise TypeError(f"{path} does not hold a ReplayBuffer (got {type(buffer).__name__})")
        buffer.device = self.device
        self.cost_buffer = buffer

    # ----------------------------------------------------------------------------------------------- acting
    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """Like SB3's ``predict``; with ``reject_in_predict`` the action passes the cost critic's sampler."""
        self._sync_policy()
        return super().predict(observation, state, episode_start, deterministic)

    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
    ) -> bool:
        """The shared cost-aware rollout loop, with the sampler settings handed to the policy first."""
        self._sync_policy()
        return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)

    def _choose_actions(self, obs_tensor: th.Tensor | dict[str, th.Tensor]) -> ActionChoice:
        """The rejection sampler (CSC paper Alg. 1) on every step; a step whose first sample was rejected counts as an
        intervention. The rollout buffer keeps the executed (raw) action and its log-probability under ``π_old``."""
        sample, distribution = self.policy.sample_safe_actions(obs_tensor)
        actions = sample.actions.cpu().numpy().reshape(-1, *self.action_space.shape)  # type: ignore[misc]
        log_probs = distribution.log_prob(sample.actions)
        values = self.policy.predict_values(obs_tensor)
        return ActionChoice(actions, values, log_probs, sample.first_rejected.cpu().numpy())

    def _store_extra_transition(
        self,
        obs: np.ndarray,
        new_obs: np.ndarray,
        actions: np.ndarray,
        costs: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Every executed transition ``(s, a, c, s', done)`` goes to the cost critic's replay buffer, with the action
        clipped and rescaled to [-1, 1] and ``s'`` the terminal observation where an episode ended."""
        next_obs = np.array(new_obs, copy=True)
        for idx in np.flatnonzero(dones):
            terminal_obs = infos[idx].get("terminal_observation")
            if terminal_obs is not None:
                next_obs[idx] = terminal_obs
        with th.no_grad():
            flat_actions = th.as_tensor(actions, device=self.device).reshape(len(actions), -1)
            critic_actions = self.policy.normalize_actions(flat_actions).cpu().numpy()
        self.cost_buffer.add(obs, next_obs, critic_actions, costs, dones, infos)  # type: ignore[arg-type]

    # ----------------------------------------------------------------------------------------------- learning
    def train_cost_critic(self, gradient_steps: int, batch_size: int | None = None) -> dict[str, float]:
        """Fit ``Q_C`` with the conservative objective of the CSC paper's eq. 2 on the replay buffer.

        ``loss = ½ (Q_C(s,a) - c - γ_C(1-done) Q_C⁻(s', a'~π))² + α_cql (Q_C(s,a) - mean_k Q_C(s, a_k ~ π))`` with
        ``n_cql_actions`` samples ``a_k`` of ``π(·|s)``, as in eq. 2; Polyak update of ``Q_C⁻`` after each step.

        Uniform actions (CQL's ``μ = Unif``) are left out on purpose: with a clipped Gaussian policy, half the data
        sits on the Box's faces while uniform actions fill its interior, so the push-up would make the interior look
        costlier than the saturated actions and the sampler's argmin would favour full-force actions.

        :return: mean TD loss, CQL gap and ``Q_C`` on the data over the steps (empty if the buffer is empty).
        """
        if self.cost_buffer.size() == 0 or gradient_steps <= 0:
            return {}
        batch_size = self.cost_batch_size if batch_size is None else batch_size
        policy = self.policy
        for group in policy.cost_optimizer.param_groups:
            group["lr"] = self.cost_learning_rate
        td_losses, gaps, q_means = [], [], []
        for _ in range(gradient_steps):
            data = self.cost_buffer.sample(batch_size)
            with th.no_grad():
                next_actions = policy.normalize_actions(policy.get_distribution(data.next_observations).sample())
                next_q = policy.cost_values(data.next_observations, next_actions, target=True)
                target = data.rewards.flatten() + (1.0 - data.dones.flatten()) * self.cost_gamma * next_q
                gaussian = policy.gaussian(policy.get_distribution(data.observations))
                pi_actions = policy.normalize_actions(gaussian.sample((self.n_cql_actions,)))
            features = policy.cost_features(data.observations)
            q_data = policy.cost_critic(features, data.actions)
            td_loss = 0.5 * F.mse_loss(q_data, target)
            cql_gap = q_data.mean() - policy.cost_critic(features, pi_actions).mean()
            loss = td_loss + self.cql_alpha * cql_gap
            policy.cost_optimizer.zero_grad()
            loss.backward()
            policy.cost_optimizer.step()
            polyak_update(policy.cost_critic.parameters(), policy.cost_critic_target.parameters(), self.cost_tau)
            td_losses.append(td_loss.item())
            gaps.append(cql_gap.item())
            q_means.append(q_data.mean().item())
        return {"td_loss": float(np.mean(td_losses)), "cql_gap": float(np.mean(gaps)), "q_data": float(np.mean(q_means))}

    def cost_advantages(self, observations: np.ndarray, actions: np.ndarray, chunk: int = 4096) -> np.ndarray:
        """``A_C(s, a) = Q_C(s, a) - mean_k Q_C(s, a_k)``, ``a_k ~ π_old(·|s)``, for flat batches of raw actions."""
        policy = self.policy
        out = []
        with th.no_grad():
            for start in range(0, len(observations), chunk):
                obs = obs_as_tensor(observations[start : start + chunk], self.device)
                act = th.as_tensor(actions[start : start + chunk], device=self.device)
                q = policy.cost_values(obs, policy.normalize_actions(act))
                samples = policy.gaussian(policy.get_distribution(obs)).sample((self.n_cost_baseline_samples,))
                baseline = policy.cost_values(obs, policy.normalize_actions(samples)).mean(dim=0)
                out.append((q - baseline).cpu().numpy())
        return np.concatenate(out)

    def train(self) -> None:
        """One CSC iteration on the collected rollout: cost critic (eq. 2), dual step on ``λ``, then the PPO step on
        the Lagrangian advantage ``(A_R - λ A_C) / (1 + λ)``."""
        self._sync_policy()
        self.policy.set_training_mode(True)
        critic_stats = self.train_cost_critic(self.cost_gradient_steps)
        lam = self.update_lagrange_multiplier()

        buffer = self.rollout_buffer
        n_steps, n_envs = buffer.advantages.shape
        flat_obs = buffer.observations.reshape(n_steps * n_envs, *buffer.obs_shape)  # type: ignore[union-attr]
        flat_actions = buffer.actions.reshape(n_steps * n_envs, -1)
        cost_adv = self.cost_advantages(flat_obs, flat_actions).reshape(n_steps, n_envs)
        buffer.advantages = lagrangian_advantage(buffer.advantages, cost_adv, lam)

        super().train()

        for key, value in critic_stats.items():
            self.logger.record(f"train/cost_critic_{key}", value)
        self.logger.record("train/cost_advantage_mean", float(cost_adv.mean()))
        self.logger.record("train/cost_threshold", self.cost_threshold)

    def learn(
        self: SelfCSC,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "CSC",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfCSC:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
