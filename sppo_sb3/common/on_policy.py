"""Cost-aware on-policy machinery shared by the safe-RL baselines PDO, CPO and SAILR (SPEC §4).

SB3's ``RolloutBuffer`` and ``OnPolicyAlgorithm.collect_rollouts`` never see the step ``infos``, so the violation
indicator ``c(s, a) = info["cost"]`` never reaches the learner. This module adds, once for every on-policy safe
algorithm of the package:

- :func:`compute_gae`: GAE(λ) (Schulman et al. 2016, eqs. 11–16) of any per-step signal — used for the cost;
- :func:`lagrange_update` and :func:`lagrangian_advantage`: the dual and primal steps of the primal-dual methods
  (PDO, CSC);
- :class:`CostRolloutBuffer`: a ``RolloutBuffer`` that also stores costs, cost values, cost GAE and cost returns,
  and a per-step *learning mask* (SAILR does not learn from the steps after an intervention);
- :class:`CostActorCriticPolicy`: SB3's actor-critic with an extra cost value head ``V_C(s)``;
- :class:`EpisodeCostTracker`: the measured episode cost ``J_C`` compared with the cost limit ``d``;
- :class:`SafeOnPolicyMixin`: a cost-aware ``collect_rollouts`` that reads ``info["cost"]`` (failing on the first
  step with :class:`~sppo_sb3.common.costs.MissingCostError` when it is missing), feeds ``self.safety_metrics`` and
  logs it under ``safety/`` with the other logs.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Generator, Iterable
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.type_aliases import MaybeCallback, Schedule
from stable_baselines3.common.utils import explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from torch import nn
from torch.nn import functional as F

from sppo_sb3.common.safety import SafetyMetrics


def compute_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    episode_starts: np.ndarray,
    last_values: np.ndarray,
    dones: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation, GAE(γ, λ) (Schulman et al. 2016, eq. 16), of any per-step signal.

    ``δ_t = x_t + γ·(1 - done_t)·V(s_(t+1)) - V(s_t)`` and ``A_t = δ_t + γλ·(1 - done_t)·A_(t+1)``, where ``done_t``
    is ``episode_starts[t + 1]`` (``dones`` for the last step). Used with ``x = r`` for the reward and ``x = c`` for
    the cost (the cost advantage ``A_C`` of PDO and CPO). Same convention as SB3's ``RolloutBuffer``.

    :param rewards: ``(T, n_envs)`` per-step signal (reward or cost).
    :param values: ``(T, n_envs)`` value estimates of the states.
    :param episode_starts: ``(T, n_envs)`` whether step ``t`` starts an episode.
    :param last_values: ``(n_envs,)`` value of the state after the last step.
    :param dones: ``(n_envs,)`` whether the last step ended its episode.
    :param gamma: discount ``γ``.
    :param gae_lambda: GAE ``λ`` (1: Monte-Carlo with bootstrap, 0: one-step TD).
    :return: ``(advantages, returns)``, both ``(T, n_envs)`` float32; ``returns = advantages + values`` (TD(λ)).
    """
    rewards = np.asarray(rewards, dtype=np.float32)
    values = np.asarray(values, dtype=np.float32)
    n_steps = rewards.shape[0]
    advantages = np.zeros_like(rewards)
    last_gae = np.zeros(rewards.shape[1:], dtype=np.float32)
    for step in reversed(range(n_steps)):
        if step == n_steps - 1:
            next_non_terminal = 1.0 - np.asarray(dones, dtype=np.float32)
            next_values = np.asarray(last_values, dtype=np.float32).reshape(rewards.shape[1:])
        else:
            next_non_terminal = 1.0 - np.asarray(episode_starts[step + 1], dtype=np.float32)
            next_values = values[step + 1]
        delta = rewards[step] + gamma * next_values * next_non_terminal - values[step]
        last_gae = delta + gamma * gae_lambda * next_non_terminal * last_gae
        advantages[step] = last_gae
    return advantages, advantages + values


def lagrange_update(lagrange_multiplier: float, episode_cost: float, cost_limit: float, lagrange_lr: float) -> float:
    """Projected dual ascent on the Lagrange multiplier: ``λ ← max(0, λ + η_λ·(J_C - d))``.

    ``∂L/∂λ = -(J_C(π) - d)`` for ``L(π, λ) = J_R(π) - λ·(J_C(π) - d)``: the dual problem ``min_λ≥0 max_π L`` moves ``λ``
    up while the measured cost exceeds the limit and down (to 0 at most) while it is below.

    :param lagrange_multiplier: current ``λ >= 0``.
    :param episode_cost: measured mean episode cost ``J_C``.
    :param cost_limit: the limit ``d``.
    :param lagrange_lr: dual step size ``η_λ > 0``.
    :return: the new ``λ``.
    """
    return max(0.0, lagrange_multiplier + lagrange_lr * (episode_cost - cost_limit))


def lagrangian_advantage(advantages: np.ndarray, cost_advantages: np.ndarray, lagrange_multiplier: float) -> np.ndarray:
    """The primal step's advantage ``(A_R - λ·A_C) / (1 + λ)``; the ``1 + λ`` keeps its scale as ``λ`` grows."""
    lam = lagrange_multiplier
    return ((advantages - lam * cost_advantages) / (1.0 + lam)).astype(np.float32)


class CostRolloutBufferSamples(NamedTuple):
    """A minibatch of :class:`CostRolloutBuffer`; the first six fields are SB3's ``RolloutBufferSamples``."""

    observations: th.Tensor
    actions: th.Tensor
    old_values: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    returns: th.Tensor
    old_cost_values: th.Tensor
    cost_advantages: th.Tensor
    cost_returns: th.Tensor


class CostRolloutBuffer(RolloutBuffer):
    """SB3's ``RolloutBuffer`` plus the cost signal: costs, cost values ``V_C``, cost GAE ``A_C`` and cost returns.

    It also keeps a per-step learning mask: :meth:`get` only yields the steps whose mask is 1 (SAILR masks the
    steps that follow an intervention within an episode). Minibatches are drawn among those steps only, so
    advantage normalisation and every loss ignore the masked ones.

    :param buffer_size: steps per env per rollout (``n_steps``).
    :param observation_space: observation space.
    :param action_space: action space.
    :param device: PyTorch device.
    :param gae_lambda: GAE ``λ``, shared by the reward and the cost.
    :param gamma: discount ``γ``, shared by the reward and the cost.
    :param n_envs: number of parallel envs.
    """

    costs: np.ndarray
    cost_values: np.ndarray
    cost_advantages: np.ndarray
    cost_returns: np.ndarray
    masks: np.ndarray

    def reset(self) -> None:
        shape = (self.buffer_size, self.n_envs)
        self.costs = np.zeros(shape, dtype=np.float32)
        self.cost_values = np.zeros(shape, dtype=np.float32)
        self.cost_advantages = np.zeros(shape, dtype=np.float32)
        self.cost_returns = np.zeros(shape, dtype=np.float32)
        self.masks = np.ones(shape, dtype=np.float32)
        super().reset()

    def add(  # type: ignore[override]
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        episode_start: np.ndarray,
        value: th.Tensor,
        log_prob: th.Tensor,
        cost: np.ndarray | None = None,
        cost_value: th.Tensor | None = None,
        mask: np.ndarray | None = None,
    ) -> None:
        """Store one VecEnv step.

        :param cost: ``(n_envs,)`` cost of the step (``info["cost"]``, plus the timeout bootstrap); 0 if ``None``.
        :param cost_value: ``(n_envs,)`` ``V_C(s)``; 0 if ``None``.
        :param mask: ``(n_envs,)`` 1 where the step is learned from, 0 where it is masked out; 1 if ``None``.
        """
        pos = self.pos
        self.costs[pos] = 0.0 if cost is None else np.asarray(cost)
        self.cost_values[pos] = 0.0 if cost_value is None else cost_value.clone().cpu().numpy().flatten()
        self.masks[pos] = 1.0 if mask is None else np.asarray(mask, dtype=np.float32)
        super().add(obs, action, reward, episode_start, value, log_prob)

    def compute_returns_and_advantage(  # type: ignore[override]
        self, last_values: th.Tensor, dones: np.ndarray, last_cost_values: th.Tensor | None = None
    ) -> None:
        """Reward GAE (SB3's) and cost GAE (:func:`compute_gae`) of the rollout.

        :param last_values: ``V(s)`` of the state after the last step, one per env.
        :param dones: whether the last step ended its episode (for learning), one per env.
        :param last_cost_values: ``V_C(s)`` of the state after the last step; 0 if ``None``.
        """
        super().compute_returns_and_advantage(last_values, dones)
        last_c = np.zeros(self.n_envs, dtype=np.float32) if last_cost_values is None else last_cost_values.cpu().numpy()
        self.cost_advantages, self.cost_returns = compute_gae(
            self.costs, self.cost_values, self.episode_starts, last_c.flatten(), dones, self.gamma, self.gae_lambda
        )

    @property
    def n_learnable(self) -> int:
        """Number of stored steps with mask 1 (the ones :meth:`get` yields)."""
        return int(self.masks.sum())

    def get(self, batch_size: int | None = None) -> Generator[CostRolloutBufferSamples, None, None]:  # type: ignore[override]
        """Minibatches, in random order, of the unmasked steps; ``batch_size=None``: all of them at once."""
        assert self.full, "The rollout buffer is not full yet."
        if not self.generator_ready:
            for name in (
                "observations",
                "actions",
                "values",
                "log_probs",
                "advantages",
                "returns",
                "cost_values",
                "cost_advantages",
                "cost_returns",
                "masks",
            ):
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
            self.generator_ready = True
        indices = np.random.permutation(np.flatnonzero(self.masks.reshape(-1) > 0))
        if batch_size is None:
            batch_size = max(len(indices), 1)
        for start in range(0, len(indices), batch_size):
            yield self._get_samples(indices[start : start + batch_size])

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> CostRolloutBufferSamples:  # type: ignore[override]
        data = (
            self.observations[batch_inds],
            self.actions[batch_inds].astype(np.float32, copy=False),
            self.values[batch_inds].flatten(),
            self.log_probs[batch_inds].flatten(),
            self.advantages[batch_inds].flatten(),
            self.returns[batch_inds].flatten(),
            self.cost_values[batch_inds].flatten(),
            self.cost_advantages[batch_inds].flatten(),
            self.cost_returns[batch_inds].flatten(),
        )
        return CostRolloutBufferSamples(*tuple(map(self.to_torch, data)))


class CostActorCriticPolicy(ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` with an extra cost value head ``V_C(s)`` (the cost critic of PDO and CPO).

    The cost critic is its own MLP on the critic's features (``cost_value_net``), so it shares no weights with the
    actor. Its parameter names contain ``"value"``, which keeps it out of sb3-contrib TRPO's natural-gradient step.
    Every other argument is ``ActorCriticPolicy``'s.

    :param cost_net_arch: hidden layers of the cost critic; ``None``: the same as the value network's.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.Tanh,
        *args: Any,
        cost_net_arch: list[int] | None = None,
        **kwargs: Any,
    ) -> None:
        self.cost_net_arch = cost_net_arch
        super().__init__(observation_space, action_space, lr_schedule, net_arch, activation_fn, *args, **kwargs)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        if self.cost_net_arch is None:
            arch = self.net_arch.get("vf", []) if isinstance(self.net_arch, dict) else list(self.net_arch)
            self.cost_net_arch = list(arch)
        features_dim = self.vf_features_extractor.features_dim
        self.cost_value_net = nn.Sequential(*create_mlp(features_dim, 1, self.cost_net_arch, self.activation_fn))
        if self.ortho_init:
            self.cost_value_net.apply(lambda module: self.init_weights(module, gain=np.sqrt(2)))
            last = self.cost_value_net[-1]
            assert isinstance(last, nn.Linear)
            self.init_weights(last, gain=1.0)
        # the optimiser built by ActorCriticPolicy does not know the new head yet
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]

    def predict_cost_values(self, obs: th.Tensor) -> th.Tensor:
        """``V_C(s)``: the expected discounted cost-to-go of the current policy, shape ``(batch, 1)``."""
        features = super(ActorCriticPolicy, self).extract_features(obs, self.vf_features_extractor)
        return self.cost_value_net(features)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(cost_net_arch=self.cost_net_arch)
        return data


class EpisodeCostTracker:
    """Measured episode cost ``J_C`` (undiscounted sum of ``info["cost"]`` per episode), compared with the limit ``d``.

    PDO's dual ascent and CPO's constraint value ``c = J_C - d`` read :meth:`estimate`: the mean cost of the
    episodes that ended during the latest rollout; if none ended, the mean over the last ``window`` finished
    episodes; if none ever ended, the mean cost so far of the running episodes (a lower bound).

    :param n_envs: number of parallel envs.
    :param window: number of finished episodes kept for the fallback estimate.
    """

    def __init__(self, n_envs: int, window: int = 100) -> None:
        self.n_envs = n_envs
        self.window = window
        self.running_cost = np.zeros(n_envs)
        self.running_length = np.zeros(n_envs, dtype=np.int64)
        self.recent_costs: deque[float] = deque(maxlen=window)
        self.recent_lengths: deque[int] = deque(maxlen=window)
        self.rollout_costs: list[float] = []
        self.rollout_lengths: list[int] = []

    def resize(self, n_envs: int) -> None:
        """Follow a change in the number of envs (running episodes restart; finished ones are kept)."""
        if n_envs != self.n_envs:
            self.n_envs = n_envs
            self.reset_running()

    def reset_running(self) -> None:
        """Forget the running episodes (the envs were reset)."""
        self.running_cost = np.zeros(self.n_envs)
        self.running_length = np.zeros(self.n_envs, dtype=np.int64)

    def start_rollout(self) -> None:
        """Start counting the episodes of a new rollout."""
        self.rollout_costs = []
        self.rollout_lengths = []

    def update(self, costs: np.ndarray, dones: np.ndarray) -> None:
        """Feed one VecEnv step: ``(n_envs,)`` costs and episode ends."""
        self.running_cost += costs
        self.running_length += 1
        for idx in np.flatnonzero(dones):
            cost, length = float(self.running_cost[idx]), int(self.running_length[idx])
            self.rollout_costs.append(cost)
            self.rollout_lengths.append(length)
            self.recent_costs.append(cost)
            self.recent_lengths.append(length)
            self.running_cost[idx] = 0.0
            self.running_length[idx] = 0

    def estimate(self) -> float:
        """The measured mean episode cost ``J_C`` (see the class docstring for the fallbacks)."""
        if self.rollout_costs:
            return float(np.mean(self.rollout_costs))
        if self.recent_costs:
            return float(np.mean(self.recent_costs))
        return float(np.mean(self.running_cost))

    def mean_length(self) -> float:
        """Mean episode length matching :meth:`estimate` (at least 1)."""
        if self.rollout_lengths:
            return max(float(np.mean(self.rollout_lengths)), 1.0)
        if self.recent_lengths:
            return max(float(np.mean(self.recent_lengths)), 1.0)
        return max(float(np.mean(self.running_length)), 1.0)


class SafeOnPolicyMixin:
    """Cost-aware rollouts for SB3 on-policy algorithms. Put it first in the bases: ``class PDO(SafeOnPolicyMixin, PPO)``.

    The subclass calls :meth:`_init_safety` in its ``__init__`` (after the SB3 base ``__init__`` with
    ``_init_setup_model=False`` and before ``_setup_model``). It gets:

    - ``self.safety_metrics`` (:class:`~sppo_sb3.common.safety.SafetyMetrics`) fed every env step, logged under
      ``safety/`` whenever the logs are dumped, saved with the model;
    - ``self.cost_tracker`` (:class:`EpisodeCostTracker`): the measured episode cost ``J_C``;
    - a :class:`CostRolloutBuffer` filled with costs, cost values and cost GAE;
    - the hook :meth:`_learning_transition`, where SAILR turns a shield intervention into an absorbing terminal.

    :cvar uses_cost_critic: whether the policy must have a cost value head (:class:`CostActorCriticPolicy`).
    """

    uses_cost_critic: bool = True

    # provided by OnPolicyAlgorithm
    env: VecEnv | None
    n_envs: int
    policy: Any
    rollout_buffer: RolloutBuffer
    rollout_buffer_class: type[RolloutBuffer] | None
    gamma: float
    num_timesteps: int
    logger: Any
    use_sde: bool
    sde_sample_freq: int
    action_space: spaces.Space
    device: th.device
    _last_obs: Any
    _last_episode_starts: Any
    _vec_normalize_env: VecNormalize | None

    def _init_safety(self) -> None:
        """Create the safety metrics and the episode-cost tracker (kept as they are when a saved model is loaded)."""
        n_envs = self.n_envs if getattr(self, "env", None) is not None else 1
        self.safety_metrics = SafetyMetrics(n_envs)
        self.cost_tracker = EpisodeCostTracker(n_envs)

    def _setup_model(self) -> None:
        if self.rollout_buffer_class is None:
            self.rollout_buffer_class = CostRolloutBuffer
        if not issubclass(self.rollout_buffer_class, CostRolloutBuffer):
            raise TypeError(
                f"{type(self).__name__} needs a CostRolloutBuffer (it stores the costs); got rollout_buffer_class="
                f"{self.rollout_buffer_class.__name__}. Leave rollout_buffer_class=None or subclass CostRolloutBuffer."
            )
        super()._setup_model()  # type: ignore[misc]
        if self.uses_cost_critic and not isinstance(self.policy, CostActorCriticPolicy):
            raise TypeError(
                f"{type(self).__name__} learns a cost critic: its policy must be a CostActorCriticPolicy (use "
                f"'MlpPolicy' or subclass sppo_sb3.common.on_policy.CostActorCriticPolicy), got {type(self.policy).__name__}."
            )

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        env_reset = reset_num_timesteps or self._last_obs is None
        out = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)  # type: ignore[misc]
        assert self.env is not None
        self.safety_metrics.resize(self.env.num_envs)
        self.cost_tracker.resize(self.env.num_envs)
        if env_reset:
            self._on_env_reset()
        return out

    def _on_env_reset(self) -> None:
        """Called when ``learn`` resets the envs: running episodes start over."""
        self.safety_metrics.restart_episodes()
        self.cost_tracker.reset_running()

    def _learning_transition(
        self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """How one env step enters the learning data (hook; the default keeps it as it is).

        :param rewards: ``(n_envs,)`` rewards returned by the env.
        :param dones: ``(n_envs,)`` episode ends.
        :param infos: the step's infos.
        :return: ``(rewards, absorbed, mask)``: the rewards to learn from; where the learning data ends at this step
            although the real episode may go on (an absorbing terminal: no bootstrap); where the step is learned
            from (1) or masked out (0).
        """
        n = len(rewards)
        return rewards, np.zeros(n, dtype=bool), np.ones(n, dtype=np.float32)

    def _cost_values(self, obs_tensor: th.Tensor | dict[str, th.Tensor]) -> th.Tensor | None:
        if isinstance(self.policy, CostActorCriticPolicy):
            return self.policy.predict_cost_values(obs_tensor)  # type: ignore[arg-type]
        return None

    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
    ) -> bool:
        """SB3's ``collect_rollouts`` plus the costs: ``info["cost"]`` of every step, ``V_C``, and the safety metrics.

        :raises MissingCostError: on the first step, when the env does not report ``info["cost"]``.
        """
        assert self._last_obs is not None, "No previous observation was provided"
        assert isinstance(rollout_buffer, CostRolloutBuffer)
        self.policy.set_training_mode(False)
        n_steps = 0
        rollout_buffer.reset()
        self.cost_tracker.start_rollout()
        if self.use_sde:
            self.policy.reset_noise(env.num_envs)
        callback.on_rollout_start()

        while n_steps < n_rollout_steps:
            if self.use_sde and self.sde_sample_freq > 0 and n_steps % self.sde_sample_freq == 0:
                self.policy.reset_noise(env.num_envs)
            with th.no_grad():
                obs_tensor = obs_as_tensor(self._last_obs, self.device)
                actions, values, log_probs = self.policy(obs_tensor)
                cost_values = self._cost_values(obs_tensor)
            actions = actions.cpu().numpy()
            clipped_actions = actions
            if isinstance(self.action_space, spaces.Box):
                if self.policy.squash_output:
                    clipped_actions = self.policy.unscale_action(clipped_actions)
                else:
                    clipped_actions = np.clip(actions, self.action_space.low, self.action_space.high)

            new_obs, rewards, dones, infos = env.step(clipped_actions)
            env_rewards = self._vec_normalize_env.get_original_reward() if self._vec_normalize_env is not None else rewards
            # raises MissingCostError on the first step of an env without info["cost"]
            costs = self.safety_metrics.update_from_infos(env_rewards, dones, infos)
            self.cost_tracker.update(costs, dones)
            self.num_timesteps += env.num_envs

            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)  # type: ignore[attr-defined]
            n_steps += 1

            if isinstance(self.action_space, spaces.Discrete):
                actions = actions.reshape(-1, 1)

            learn_rewards, absorbed, masks = self._learning_transition(np.array(rewards, dtype=np.float32), dones, infos)
            learn_costs = costs.copy()
            # bootstrap timeouts with V and V_C of the terminal observation (SB3 GH #633), but not absorbing steps
            for idx, done in enumerate(dones):
                if (
                    done
                    and not absorbed[idx]
                    and infos[idx].get("terminal_observation") is not None
                    and infos[idx].get("TimeLimit.truncated", False)
                ):
                    terminal_obs = self.policy.obs_to_tensor(infos[idx]["terminal_observation"])[0]
                    with th.no_grad():
                        learn_rewards[idx] += self.gamma * self.policy.predict_values(terminal_obs)[0].item()
                        terminal_cost = self._cost_values(terminal_obs)
                    if terminal_cost is not None:
                        learn_costs[idx] += self.gamma * terminal_cost[0].item()

            rollout_buffer.add(
                self._last_obs,
                actions,
                learn_rewards,
                self._last_episode_starts,
                values,
                log_probs,
                cost=learn_costs,
                cost_value=cost_values,
                mask=masks,
            )
            self._last_obs = new_obs
            self._last_episode_starts = np.logical_or(dones, absorbed)

        with th.no_grad():
            obs_tensor = obs_as_tensor(new_obs, self.device)  # type: ignore[arg-type]
            values = self.policy.predict_values(obs_tensor)
            last_cost_values = self._cost_values(obs_tensor)
        rollout_buffer.compute_returns_and_advantage(
            last_values=values, dones=self._last_episode_starts, last_cost_values=last_cost_values
        )
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def _fit_critics(
        self, n_epochs: int, batch_size: int, reward_critic: bool, frozen: Iterable[nn.Parameter] = ()
    ) -> dict[str, float]:
        """Regress ``V_C`` (and ``V`` if ``reward_critic``) on the rollout's TD(λ) returns, by minibatch MSE.

        :param n_epochs: passes over the rollout.
        :param batch_size: minibatch size.
        :param reward_critic: also fit the reward value ``V`` (CPO; PDO fits it inside PPO's loss).
        :param frozen: parameters whose gradients are dropped before each step (the actor's, for TRPO/CPO).
        :return: mean losses, for the logs.
        """
        policy = self.policy
        assert isinstance(policy, CostActorCriticPolicy)
        assert isinstance(self.rollout_buffer, CostRolloutBuffer)
        frozen = list(frozen)
        cost_losses, value_losses = [], []
        for _ in range(n_epochs):
            for data in self.rollout_buffer.get(batch_size):
                cost_pred = policy.predict_cost_values(data.observations).flatten()
                loss = F.mse_loss(data.cost_returns, cost_pred)
                cost_losses.append(loss.item())
                if reward_critic:
                    value_loss = F.mse_loss(data.returns, policy.predict_values(data.observations).flatten())
                    value_losses.append(value_loss.item())
                    loss = loss + value_loss
                policy.optimizer.zero_grad()
                loss.backward()
                for param in frozen:
                    param.grad = None
                policy.optimizer.step()
        buf = self.rollout_buffer
        out = {"cost_value_loss": float(np.mean(cost_losses)) if cost_losses else float("nan")}
        out["cost_explained_variance"] = float(explained_variance(buf.cost_values.flatten(), buf.cost_returns.flatten()))
        if reward_critic:
            out["value_loss"] = float(np.mean(value_losses)) if value_losses else float("nan")
        return out

    def dump_logs(self, iteration: int = 0) -> None:
        """Write the ``safety/`` figures and the measured episode cost, then SB3's logs."""
        self.safety_metrics.record(self.logger)
        self.logger.record("safety/ep_cost_estimate", self.cost_tracker.estimate())
        super().dump_logs(iteration)  # type: ignore[misc]
