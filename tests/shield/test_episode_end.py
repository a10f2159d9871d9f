"""Where a task ends its episodes (a fall), the MuJoCo rule stops counting cost: the episode end and the fall that
Walker2d seed 0 of the velocity grid paid 20 violations in."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.mujoco.walker2d_v4 import Walker2dEnv

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.shield import MujocoShieldingRule, StateConstraint
from sppo_sb3.shield.analysis.replay import replay_proposals
from sppo_sb3.shield.mujoco.model import ConstraintSteps, EpisodeEnd, MujocoLayout
from sppo_sb3.shield.registry import default_shielding_rule

DATA = Path(__file__).resolve().parent / "data"


def test_the_episode_end_is_read_from_the_env() -> None:
    walker = MujocoLayout.of("Walker2d-v4").episode_end
    assert walker == EpisodeEnd(z_index=1, z_range=(0.8, 2.0), angle_range=(-1.0, 1.0))
    ant = MujocoLayout.of("Ant-v4").episode_end
    assert ant is not None and ant.z_index == 2 and ant.angle_range is None  # a free joint: qpos[2] is the height
    assert MujocoLayout.of("HalfCheetah-v4").episode_end is None  # never ends an episode on its own
    assert MujocoLayout.of("Hopper-v4", terminate_when_unhealthy=False).episode_end is None


@pytest.mark.parametrize("env_id", ["Hopper-v4", "Walker2d-v4", "Ant-v4"])
def test_ended_is_where_the_env_terminates(env_id: str) -> None:
    env = gym.make(env_id)
    end = MujocoLayout.of(env).episode_end
    assert end is not None
    env.action_space.seed(0)
    env.reset(seed=0)
    terminations = 0
    for _ in range(400):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        data = env.unwrapped.data  # type: ignore[attr-defined]
        assert bool(end.ended(data.qpos, data.qvel)) == terminated
        terminations += int(terminated)
        if terminated or truncated:
            env.reset()
    assert terminations > 0  # random actions fall: both answers were checked


def test_an_env_that_ends_elsewhere_is_refused() -> None:
    class NeverFalls(Walker2dEnv):
        @property
        def is_healthy(self) -> bool:
            return True

    env = NeverFalls()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="cannot tell where its episodes end"):
        EpisodeEnd.of(env)


@dataclasses.dataclass(frozen=True)
class UnsafeAfter(StateConstraint):
    """Every step that ends after ``time`` seconds is unsafe (a test constraint on the rolled time)."""

    time: float

    def is_unsafe(self, steps: ConstraintSteps) -> np.ndarray:
        return steps.after[..., 0] > self.time

    def distance(self, steps: ConstraintSteps) -> np.ndarray:
        return np.where(self.is_unsafe(steps), 0.0, 1.0)


def test_no_cost_is_counted_after_the_step_that_ends_the_episode() -> None:
    rule = MujocoShieldingRule("Walker2d-v4", UnsafeAfter(0.05), horizon=10, n_particles=4, n_threads=0, alpha=0.1)
    blind = MujocoShieldingRule(
        dataclasses.replace(rule.layout, episode_end=None), rule.constraint, horizon=10, n_particles=4, n_threads=0, alpha=0.1
    )
    lying = np.zeros((1, len(rule.layout.states_from_obs(rule.model, np.zeros((1, 17)))[0])))
    lying[0, 2] = 0.3  # rootz far below the healthy 0.8: the first step ends the episode
    plan = np.zeros((1, 10, rule.model.nu))
    assert rule.plan_costs(lying, plan)[0] == 0.0  # the violations from 0.05 s on come after the end
    assert blind.plan_costs(lying, plan)[0] > 50.0  # counted, they are worth a violation


def replay_walker2d_fall(rule: MujocoShieldingRule) -> tuple[int, int]:
    """The falling episode of Walker2d seed 0 (velocity grid, the rule before the episode end and the 0.24 s
    lookahead), replayed through ``rule`` from the recorded state. Returns (violations, interventions)."""
    recorded = np.load(DATA / "walker2d_fall.npz")
    replay = replay_proposals(
        rule, "sppo_sb3/SafetyWalker2dVelocity-v1", recorded["qpos"], recorded["qvel"], recorded["proposals"]
    )
    return replay.violations, replay.interventions


def test_the_fall_of_walker2d_seed_0_is_shielded() -> None:
    env_id = "sppo_sb3/SafetyWalker2dVelocity-v1"
    rule = default_shielding_rule(env_id, gym.make(env_id))
    assert isinstance(rule, MujocoShieldingRule)
    assert rule.horizon == 30 and rule.layout.episode_end is not None
    violations, interventions = replay_walker2d_fall(rule)
    assert violations == 0 and interventions > 0
    before = MujocoShieldingRule(
        dataclasses.replace(rule.layout, episode_end=None), rule.constraint, horizon=15, alpha=rule.alpha, eta=rule.eta
    )
    assert replay_walker2d_fall(before)[0] > 0  # the rule the grid ran: the fall's violations get through
