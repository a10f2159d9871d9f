"""``ShieldWrapper``: shield any gymnasium env — and so any SB3 algorithm — with a :class:`ShieldingRule`."""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from sppo_sb3.common.action_repeat import HeldSteps, check_action_repeat, check_held_steps_are_shielded
from sppo_sb3.common.keys import (
    ABSORBED_KEY,
    ADVANTAGE_KEY,
    COST_KEY,
    EDITS_KEY,
    ENV_REWARD_KEY,
    EXECUTED_ACTION_KEY,
    INTERVENED_KEY,
    INTERVENTIONS_KEY,
    PROPOSED_ACTION_KEY,
)
from sppo_sb3.shield.base import ShieldDecision, ShieldingRule, make_permissive
from sppo_sb3.shield.intervention import OnIntervention, check_on_intervention, check_penalty
from sppo_sb3.shield.records import MAX_RECORDS, CostlyEpisode, EpisodeLog, costly_episode, reset_randomness, simulator_state
from sppo_sb3.shield.registry import resolve_shielding_rule

#: the values of ``on_intervention`` a wrapper can implement through the gym API (:mod:`~sppo_sb3.shield.intervention`)
WRAPPER_ON_INTERVENTION: tuple[OnIntervention, ...] = ("continue", "terminate", "takeover")


class ShieldWrapper(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """Pass every action through the rule's shield (eq. 12) before the env executes it.

    The env always executes the safe action. What the learner sees on an intervention is ``on_intervention``, in the
    package's one vocabulary (:mod:`~sppo_sb3.shield.intervention`):

    - ``"continue"`` (default): the step of the executed backup action, as if the learner's proposal had produced it,
      its reward less ``penalty``. With the default ``penalty=0`` the learner learns in the *shielded* env, where a
      proposal means "this action, passed through the shield", and nothing tells it that the proposal was rejected.
    - ``"terminate"``: eq. 7's absorbing MDP: the step ends the episode (``terminated=True``) with reward
      ``R̃ = -penalty``, so the learner stores ``(s, proposal, R̃, terminal)`` (the proposal is what leads to ``s†``)
      and the episode restarts at the next ``reset``. The env's reward of the executed step is in
      ``info["env_reward"]``.
    - ``"takeover"``: the step as the env executed it, and the backup policy ``ζ`` then keeps control until the
      episode ends: every later step executes ``ζ(s)`` whatever is proposed (and is reported as an intervention).
      This is how SAILR's code (Wagener et al. 2021) runs an episode after its first intervention; the learner
      relabels the first intervention and masks the later steps itself (:class:`~sppo_sb3.sailr.SAILR` does), so this
      mode takes no penalty.

    The step's info carries ``info["shield_intervened"]`` (whether the backup replaced the action),
    ``info["proposed_action"]`` (what the agent asked for, clipped to the action space), ``info["executed_action"]``
    (what the env executed), ``info["shield_advantage"]`` (``Ā(s, a)``) and ``info["shield_absorbed"]`` (the step
    was turned into the absorbing terminal). The rule is probed once, at the first ``reset``
    (:meth:`ShieldingRule.check_action_space`).

    Every episode that pays cost is kept as a replayable record (:mod:`~sppo_sb3.shield.records`), the first
    :data:`~sppo_sb3.shield.records.MAX_RECORDS` of them: :attr:`costly_episodes`. The train CLI writes them to the run
    folder (``costly_episodes/``), and ``scripts/replay_costly.py`` replays one closed loop on any machine.

    :param env: the env to protect; its observations are what the rule reads.
    :param rule: the shielding rule, or a registered rule's name: ``"auto"`` (the rule of the env's own id, built from
        the env's parameters), an env id or a variant such as ``"SafePointCircle-v0:paper"``. A name lets a YAML file
        shield any algorithm, through rl-zoo3's ``env_wrapper``:
        ``env_wrapper: [{sppo_sb3.shield.ShieldWrapper: {rule: auto}}]``.
    :param on_intervention: ``"continue"``, ``"terminate"`` or ``"takeover"`` (see above).
    :param penalty: what an intervention costs the learner, ``>= 0``: subtracted from the step's reward under
        ``"continue"`` (once per intervened env step), the absorbing step's reward ``R̃ = -penalty`` under
        ``"terminate"``.
    :param permissive: where the rule rejects a proposal, execute an accepted action near it instead of the backup's
        (a rule with edits, :class:`~sppo_sb3.shield.MujocoShieldingRule`'s ``permissive``; every executed action is
        still one the rule accepted). ``info["shield_edits"]`` counts the env steps replaced by an edit.
    :param action_repeat: env steps each action is held for (:mod:`~sppo_sb3.common.action_repeat`): the learner acts
        every ``action_repeat`` env steps, and the shield checks the held action on *every* env step, executing the
        backup's action on those it rejects. The learner's step then carries the held action's summed reward and cost,
        ``info["env_steps"]``, ``info["costly_steps"]`` and ``info["shield_interventions"]`` (env steps intervened);
        ``info["shield_intervened"]`` is whether any was, ``info["executed_action"]`` and ``info["shield_advantage"]``
        are the first env step's. Under ``"terminate"`` the held action ends at its first intervention.
    """

    def __init__(
        self,
        env: gym.Env,
        rule: ShieldingRule | str,
        on_intervention: OnIntervention = "continue",
        penalty: float = 0.0,
        action_repeat: int = 1,
        permissive: bool = False,
    ) -> None:
        super().__init__(env)
        if not isinstance(env.action_space, gym.spaces.Box):
            raise TypeError(f"ShieldWrapper needs a Box action space, got {env.action_space}.")
        check_on_intervention(on_intervention, WRAPPER_ON_INTERVENTION, "ShieldWrapper")
        check_action_repeat(action_repeat)
        check_held_steps_are_shielded(env, "ShieldWrapper")
        check_penalty(penalty, "ShieldWrapper")
        if on_intervention == "takeover" and penalty != 0.0:
            raise ValueError(
                "ShieldWrapper(on_intervention='takeover') reports the executed steps as they are and leaves the relabel to "
                "the learner (SAILR weights its intervention cost by its own penalty): pass penalty=0.0."
            )
        resolved = resolve_shielding_rule(rule, env, required=True)
        if resolved is None:
            raise TypeError("ShieldWrapper needs a shielding rule: a ShieldingRule or a registered rule's name, not None.")
        self.rule = resolved
        if permissive:
            make_permissive(resolved)
        self.on_intervention = on_intervention
        self.penalty = penalty
        self.action_repeat = action_repeat
        self._box: gym.spaces.Box = env.action_space
        self._obs: np.ndarray | None = None
        self._checked = False
        self._backup_in_control = False
        self._rule_name = rule if isinstance(rule, str) else None
        self._log: EpisodeLog | None = None
        self._episodes = 0
        self._records: list[CostlyEpisode] = []

    @property
    def costly_episodes(self) -> list[CostlyEpisode]:
        """The records of the episodes that paid cost so far (the one running too, if it has)."""
        running = self._record_of_running_episode()
        return self._records + ([running] if running is not None else [])

    def _record_of_running_episode(self) -> CostlyEpisode | None:
        if self._log is None or not self._log.costly_steps or self._obs is None or len(self._records) >= MAX_RECORDS:
            return None
        return costly_episode(self.env, self.rule, self._rule_name, self._episodes - 1, self._log, self._obs)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        finished = self._record_of_running_episode()
        if finished is not None:
            self._records.append(finished)
        randomness = reset_randomness(self.env, kwargs.get("seed"))
        obs, info = self.env.reset(**kwargs)
        self._log, self._episodes = EpisodeLog(randomness), self._episodes + 1
        self._obs = np.asarray(obs)
        self._backup_in_control = False
        if not self._checked:
            self.rule.check_action_space(self.env.action_space, self._obs[None])
            self._checked = True
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Shield the proposal on each of the ``action_repeat`` env steps it is held for, and execute what passes."""
        if self._obs is None:
            raise RuntimeError("ShieldWrapper.step called before reset().")
        proposed = np.clip(np.asarray(action, dtype=np.float64), self._box.low, self._box.high)
        held, interventions, edits = HeldSteps(), 0, 0
        first: tuple[np.ndarray, float] | None = None  # the first env step's executed action and Ā
        for _ in range(self.action_repeat):
            obs, reward, terminated, truncated, info, decision = self._shielded_env_step(proposed)
            held.add(reward, info)
            intervened = bool(decision.intervened[0])
            interventions += intervened
            edits += bool(decision.edits[0])
            first = first or (info[EXECUTED_ACTION_KEY], float(decision.advantage[0]))
            if terminated or truncated or (intervened and self.on_intervention == "terminate"):
                break
        if self.action_repeat > 1:  # the held action's totals, and what the shield did on each of its env steps
            info = held.write(info)
            info[INTERVENTIONS_KEY] = interventions
            reward = held.reward
        assert first is not None  # action_repeat >= 1
        info[INTERVENED_KEY] = interventions > 0
        if edits:
            info[EDITS_KEY] = edits
        info[PROPOSED_ACTION_KEY] = proposed
        info[EXECUTED_ACTION_KEY], info[ADVANTAGE_KEY] = first
        info[ABSORBED_KEY] = interventions > 0 and self.on_intervention == "terminate"
        if info[ABSORBED_KEY]:
            info[ENV_REWARD_KEY] = reward
            return obs, -self.penalty, True, False, info
        if interventions and self.on_intervention == "continue" and self.penalty:
            info[ENV_REWARD_KEY] = reward
            reward = float(reward) - self.penalty * interventions
        return obs, reward, terminated, truncated, info

    def _shielded_env_step(self, proposed: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any], Any]:
        """One env step of the held proposal, shielded (eq. 12) at the current state: the step and the decision."""
        decision = self._decide(proposed)
        safe = decision.actions[0].reshape(self._box.shape).astype(self._box.dtype)  # the rule's actions are flat
        state = simulator_state(self.env)
        obs, reward, terminated, truncated, info = self.env.step(safe)
        intervened = bool(decision.intervened[0])
        assert self._log is not None  # reset() came first
        self._log.add(state, proposed, safe, intervened, float(decision.advantage[0]), float(info.get(COST_KEY, 0.0)))
        self._backup_in_control = intervened and self.on_intervention == "takeover" and not (terminated or truncated)
        info[EXECUTED_ACTION_KEY] = safe
        self._obs = np.asarray(obs)
        return obs, reward, terminated, truncated, info, decision

    def _decide(self, proposed: np.ndarray) -> ShieldDecision:
        """The rule's shield on the proposal; once the backup has taken over (``"takeover"``), the backup action."""
        assert self._obs is not None
        obs, proposal = np.asarray(self._obs, dtype=np.float64).reshape(1, -1), proposed.reshape(1, -1)
        if not self._backup_in_control:
            return self.rule.shield(obs, proposal)
        backup = self.rule.checked_backup(obs, proposal.shape[1])
        takeover = ShieldDecision(actions=backup, intervened=np.ones(1, dtype=bool), advantage=np.full(1, np.nan))
        return self.rule.close_failures(obs, proposal, takeover)  # a backup action that is not finite: ShieldFailure
