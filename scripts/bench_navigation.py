"""Navigation benchmark: raw env speed against Safety-Gymnasium 1.0.0, and the navigation shield's cost per env step.

- ``speed``: env steps per second of the package's navigation tasks and of Safety-Gymnasium 1.0.0's (run by its own
  Python 3.10 venv, ``--sg-python``, in a subprocess), random actions, with the resets of a training loop and without
  their time (the original rebuilds its model from XML at every reset), timed alternately ``--repeats`` times in the
  same run; reported: the best of each and their ratios (a machine's speed cancels out of them). Without the venv
  this part is skipped, saying how to make it.
- ``shield``: ``ShieldWrapper`` with the task's registered rule, driven by three kinds of proposals: ``goal`` (steer
  to the goal, through anything in the way: what an unsafe learner does), ``route`` (head for the goal around the
  hazards, vases and pillars: a driver that plans), ``random`` and ``adversarial`` (steer into the nearest hazard,
  vase or pillar). Reported: ms per env step of the whole shielded step and of the env alone, the 95th percentile, the
  share of steps that solved ``Q̄(s, a)``, interventions (and the edits among them: ``--rule permissive=1``, the
  accepted action nearest a rejected proposal instead of the backup's), the cost paid (0: the shield held) and the
  goals reached; then the goals and cost of the same proposals without the shield (does the shield leave the task solvable?).
  The goal-seeking and adversarial proposals push against the shield on most steps, so it solves on most steps;
- ``sppo``: SPPO training (``hyperparams/navigation/sppo.yml``) for ``--sppo-steps`` with the task's rule, timed
  inside the run: the shield's ms per env step where the learner proposes (it learns to stop pushing against the
  shield), the violations and the interventions.

    python scripts/bench_navigation.py                                  # both parts, PointGoal1 and CarGoal1 (+ PointGoal2)
    python scripts/bench_navigation.py --skip shield --repeats 5
    python scripts/bench_navigation.py --skip speed --shield-steps 2000 --tasks sppo_sb3/SafetyPointGoal2-v0
    python scripts/bench_navigation.py --skip speed shield --sppo-steps 20000   # SPPO's shield on the three tasks

Time it on a quiet machine: other jobs on the same cores change both numbers (not their ratio as much).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.envs.navigation import SafetyNavigationEnv
from sppo_sb3.shield import ShieldWrapper
from sppo_sb3.shield.base import ShieldDecision, ShieldingRule
from sppo_sb3.shield.registry import SHIELDING_RULES, rule_parameters_of
from sppo_sb3.shield.tasks.navigation import NavigationShieldingRule

ROOT = Path(__file__).resolve().parents[1]

SG_PYTHON = Path("/tmp/sg310/bin/python")
SPEED_TASKS = ("sppo_sb3/SafetyPointGoal1-v0", "sppo_sb3/SafetyCarGoal1-v0")
SHIELD_TASKS = ("sppo_sb3/SafetyPointGoal1-v0", "sppo_sb3/SafetyPointGoal2-v0", "sppo_sb3/SafetyCarGoal1-v0")
#: the loop both envs are timed with: random actions, a reset where an episode ends; it prints the steps per second
#: with the resets' time and without it (the original rebuilds its model from XML at every reset)
TIMING_LOOP = """
import sys, time, numpy as np
def timed(env, n):
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (n, 2))
    stepping = resetting = 0.0
    for action in actions:
        start = time.perf_counter()
        *_, terminated, truncated, _ = env.step(action)
        stepping += time.perf_counter() - start
        if terminated or truncated:
            start = time.perf_counter()
            env.reset()
            resetting += time.perf_counter() - start
    return n / (stepping + resetting), n / stepping
"""
SG_SNIPPET = (
    TIMING_LOOP
    + """
import safety_gymnasium
print(*timed(safety_gymnasium.make(sys.argv[1]), int(sys.argv[2])))
"""
)


def our_steps_per_second(env_id: str, steps: int) -> tuple[float, float]:
    """Env steps per second of the package's task, with and without the resets' time."""
    namespace: dict[str, Any] = {}
    exec(TIMING_LOOP, namespace)  # the same loop as the original's, from one string
    return namespace["timed"](gym.make(env_id).unwrapped, steps)


def sg_steps_per_second(env_id: str, steps: int, python: Path) -> tuple[float, float]:
    """The same loop on Safety-Gymnasium 1.0.0's task, in its own venv."""
    original = env_id.split("/")[-1]
    result = subprocess.run([str(python), "-c", SG_SNIPPET, original, str(steps)], capture_output=True, text=True, check=True)
    with_resets, steps_only = result.stdout.strip().splitlines()[-1].split()
    return float(with_resets), float(steps_only)


def bench_speed(tasks: tuple[str, ...], steps: int, repeats: int, python: Path) -> list[dict[str, Any]]:
    rows = []
    for env_id in tasks:
        ours, theirs = [], []
        for _ in range(repeats):  # alternately, so that both see the same machine
            ours.append(our_steps_per_second(env_id, steps))
            theirs.append(sg_steps_per_second(env_id, steps, python))
        best_ours, best_theirs = np.max(ours, axis=0), np.max(theirs, axis=0)
        rows.append(
            {
                "task": env_id,
                "ours steps/s": best_ours[0],
                "Safety-Gymnasium steps/s": best_theirs[0],
                "ratio": best_ours[0] / best_theirs[0],
                "ours, steps only": best_ours[1],
                "Safety-Gymnasium, steps only": best_theirs[1],
                "ratio, steps only": best_ours[1] / best_theirs[1],
            }
        )
    return rows


def steer(env: SafetyNavigationEnv, target: np.ndarray) -> np.ndarray:
    """The action that drives the robot straight at ``target`` (the Point drives along x; the Car along -y)."""
    ego_x, ego_y = (np.r_[target - env.world.agent_xpos()[:2], 0.0] @ env.world.agent_xmat())[:2]
    if env.world.robot.name == "Point":
        return np.array([1.0, float(np.clip(3 * np.arctan2(ego_y, ego_x), -1, 1))])
    turn = float(np.clip(3 * np.arctan2(ego_x, -ego_y), -1, 1))
    return np.clip(np.array([1.0 + turn, 1.0 - turn]), -1, 1)


def constrained_positions(env: SafetyNavigationEnv) -> np.ndarray:
    """``(n, 2)``: where the hazards, vases and pillars are."""
    return env.world.body_xpos([name for name in env.layout if name.startswith(("hazard", "vase", "pillar"))])[:, :2]


def route(env: SafetyNavigationEnv, clearance: float = 0.5, reach: float = 0.6) -> np.ndarray:
    """Head for the goal along the free direction nearest to it: the first of 32 headings whose next ``reach`` metres
    pass no hazard, vase or pillar closer than ``clearance`` (a driver that plans, unlike ``goal``); the Point turns on
    the spot before it drives."""
    me, goal = env.world.agent_xpos()[:2], env.world.body_xpos(("goal",))[0, :2]
    headings = np.linspace(-np.pi, np.pi, 32, endpoint=False)
    directions = np.stack([np.cos(headings), np.sin(headings)], axis=1)
    paths = me + np.linspace(0.0, reach, 13)[None, :, None] * directions[:, None]  # (32, 13, 2)
    objects = constrained_positions(env)
    nearest = np.linalg.norm(paths[:, :, None] - objects[None, None], axis=-1).min(axis=(1, 2)) if len(objects) else np.inf
    to_goal = np.arctan2(*(goal - me)[::-1])
    score = np.cos(headings - to_goal) - 10.0 * (nearest < clearance)
    target = me + directions[np.argmax(score)]
    if env.world.robot.name != "Point":
        return steer(env, target)
    ego_x, ego_y = (np.r_[target - me, 0.0] @ env.world.agent_xmat())[:2]
    bearing = float(np.arctan2(ego_y, ego_x))
    return np.array([float(abs(bearing) < 0.5), float(np.clip(3 * bearing, -1, 1))])


def proposal(kind: str, env: SafetyNavigationEnv, rng: np.random.Generator) -> np.ndarray:
    """A proposed action of the given ``kind`` (see the module)."""
    if kind == "random":
        return rng.uniform(-1, 1, 2)
    if kind == "goal":
        return steer(env, env.world.body_xpos(("goal",))[0, :2])
    if kind == "route":
        return route(env)
    positions = constrained_positions(env)
    return steer(env, positions[np.argmin(np.linalg.norm(positions - env.world.agent_xpos()[:2], axis=1))])


#: settings of the rules under test beside the registered ones' (``--rule``)
RULE_SETTINGS: dict[str, Any] = {}


def task_rule(env_id: str, env: Any) -> NavigationShieldingRule:
    """The rule registered for ``env_id``, built from ``env``'s parameters, with :data:`RULE_SETTINGS` on top."""
    factory = SHIELDING_RULES.get(env_id)
    rule = factory(**{**rule_parameters_of(env_id, env), **RULE_SETTINGS}) if factory is not None else None
    if not isinstance(rule, NavigationShieldingRule):
        raise SystemExit(f"{env_id} has no navigation shield (level 0 constrains nothing)")
    return rule


def bench_shield(env_id: str, kind: str, steps: int) -> dict[str, Any]:
    env = gym.make(env_id)
    rule = task_rule(env_id, env)
    shielded = ShieldWrapper(env, rule)
    inner = env.unwrapped
    assert isinstance(inner, SafetyNavigationEnv)
    shielded.reset(seed=0)
    shielded.step(np.zeros(2))  # the first step checks the rule on the action space: not timed
    rng = np.random.default_rng(0)
    times, env_times, cost, interventions, edits, goals, goals_alone, cost_alone = [], [], 0.0, 0, 0, 0, 0, 0.0
    for _ in range(steps):
        action = proposal(kind, inner, rng)
        start = time.perf_counter()
        _, _, terminated, truncated, info = shielded.step(action)
        times.append(time.perf_counter() - start)
        cost += info["cost"]
        interventions += info["shield_intervened"]
        edits += info.get("shield_edits", 0)
        goals += bool(info.get("goal_met", False))
        if terminated or truncated:
            shielded.reset()
    inner.reset(seed=0)
    for _ in range(steps):  # the env alone: its time, for scale, and what the same proposals reach without the shield
        start = time.perf_counter()
        _, _, terminated, truncated, info = inner.step(proposal(kind, inner, rng))
        env_times.append(time.perf_counter() - start)
        cost_alone += info["cost"]
        goals_alone += bool(info.get("goal_met", False))
        if terminated or truncated:
            inner.reset()
    ms = 1e3 * np.asarray(times)
    return {
        "task": env_id,
        "proposals": kind,
        "rule": " ".join(f"{name}={value}" for name, value in RULE_SETTINGS.items()) or "registered",
        "steps": steps,
        "ms/step": float(ms.mean()),
        "p95 ms": float(np.quantile(ms, 0.95)),
        "env ms/step": 1e3 * float(np.mean(env_times)),
        "Q̄(s,a) solved": rule.solve_counts.q_solves / max(rule.solve_counts.steps, 1),
        "interventions": interventions,
        "edits": edits,
        "cost": cost,
        "goals": goals,
        "alone: goals": goals_alone,
        "alone: cost": cost_alone,
    }


class TimedRule(ShieldingRule):
    """A rule that times every call of ``rule.shield`` and counts the env steps it shielded."""

    def __init__(self, rule: ShieldingRule) -> None:
        super().__init__(eta=rule.eta)
        self.rule, self.gamma = rule, getattr(rule, "gamma", 0.99)
        self.seconds, self.steps = 0.0, 0

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return self.rule.cost_value(obs, actions)

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return self.rule.backup_action(obs)

    def shield(self, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        start = time.perf_counter()
        decision = self.rule.shield(obs, actions)
        self.seconds += time.perf_counter() - start
        self.steps += len(obs)
        return decision


def bench_sppo(env_id: str, steps: int, seed: int = 0) -> dict[str, Any]:
    """Shielded SPPO training on ``env_id``: the shield's time per env step, violations and interventions."""
    import torch as th
    from stable_baselines3.common.env_util import make_vec_env

    from sppo_sb3 import SPPO
    from sppo_sb3.zoo.hyperparams import constructor_kwargs

    th.set_num_threads(1)  # as the benchmark's runs (--num-threads 1): two threads beside another job stall each other
    env = make_vec_env(env_id, n_envs=1, seed=seed)
    rule = TimedRule(task_rule(env_id, env))
    kwargs = constructor_kwargs(ROOT / "hyperparams" / "navigation" / "sppo.yml", env_id)
    kwargs.pop("shield", None)
    model = SPPO(kwargs.pop("policy"), env, shield=rule, seed=seed, **kwargs)
    start = time.perf_counter()
    model.learn(steps)
    total = time.perf_counter() - start
    return {"task": env_id, "SPPO steps": steps, "shield ms/step": 1e3 * rule.seconds / rule.steps,
            "training ms/step": 1e3 * total / steps, "violations": int(model.safety_metrics.violations),
            "interventions": int(model.safety_metrics.interventions)}  # fmt: skip


def rule_settings(text: str) -> dict[str, Any]:
    """``"alpha=0.05 horizon=8"`` as keyword arguments of the rule (numbers are parsed, the rest kept as text)."""
    settings: dict[str, Any] = {}
    for item in text.split():
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise SystemExit(f"--rule takes NAME=VALUE items, got {item!r}")
        try:
            settings[name] = int(value)
        except ValueError:
            try:
                settings[name] = float(value)
            except ValueError:
                settings[name] = value
    return settings


def print_table(title: str, rows: list[dict[str, Any]]) -> None:
    print(f"\n{title}\n")
    print("| " + " | ".join(rows[0]) + " |")
    print("|" + "---|" * len(rows[0]))
    for row in rows:
        print("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in row.values()) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--tasks", nargs="+", default=None, help="tasks (default: PointGoal1, CarGoal1; PointGoal2 too for the shield)"
    )
    parser.add_argument("--speed-steps", type=int, default=3000, help="env steps per speed timing")
    parser.add_argument("--repeats", type=int, default=3, help="alternate timings of each env")
    parser.add_argument("--sg-python", type=Path, default=SG_PYTHON, help="Python of a venv with safety-gymnasium==1.0.0")
    parser.add_argument("--shield-steps", type=int, default=1000, help="shielded env steps per proposal kind")
    parser.add_argument(
        "--proposals",
        nargs="+",
        default=["goal", "route", "random", "adversarial"],
        choices=["goal", "route", "random", "adversarial"],
    )
    parser.add_argument("--sppo-steps", type=int, default=20_000, help="SPPO training steps per task")
    parser.add_argument("--skip", nargs="*", default=[], choices=["speed", "shield", "sppo"], help="parts to skip")
    parser.add_argument(
        "--rule", type=str, default="", help='settings of the rules beside the registered ones, e.g. "alpha=0.05 eta=0.5"'
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the figures to this file")
    args = parser.parse_args()
    RULE_SETTINGS.update(rule_settings(args.rule))
    figures: dict[str, list[dict[str, Any]]] = {}
    if "speed" not in args.skip:
        if args.sg_python.exists():
            figures["speed"] = bench_speed(tuple(args.tasks or SPEED_TASKS), args.speed_steps, args.repeats, args.sg_python)
            print_table("Raw env steps per second (best of the alternate timings; 1000-step episodes)", figures["speed"])
        else:
            venv = '"$(pyenv prefix 3.10.13)/bin/python" -m venv /tmp/sg310'
            print(
                f"speed: skipped, no {args.sg_python}: {venv} && /tmp/sg310/bin/pip install safety-gymnasium==1.0.0",
                file=sys.stderr,
            )
    if "shield" not in args.skip:
        figures["shield"] = [
            bench_shield(task, kind, args.shield_steps) for task in args.tasks or SHIELD_TASKS for kind in args.proposals
        ]
        print_table("The navigation shield per env step (ShieldWrapper, the task's registered rule)", figures["shield"])
    if "sppo" not in args.skip:
        figures["sppo"] = [bench_sppo(task, args.sppo_steps) for task in args.tasks or SHIELD_TASKS]
        print_table("SPPO's shield while it learns (hyperparams/navigation/sppo.yml)", figures["sppo"])
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
