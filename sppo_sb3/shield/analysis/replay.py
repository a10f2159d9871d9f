"""Replay recorded proposals through a MuJoCo rule from a recorded state: what the rule lets into the env."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from sppo_sb3.shield.mujoco.rule import MujocoShieldingRule


@dataclass(frozen=True)
class Replay:
    """What a rule let through on a replayed episode: costly steps, interventions and steps until the episode ended."""

    violations: int
    interventions: int
    steps: int
    terminated: bool


def replay_proposals(
    rule: MujocoShieldingRule, env_id: str, qpos: np.ndarray, qvel: np.ndarray, proposals: np.ndarray
) -> Replay:
    """Shield each of ``proposals`` with ``rule`` and step ``env_id`` (from the state ``qpos, qvel``) with the decision,
    until the proposals or the episode end.

    The rule is handed the recorded state once, as the prediction it keeps for the first observation (a recorded
    state may start mid-fall, with velocities beyond what the observation keeps: gymnasium's MuJoCo envs clip them);
    from there it tracks the states itself, as it does in training.

    :param rule: a rule whose model is the env's (``rule.layout`` of ``env_id``).
    :param env_id: the task the proposals were recorded on.
    :param qpos: the recorded positions.
    :param qvel: the recorded velocities.
    :param proposals: ``(T, nu)``, the learner's proposals from that state on.
    """
    env = gym.make(env_id)
    env.reset(seed=0)
    sim = env.unwrapped
    sim.set_state(qpos, qvel)  # type: ignore[attr-defined]
    obs = sim._get_obs()  # type: ignore[attr-defined]
    state = rule.layout.states_from_obs(rule.model, obs[None])  # [time, qpos, qvel, ...]
    state[0, 1 : 1 + rule.model.nq], state[0, 1 + rule.model.nq : 1 + rule.model.nq + rule.model.nv] = qpos, qvel
    rule.warm_starts.replace(np.array([-1]), rule._state_obs(obs[None]), np.zeros((1, rule.horizon, rule.model.nu)), state)
    violations = interventions = steps = 0
    terminated = False
    try:
        for proposal in proposals:
            decision = rule.shield(obs[None], proposal[None])
            obs, _, terminated, _, info = env.step(decision.actions[0])
            violations += int(info["cost"] > 0)
            interventions += int(decision.intervened[0])
            steps += 1
            if terminated:
                break
    finally:
        env.close()
    return Replay(violations, interventions, steps, terminated)
