"""The cost-aware rollout loop shared by the on-policy safe-RL baselines PDO, CPO, SAILR and CSC.

SB3's ``OnPolicyAlgorithm.collect_rollouts`` never shows the step ``infos`` to the learner, so the violation indicator
``c(s, a) = info["cost"]`` (the paper's Definition 1) never reaches it. :class:`SafeOnPolicyMixin` is that loop,
cost-aware, written once, with a hook for each thing the algorithms do differently:

- :meth:`~SafeOnPolicyMixin._choose_actions`: how the executed actions are chosen (CSC: its cost critic's rejection
  sampler);
- :meth:`~SafeOnPolicyMixin._learning_transition`: how a step enters the learning data (SAILR: the absorbing MDP);
- :meth:`~SafeOnPolicyMixin._store_extra_transition`: what else is stored per transition (CSC: its cost critic's replay
  buffer).

and the update PDO and SAILR share, PPO on the penalised advantage followed by the cost critic's regression
(:meth:`~SafeOnPolicyMixin._train_on_penalised_advantage`).

Its parts live in their own modules: :func:`~sppo_sb3.common.gae.compute_gae`,
:class:`~sppo_sb3.common.cost_buffer.CostRolloutBuffer`, :class:`~sppo_sb3.common.cost_policy.CostActorCriticPolicy`,
:class:`~sppo_sb3.common.safety.EpisodeCostTracker` (kept with the safety metrics by
:class:`~sppo_sb3.common.safety.SafetyTrackingMixin`) and the Lagrange multiplier of
:mod:`sppo_sb3.common.lagrange`.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv

from sppo_sb3.common.cost_buffer import CostRolloutBuffer, cost_buffer_class
from sppo_sb3.common.cost_policy import CostActorCriticPolicy, fit_critics
from sppo_sb3.common.lagrange import lagrangian_advantage
from sppo_sb3.common.safety import SafetyTrackingMixin

__all__ = ["ActionChoice", "SafeOnPolicyMixin"]


class ActionChoice(NamedTuple):
    """What :meth:`SafeOnPolicyMixin._choose_actions` returns for one VecEnv step.

    :param actions: ``(n_envs, *action_shape)`` the policy's actions, before clipping to the Box.
    :param values: ``(n_envs, 1)`` ``V(s)``.
    :param log_probs: ``(n_envs,)`` log-probabilities of ``actions`` under the policy.
    :param intervened: ``(n_envs,)`` where something else than the policy's first sample was executed (counted as
        interventions by the safety metrics), or ``None``.
    """

    actions: np.ndarray
    values: th.Tensor
    log_probs: th.Tensor
    intervened: np.ndarray | None = None


class SafeOnPolicyMixin(SafetyTrackingMixin):
    """Cost-aware rollouts for SB3 on-policy algorithms. Put it before the SB3 algorithm in the bases:
    ``class CPO(SafeOnPolicyMixin, TRPO)``, ``class PDO(LagrangianMixin, SafeOnPolicyMixin, PPO)``.

    The subclass calls :meth:`_init_safety` in its ``__init__`` (after the SB3 base ``__init__`` with
    ``_init_setup_model=False`` and before ``_setup_model``). It gets:

    - from :class:`~sppo_sb3.common.safety.SafetyTrackingMixin`: ``self.safety_metrics``
      (:class:`~sppo_sb3.common.safety.SafetyMetrics`) fed every env step with the env's original rewards (also under
      ``VecNormalize``), logged under ``safety/`` whenever the logs are dumped, saved with the model; and
      ``self.cost_tracker`` (:class:`~sppo_sb3.common.safety.EpisodeCostTracker`): the measured episode cost
      ``J_C``;
    - a :class:`CostRolloutBuffer` filled with costs, cost values and cost GAE;
    - the hooks :meth:`_choose_actions`, :meth:`_learning_transition` and :meth:`_store_extra_transition`;
    - :meth:`_train_on_penalised_advantage`, for a ``train`` that follows ``(A_R - κ·A_C) / (1 + κ)``.

    :cvar uses_cost_critic: whether the policy must have a cost value head (:class:`CostActorCriticPolicy`).
    """

    uses_cost_critic: bool = True

    # provided by OnPolicyAlgorithm
    policy: Any
    policy_aliases: ClassVar[dict[str, type[BasePolicy]]]
    rollout_buffer: RolloutBuffer
    rollout_buffer_class: type[RolloutBuffer] | None
    gamma: float
    n_epochs: int
    batch_size: int
    num_timesteps: int
    use_sde: bool
    sde_sample_freq: int
    action_space: spaces.Space
    device: th.device
    _last_episode_starts: Any

    def _setup_model(self) -> None:
        given, name = self.rollout_buffer_class, type(self).__name__
        self.rollout_buffer_class = cost_buffer_class(given, CostRolloutBuffer, name, "rollout_buffer_class")
        super()._setup_model()  # type: ignore[misc]
        if self.uses_cost_critic and not isinstance(self.policy, CostActorCriticPolicy):
            raise TypeError(
                f"{type(self).__name__} learns a cost critic: its policy must be a CostActorCriticPolicy (use "
                f"'MlpPolicy' or subclass sppo_sb3.common.on_policy.CostActorCriticPolicy), got {type(self.policy).__name__}."
            )

    def _maybe_recommend_cpu(self, mlp_class_name: str = "ActorCriticPolicy") -> None:
        """SB3's advice to train MLP policies on the CPU, for this algorithm's own ``MlpPolicy`` class.

        SB3 compares the policy's class name with ``ActorCriticPolicy``, which the cost-aware policies are not named.
        """
        mlp_policy = self.policy_aliases.get("MlpPolicy")
        super()._maybe_recommend_cpu(mlp_class_name if mlp_policy is None else mlp_policy.__name__)  # type: ignore[misc]

    # --- hooks ----------------------------------------------------------------------------------------------------

    def _choose_actions(self, obs_tensor: th.Tensor | dict[str, th.Tensor]) -> ActionChoice:
        """How the executed actions are chosen (hook; the default samples the policy, as SB3 does). Runs under no_grad.

        :param obs_tensor: the current observations.
        """
        actions, values, log_probs = self.policy(obs_tensor)
        return ActionChoice(actions.cpu().numpy(), values, log_probs)

    def _learning_transition(
        self, rewards: np.ndarray, costs: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """How one env step enters the learning data (hook; the default keeps it as it is).

        :param rewards: ``(n_envs,)`` rewards returned by the env.
        :param costs: ``(n_envs,)`` the step's ``info["cost"]``.
        :param dones: ``(n_envs,)`` episode ends.
        :param infos: the step's infos.
        :return: ``(rewards, costs, absorbed, mask)``: the rewards and costs to learn from; where the learning data
            ends at this step although the real episode may go on (an absorbing terminal: no bootstrap); where the
            step is learned from (1) or masked out (0).
        """
        n = len(rewards)
        return rewards, costs.astype(np.float32), np.zeros(n, dtype=bool), np.ones(n, dtype=np.float32)

    def _store_extra_transition(
        self,
        obs: np.ndarray,
        new_obs: np.ndarray,
        actions: np.ndarray,
        costs: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one VecEnv step beyond the rollout buffer (hook; the default stores nothing more).

        :param obs: the observations the actions were chosen on.
        :param new_obs: the observations returned by the step (the next episode's first ones where ``dones``).
        :param actions: the policy's actions, as returned by :meth:`_choose_actions`.
        :param costs: ``(n_envs,)`` the step's ``info["cost"]``.
        :param dones: ``(n_envs,)`` episode ends.
        :param infos: the step's infos (``terminal_observation`` where ``dones``).
        """

    # --- the loop -------------------------------------------------------------------------------------------------

    def _cost_values(self, obs_tensor: th.Tensor | dict[str, th.Tensor]) -> th.Tensor | None:
        if isinstance(self.policy, CostActorCriticPolicy):
            return self.policy.predict_cost_values(obs_tensor)  # type: ignore[arg-type]
        return None

    def _env_actions(self, actions: np.ndarray) -> np.ndarray:
        """The actions sent to the env: unscaled (squashing policies) or clipped to the Box, as SB3 does."""
        if not isinstance(self.action_space, spaces.Box):
            return actions
        if self.policy.squash_output:
            return self.policy.unscale_action(actions)
        return np.clip(actions, self.action_space.low, self.action_space.high)

    def _bootstrap_timeouts(
        self, rewards: np.ndarray, costs: np.ndarray, dones: np.ndarray, absorbed: np.ndarray, infos: list[dict[str, Any]]
    ) -> None:
        """Add ``γ·V`` and ``γ·V_C`` of the terminal observation to the steps cut by a time limit (SB3 GH #633), in
        place; absorbing steps are not bootstrapped."""
        for idx, done in enumerate(dones):
            if (
                done
                and not absorbed[idx]
                and infos[idx].get("terminal_observation") is not None
                and infos[idx].get("TimeLimit.truncated", False)
            ):
                terminal_obs = self.policy.obs_to_tensor(infos[idx]["terminal_observation"])[0]
                with th.no_grad():
                    rewards[idx] += self.gamma * self.policy.predict_values(terminal_obs)[0].item()
                    terminal_cost = self._cost_values(terminal_obs)
                if terminal_cost is not None:
                    costs[idx] += self.gamma * terminal_cost[0].item()

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
                actions, values, log_probs, intervened = self._choose_actions(obs_tensor)
                cost_values = self._cost_values(obs_tensor)

            new_obs, rewards, dones, infos = env.step(self._env_actions(actions))
            costs = self._record_safety(rewards, dones, infos, intervened)
            self.num_timesteps += env.num_envs

            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)  # type: ignore[attr-defined]
            n_steps += 1

            learn_rewards, learn_costs, absorbed, masks = self._learning_transition(
                np.array(rewards, dtype=np.float32), costs.copy(), dones, infos
            )
            self._bootstrap_timeouts(learn_rewards, learn_costs, dones, absorbed, infos)
            self._store_extra_transition(self._last_obs, new_obs, actions, costs, dones, infos)  # type: ignore[arg-type]
            if isinstance(self.action_space, spaces.Discrete):
                actions = actions.reshape(-1, 1)
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

    # --- the update -----------------------------------------------------------------------------------------------

    def _train_on_penalised_advantage(self, penalty: float) -> None:
        """The PPO step on ``(A_R - κ·A_C) / (1 + κ)`` with ``κ = penalty``, then the cost critic's regression on the
        rollout's cost returns (PDO: ``κ = λ``, the Lagrange multiplier; SAILR: its fixed penalty coefficient).

        :param penalty: ``κ >= 0``.
        """
        buf = self.rollout_buffer
        assert isinstance(buf, CostRolloutBuffer)
        assert not buf.generator_ready, "the advantages must be combined before the buffer is flattened"
        buf.advantages = lagrangian_advantage(buf.advantages, buf.cost_advantages, penalty)
        super().train()  # type: ignore[misc]
        for key, value in fit_critics(self.policy, buf, self.n_epochs, self.batch_size, reward_critic=False).items():
            self.logger.record(f"train/{key}", value)

    def dump_logs(self, iteration: int = 0) -> None:
        """Write the ``safety/`` figures and the measured episode cost, then SB3's logs."""
        self._record_safety_logs()
        super().dump_logs(iteration)  # type: ignore[misc]
