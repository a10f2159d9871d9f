"""Replayable records of costly episodes behind ``ShieldWrapper``, and their closed-loop replay."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from recording import AcceptsAll

import sppo_sb3  # noqa: F401  (registers the tasks and rules)
from sppo_sb3.shield import ShieldWrapper
from sppo_sb3.shield.records import WINDOW, CostlyEpisode, reset_randomness, restore_randomness
from sppo_sb3.shield.replay import replay

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "replay_costly.py"


def drive(env: ShieldWrapper, action: list[float], episodes: int, seed: int | None, steps: int = 300) -> None:
    for episode in range(episodes):
        env.reset(seed=seed if episode == 0 else None)
        for _ in range(steps):
            *_, terminated, truncated, _ = env.step(np.asarray(action))
            if terminated or truncated:
                break


@pytest.mark.parametrize(
    "env_id, action, seed", [("SafePointCircle-v0", [1.0, 0.3], 3), ("sppo_sb3/SafetyPointGoal1-v0", [1.0, 0.0], 0)]
)
def test_a_costly_episode_replays_step_for_step_and_a_sound_rule_holds_on_it(tmp_path, env_id, action, seed) -> None:
    env = ShieldWrapper(gym.make(env_id), AcceptsAll())
    drive(env, action, episodes=2, seed=seed, steps=120)
    records = env.costly_episodes
    assert records, "driving straight on with everything accepted must pay cost"
    record = CostlyEpisode.load(records[-1].save(tmp_path / "record.json"))  # through JSON, as on another machine
    assert record.costly_steps == records[-1].costly_steps
    assert record.provenance["packages"]["mujoco"] and "commit" in record.provenance
    assert record.window_start == max(0, record.costly_steps[-1] - WINDOW)
    same = replay(record, rule=AcceptsAll())
    assert same.first_divergence is None and same.replayed_costly == record.costly_steps  # the same episode again
    assert replay(record, rule="auto").holds  # the registered rule would have held


def test_the_second_episode_replays_from_the_streams_the_first_left() -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), AcceptsAll())
    drive(env, [1.0, 0.3], episodes=3, seed=7, steps=200)
    later = [record for record in env.costly_episodes if record.log.randomness["seed"] is None]
    assert later, "episodes after the first are reset without a seed"
    result = replay(later[0], rule=AcceptsAll())
    assert result.first_divergence is None and result.replayed_costly == later[0].costly_steps


def test_an_episode_from_fresh_entropy_is_not_replayable_and_says_why() -> None:
    env = gym.make("sppo_sb3/SafetyPointGoal1-v0")  # its layout stream exists only after a reset
    randomness = reset_randomness(env, seed=None)
    assert not randomness["replayable"]
    with pytest.raises(ValueError, match="Seed the env"):
        restore_randomness(env, randomness)
    env.reset(seed=1)
    assert reset_randomness(env, seed=None)["replayable"]  # later episodes continue a seeded stream


def test_replay_script_reports_and_exits_on_whether_the_rule_holds(tmp_path) -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), AcceptsAll())
    drive(env, [1.0, 0.3], episodes=1, seed=3)
    path = env.costly_episodes[0].save(tmp_path / "record.json")
    data = json.loads(path.read_text())
    assert data["rule"] is None and data["rule_class"] == "AcceptsAll"
    no_rule = subprocess.run([sys.executable, str(SCRIPT), str(path)], capture_output=True, text=True)
    assert no_rule.returncode == 2 and "--rule NAME" in no_rule.stderr
    holds = subprocess.run(
        [sys.executable, str(SCRIPT), str(path), "--rule", "auto", "--window"], capture_output=True, text=True
    )
    assert holds.returncode == 0 and "the rule now holds" in holds.stdout and "env step" in holds.stdout
