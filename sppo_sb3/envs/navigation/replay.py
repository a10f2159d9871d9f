"""Replay recorded Safety-Gymnasium runs through the package's navigation tasks, step by step, and measure the gaps.

A recording (``scripts/record_safety_gymnasium.py``, run in a Python 3.10 venv with Safety-Gymnasium 1.0.0) holds, per
task, the layouts of a few seeds and a rollout: before each step the simulator state, after it the observation,
reward, cost terms and events. :func:`compare_layouts` resets the package's env with each seed and compares what it
builds; :func:`replay_steps` loads the recorded state before every step, takes the recorded action and compares the
outcome, so that differences do not compound along the rollout. ``tests/envs/navigation/test_fidelity.py`` asserts the
results; ``scripts/navigation_fidelity.py`` prints them as a table.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sppo_sb3.envs.navigation.env import GOAL_MET_KEY, NavigationState, SafetyNavigationEnv

#: the task scalars of a recording, by the names the package's tasks give them
TASK_SCALARS = {"last_dist_goal": "last_dist_goal", "last_dist_box": "last_dist_box", "last_box_goal": "last_box_goal",
                "buttons_timer": "timer", "goal_button": "goal_button"}  # fmt: skip


@dataclass
class Recording:
    """One task's recording: its arrays and its ``meta`` (versions, layouts, the order of its keys)."""

    env_id: str
    arrays: dict[str, np.ndarray]
    meta: dict[str, Any]

    @classmethod
    def load(cls, path: Path) -> Recording:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files if key != "meta"}
            meta = json.loads(str(data["meta"]))
        return cls(meta["env_id"], arrays, meta)

    def make_env(self) -> SafetyNavigationEnv:
        """The package's env of the recorded task."""
        name = self.env_id.removeprefix("Safety").removesuffix("-v0")
        robot = "Point" if name.startswith("Point") else "Car"
        return SafetyNavigationEnv(robot, name[len(robot) : -1], int(name[-1]))

    @property
    def steps(self) -> int:
        return len(self.arrays["action"])


@dataclass
class LayoutReport:
    """The largest gaps between the recorded layouts (one per seed) and the package's."""

    seeds: int = 0
    names_match: bool = True
    position: float = 0.0
    rotation: float = 0.0
    goal: float = 0.0
    goal_button_match: bool = True
    qpos: float = 0.0
    obs: dict[str, float] = field(default_factory=dict)


@dataclass
class StepReport:
    """Per replayed step: the observation's gap per key, the reward's, and which discrete outcomes differ."""

    obs: dict[str, np.ndarray]
    reward: np.ndarray
    cost_mismatch: np.ndarray
    term_mismatch: np.ndarray
    terminated_mismatch: np.ndarray
    goal_met_mismatch: np.ndarray
    goal_after: np.ndarray

    @property
    def discrete_mismatches(self) -> int:
        """Steps whose cost, a cost term, the termination or the goal event differ."""
        return int(np.sum(self.cost_mismatch | self.term_mismatch | self.terminated_mismatch | self.goal_met_mismatch))


def _obs_gaps(keys: list[tuple[str, int]], ours: np.ndarray, theirs: np.ndarray) -> dict[str, float]:
    gaps, start = {}, 0
    for key, size in keys:
        gaps[key] = float(np.max(np.abs(ours[start : start + size] - theirs[start : start + size])))
        start += size
    return gaps


def compare_layouts(recording: Recording, env: SafetyNavigationEnv | None = None) -> LayoutReport:
    """Reset the package's env with each recorded seed and compare the layout, headings, goal and first observation."""
    env = env or recording.make_env()
    report = LayoutReport()
    for layout in recording.meta["layouts"]:
        obs, _ = env.reset(seed=layout["seed"])
        report.seeds += 1
        theirs = {name: np.asarray(xy) for name, xy in layout["layout"].items()}
        report.names_match &= set(theirs) == set(env.layout)
        report.position = max(report.position, max(float(np.max(np.abs(env.layout[k] - v))) for k, v in theirs.items()))
        quat = env.model.body_quat[env.world.agent_id] if not env.world.robot.free_joint else env.data.qpos[3:7]
        heading = 2 * np.arctan2(quat[3], quat[0]) % (2 * np.pi)
        report.rotation = max(report.rotation, abs(float(heading - layout["agent_rot"] % (2 * np.pi))))
        if env.task.has("goal"):
            report.goal = max(report.goal, float(np.max(np.abs(env.world.body_xpos(("goal",))[0] - layout["goal_pos"]))))
        if layout.get("goal_button") is not None:
            report.goal_button_match &= env.task.state().get("goal_button") == layout["goal_button"]
        report.qpos = max(report.qpos, float(np.max(np.abs(env.data.qpos - layout["qpos"]))))
        for key, gap in _obs_gaps(env.observation_keys, obs, np.asarray(layout["obs"])).items():
            report.obs[key] = max(report.obs.get(key, 0.0), gap)
    return report


def recorded_state(recording: Recording, env: SafetyNavigationEnv, t: int) -> NavigationState:
    """The state before recorded step ``t``, in the package's terms."""
    arrays = recording.arrays
    task = {ours: float(arrays[theirs][t]) for theirs, ours in TASK_SCALARS.items() if theirs in arrays}
    return NavigationState(
        float(arrays["time"][t]),
        arrays["qpos"][t],
        arrays["qvel"][t],
        arrays["qacc_warmstart"][t],
        arrays["mocap_pos"][t].reshape(env.model.nmocap, 3),
        arrays["mocap_quat"][t].reshape(env.model.nmocap, 4),
        arrays["goal_pos"][t, :2] if "goal_pos" in arrays else np.zeros(2),
        {key: value for key, value in task.items() if key in env.task.state()},
    )


def replay_steps(recording: Recording, env: SafetyNavigationEnv | None = None) -> StepReport:
    """Replay every recorded step from its recorded state (and, where a goal was met, its recorded RNG state)."""
    env = env or recording.make_env()
    arrays = recording.arrays
    env.reset(seed=recording.meta["layouts"][0]["seed"])  # the rollout's layout
    rng_states = {int(t): (keys, int(pos)) for t, keys, pos in zip(arrays["rng_steps"], arrays["rng_keys"], arrays["rng_pos"])}
    cost_keys = [key for key in recording.meta["cost_keys"] if key != "cost_sum"]
    n = recording.steps
    obs_gaps = {key: np.zeros(n) for key, _ in env.observation_keys}
    reward, goal_after = np.zeros(n), np.zeros(n)
    cost, terms, terminated, goal_met = (np.zeros(n, dtype=bool) for _ in range(4))
    for t in range(n):
        env.set_state(recorded_state(recording, env, t))
        if t in rng_states:
            env.set_rng_state(rng_states[t][0], rng_states[t][1])
        obs, r, done, _, info = env.step(arrays["action"][t])
        for key, gap in _obs_gaps(env.observation_keys, obs, arrays["obs"][t]).items():
            obs_gaps[key][t] = gap
        reward[t] = abs(r - arrays["reward"][t])
        cost[t] = info["cost"] != arrays["cost"][t]
        recorded_terms = dict(zip(recording.meta["cost_keys"], arrays["cost_terms"][t], strict=True))
        terms[t] = any(info.get(key, 0.0) != recorded_terms[key] for key in cost_keys)
        terminated[t] = done != bool(arrays["terminated"][t])
        goal_met[t] = bool(info.get(GOAL_MET_KEY, False)) != bool(arrays["goal_met"][t])
        if arrays["goal_met"][t] and env.task.has("goal"):
            goal_after[t] = float(np.max(np.abs(env.world.body_xpos(("goal",))[0, :2] - arrays["goal_pos_after"][t, :2])))
    return StepReport(obs_gaps, reward, cost, terms, terminated, goal_met, goal_after)
