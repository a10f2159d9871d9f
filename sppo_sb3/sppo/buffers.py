"""SPPO's replay buffer: the real transitions ``B`` and their absorbing-MDP relabel ``B̃`` in one storage.

``B`` (Alg. 1 line 7) holds every real step ``(s, a_safe, r, cost, s')``. ``B̃`` (line 8) holds the experience of the
*unshielded* planner in the absorbing MDP ``M̃`` (eqs. 7, 8; the ``ã`` rule of Section III-D). Both agree on every
step before the first intervention ``T`` of an episode; at ``T``, ``B̃`` records ``(s_T, a_T, R̃, terminal)`` with the
planner's proposed ``a_T``, and after ``T`` the paper's ``M̃`` stays in ``s†``, so ``B̃`` holds nothing more of that
episode. ``B̃`` is therefore a view of ``B`` plus one action column and two flags — no second copy of the data.

That relabel assumes, as the paper's tasks do, that a violation ends the episode. Where it does not (a CMDP such as
the velocity tasks, whose cost limit counts every violating step), an intervention need not be a death: ``"continue"``
keeps the proposal, penalised, but bootstraps from the real next state, and ``"none"`` learns from ``B`` as it is (the
learner never sees a proposal the shield rejected). The values are the package's one vocabulary,
:mod:`sppo_sb3.shield.intervention`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize

from sppo_sb3.common.costs import intervention_count
from sppo_sb3.common.keys import COST_KEY, INTERVENED_KEY, PROPOSED_ACTION_KEY, SHAPED_COST_KEY
from sppo_sb3.shield.intervention import OnIntervention, check_on_intervention, check_penalty
from sppo_sb3.shield.learned.base import CostTransitions

#: the values of ``on_intervention`` SPPO's relabel implements (:mod:`~sppo_sb3.shield.intervention`)
SPPO_ON_INTERVENTION: tuple[OnIntervention, ...] = ("terminate", "restart", "continue", "none")


class SequenceSamples(NamedTuple):
    """``L``-step sequences from ``B̃`` (time-major, batch ``B``).

    :param observations: ``(B, obs_dim)`` the first state ``s_t`` of each sequence (the only one encoded).
    :param actions: ``(L, B, A)`` actions ``ã`` of ``M̃`` (scaled to [-1, 1]).
    :param rewards: ``(L, B)`` rewards ``r̃`` of eq. 7.
    :param next_observations: ``(L, B, obs_dim)`` next states, targets of the consistency loss (eq. 17).
    :param terminals: ``(L, B)`` 1 where the step ends in a terminal (no bootstrap in eq. 16).
    :param mask: ``(L, B)`` 1 where the step belongs to the sequence (not past an episode end or the write head).
    :param consistency_mask: ``(L, B)`` ``mask`` without the relabelled steps, whose next state did not follow their
        action (``s†`` of an absorbing relabel has no observation; under ``"continue"`` the backup led to ``s'``).
    :param proposals: ``(L, B, A)`` the planner's proposals (scaled to [-1, 1]), what the shield judged.
    :param intervened: ``(L, B)`` 1 where the shield rejected the proposal (the intervention head's label).
    """

    observations: th.Tensor
    actions: th.Tensor
    rewards: th.Tensor
    next_observations: th.Tensor
    terminals: th.Tensor
    mask: th.Tensor
    consistency_mask: th.Tensor
    proposals: th.Tensor | None = None
    intervened: th.Tensor | None = None


class ShieldedReplayBuffer(ReplayBuffer):
    """Replay buffer of real transitions ``B`` with the absorbing relabel ``B̃`` (Section III-D).

    Reads the step's ``info["cost"]``, ``info["shaped_cost"]`` (NaN where absent), ``info["shield_intervened"]``,
    ``info["shield_interventions"]`` (on how many env steps, under an action repeat) and ``info["proposed_action"]``
    (env units) in :meth:`add`. :meth:`sample` draws single transitions of ``B``;
    :meth:`sample_sequences` draws sequences of ``B̃`` for TOPO; :meth:`sample_cost_transitions` draws the real
    transitions a learned shielding rule is fitted on.

    :param on_intervention: how ``B̃`` relabels an intervention at step ``T`` (:mod:`~sppo_sb3.shield.intervention`):

        - ``"terminate"``: the paper's ``M̃``: ``(s_T, a_T, R̃)`` is an absorbing terminal, and nothing more of the
          episode is learned;
        - ``"restart"``: every intervention is an absorbing terminal, and ``B̃`` restarts at the next real state;
        - ``"continue"``: ``(s_T, a_T, r_T - penalty, s_(T+1))`` without a terminal: the proposal is penalised and its
          value bootstrapped from the real next state, the one the backup led to (tasks where a violation does not end
          the episode). TOLD's latent roll stops there, since ``s_(T+1)`` did not follow ``a_T``;
        - ``"none"``: no relabel, ``B̃ = B``: the executed action, its reward and next state.
    :param penalty: what an intervention costs the learner, ``>= 0``: the absorbing transition's reward is
        ``R̃ = -penalty`` (eq. 7); under ``"continue"`` it is subtracted from the step's reward.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        on_intervention: OnIntervention = "restart",
        penalty: float = 1.0,
    ) -> None:
        if optimize_memory_usage:
            raise ValueError("ShieldedReplayBuffer keeps next observations explicitly: use optimize_memory_usage=False.")
        check_on_intervention(on_intervention, SPPO_ON_INTERVENTION, "SPPO's replay buffer")
        check_penalty(penalty, "SPPO's replay buffer")
        super().__init__(buffer_size, observation_space, action_space, device, n_envs, False, handle_timeout_termination)
        assert isinstance(action_space, spaces.Box)
        self.on_intervention, self.penalty = on_intervention, penalty
        self.proposed_actions = np.zeros_like(self.actions)
        self.costs = np.zeros((self.buffer_size, self.n_envs), dtype=np.float32)
        self.shaped_costs = np.full((self.buffer_size, self.n_envs), np.nan, dtype=np.float32)
        self.intervened = np.zeros((self.buffer_size, self.n_envs), dtype=bool)
        self.interventions = np.zeros((self.buffer_size, self.n_envs), dtype=np.int16)  # env steps, under a repeat
        self.relabel_valid = np.zeros((self.buffer_size, self.n_envs), dtype=bool)
        self._absorbed = np.zeros(self.n_envs, dtype=bool)  # M̃ has reached s† in the env's current episode
        self._low, self._high = action_space.low, action_space.high

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        pos = self.pos
        intervened = np.array([bool(info.get(INTERVENED_KEY, False)) for info in infos])
        proposed = np.array(
            [self._scale(info[PROPOSED_ACTION_KEY]) if PROPOSED_ACTION_KEY in info else a for info, a in zip(infos, action)]
        )
        self.costs[pos] = [float(info.get(COST_KEY, 0.0)) for info in infos]
        self.shaped_costs[pos] = [float(info.get(SHAPED_COST_KEY, np.nan)) for info in infos]
        self.intervened[pos] = intervened
        self.interventions[pos] = [intervention_count(info) for info in infos]
        self.proposed_actions[pos] = proposed.reshape(self.n_envs, self.action_dim)
        self.relabel_valid[pos] = ~self._absorbed  # the ã rule: M̃ data until (and including) T
        if self.on_intervention == "terminate":
            self._absorbed |= intervened
        self._absorbed[np.asarray(done, dtype=bool)] = False
        super().add(obs, next_obs, action, reward, done, infos)

    def _scale(self, action: np.ndarray) -> np.ndarray:
        return 2.0 * (np.asarray(action) - self._low) / (self._high - self._low) - 1.0

    def _available(self, starts: np.ndarray) -> np.ndarray:
        """How many consecutive written steps follow each start index before the write head."""
        if not self.full:
            return self.pos - starts
        avail = (self.pos - starts) % self.buffer_size
        return np.where(avail == 0, self.buffer_size, avail)

    def _sample_starts(self, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
        """Uniform (time, env) starts among the steps that belong to ``B̃``."""
        upper = self.buffer_size if self.full else self.pos
        if upper == 0 or not self.relabel_valid[:upper].any():
            raise RuntimeError("B̃ holds no transition yet: collect some steps before sampling sequences.")
        times, envs = np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
        while len(times) < batch_size:
            t = np.random.randint(0, upper, size=2 * batch_size)
            e = np.random.randint(0, self.n_envs, size=2 * batch_size)
            keep = self.relabel_valid[t, e]
            times, envs = np.concatenate([times, t[keep]]), np.concatenate([envs, e[keep]])
        return times[:batch_size], envs[:batch_size]

    def sample_cost_transitions(self, batch_size: int) -> CostTransitions:
        """Uniform real transitions of ``B`` (raw observations) for fitting ``Q̄`` (Alg. 1 line 12).

        :raises ValueError: where a sampled step has no ``info["shaped_cost"]`` (the env does not report it).
        """
        upper = self.buffer_size if self.full else self.pos
        times, envs = np.random.randint(0, upper, size=batch_size), np.random.randint(0, self.n_envs, size=batch_size)
        shaped = self.shaped_costs[times, envs].astype(np.float64)
        if np.isnan(shaped).any():
            raise ValueError(
                f"The env does not report info[{SHAPED_COST_KEY!r}], the shaped cost of eq. 18 that a learned shielding "
                "rule is fitted on: report it from the env (see SafePointCircle-v0) or use refine_shield=False."
            )
        terminations = self.dones[times, envs] * (1 - self.timeouts[times, envs])
        data = (self.observations[times, envs], self.actions[times, envs], shaped, self.costs[times, envs])
        rest = (self.next_observations[times, envs], terminations)
        return CostTransitions(*(np.asarray(x, dtype=np.float64) for x in (*data, *rest)))

    def sample_sequences(self, batch_size: int, length: int, env: VecNormalize | None = None) -> SequenceSamples:
        """Sample ``batch_size`` sequences of ``length`` steps of ``B̃`` that never cross an episode end.

        Steps after an episode end (termination, truncation, or an intervention relabelled with the proposal), after the
        write head or outside ``B̃`` are masked out.
        """
        starts, envs = self._sample_starts(batch_size)
        offsets = np.arange(length)[:, None]
        idx = (starts[None] + offsets) % self.buffer_size  # (L, B)
        relabelled = self.intervened[idx, envs] & (self.on_intervention != "none")  # steps whose action is the proposal
        ends = self.dones[idx, envs].astype(bool) | relabelled
        crossed = np.cumsum(np.concatenate([np.zeros((1, batch_size), bool), ends[:-1]]), axis=0) > 0
        mask = (offsets < self._available(starts)[None]) & ~crossed & self.relabel_valid[idx, envs]
        actions = np.where(relabelled[..., None], self.proposed_actions[idx, envs], self.actions[idx, envs])
        real_terminals = (self.dones[idx, envs] * (1 - self.timeouts[idx, envs])).astype(bool)
        if self.on_intervention == "continue":
            rewards = np.where(relabelled, self.rewards[idx, envs] - self.penalty, self.rewards[idx, envs])
            terminals = real_terminals
        else:
            rewards = np.where(relabelled, -self.penalty, self.rewards[idx, envs])
            terminals = real_terminals | relabelled
        data = (
            self._normalize_obs(self.observations[starts, envs], env),
            actions,
            self._normalize_reward(rewards, env),
            self._normalize_obs(self.next_observations[idx, envs], env),
            terminals,
            mask,
            mask & ~relabelled,
            self.proposed_actions[idx, envs],
            self.intervened[idx, envs],
        )
        return SequenceSamples(*(self.to_torch(np.asarray(x, dtype=np.float32)) for x in data))
