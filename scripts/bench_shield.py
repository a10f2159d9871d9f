"""Shield benchmark: the shields' cost per env step, a MuJoCo task's rule on a real training run's states.

Runs, in one process:

- ``replay``: the observations and proposed actions of a real shielded training run on ``--task`` (a MuJoCo task with
  a registered :class:`~sppo_sb3.shield.MujocoShieldingRule`: ``SafeHalfCheetahHeight-v1`` by default, or a velocity
  task such as ``sppo_sb3/SafetyHopperVelocity-v1``; SPPO at the small configuration of ``lab/hyperparams/small/sppo.yml``
  (``hyperparams/velocity/sppo.yml``, the same, on the velocity tasks),
  or SAILR at ``hyperparams/sailr.yml``; recorded once into ``--states``, then reused) are replayed through the
  task's rule, certified (the default) and full
  (``certify=False``, every quantity solved on every step), with 1 env (the run's steps in order) and with 8 envs
  (the run cut into 8 consecutive pieces, one per env, shielded in one call per step). Reported: mean and 95th
  percentile ms per env step (a call's time over its envs), the certified mean as a share of the full rule's (a
  machine's speed cancels out of it: the full rule does the same work on every step), the share of steps that solved
  ``Q̄(s, a)``, ``ζ(s)`` and ``Q̄(s, ζ(s))``, the interventions, and whether both rules took the same decisions
  (executed action and intervention) on every replayed step;
- ``point``: ms per env step of the Point rule on visited states, 1 and 8 envs;
- ``rollouts``: the native rollouts the Cheetah rule is made of (1 rollout: a certificate; 65: one MPC solve; 520: one
  solve for 8 envs; ``5·15 + 1`` physics steps each), on the calling thread and on the rule's thread pool, against a
  Python ``mj_step`` loop doing the same work (heights checked equal).

    python scripts/bench_shield.py                       # record (if needed) 3000 steps of SPPO, replay all
    python scripts/bench_shield.py --envs 1 --full-steps 1000
    python scripts/bench_shield.py --quick               # a 400-step recording, 200 full-rule steps
    python scripts/bench_shield.py --task sppo_sb3/SafetyHopperVelocity-v1 --envs 1 --skip point rollouts
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_lab.configs import LAB_HYPERPARAMS_DIR
from sppo_lab.recording import RecordingRule
from sppo_sb3.envs.velocity import VELOCITY_TASKS
from sppo_sb3.shield import SHIELDING_RULES, MujocoShieldingRule, rule_parameters_of
from sppo_sb3.shield.base import ShieldingRule
from sppo_sb3.shield.tasks.cheetah import HalfCheetahHeightShieldingRule, rollout_heights_python
from sppo_sb3.shield.tasks.point import PointCircleShieldingRule
from sppo_sb3.zoo import constructor_kwargs

ENV_ID = "SafeHalfCheetahHeight-v1"
ROOT = Path(__file__).resolve().parents[1]
HYPERPARAMS = {"sppo": LAB_HYPERPARAMS_DIR / "small" / "sppo.yml", "sailr": ROOT / "hyperparams" / "sailr.yml"}
#: the velocity tasks' settings: the velocity benchmark's (the same small TOLD for SPPO)
VELOCITY_HYPERPARAMS = ROOT / "hyperparams" / "velocity"
VELOCITY_IDS = frozenset(task.env_id for task in VELOCITY_TASKS)


# ---------------------------------------------------------------------------------------------------- recording
def task_rule(task: str, **settings: Any) -> MujocoShieldingRule:
    """The rule registered for ``task``, built from the env's parameters, with ``settings`` (threads, certify)."""
    env = gym.make(task)
    rule = SHIELDING_RULES[task](**rule_parameters_of(task, env), **settings)
    env.close()
    assert isinstance(rule, MujocoShieldingRule), f"{task}'s rule is not a MujocoShieldingRule"
    return rule


def algo_kwargs(algo: str, task: str) -> dict[str, Any]:
    """The yml entry of ``algo`` for the task, as constructor keywords (the shield is the recording one)."""
    kwargs = constructor_kwargs(VELOCITY_HYPERPARAMS / f"{algo}.yml" if task in VELOCITY_IDS else HYPERPARAMS[algo], task)
    kwargs.pop("shield", None)
    return kwargs


def record_run(algo: str, task: str, steps: int, seed: int) -> dict[str, np.ndarray]:
    """Train ``algo`` shielded on one env for ``steps`` env steps; the shield's inputs, in order, and the violations."""
    from stable_baselines3.common.env_util import make_vec_env

    from sppo_sb3 import SAILR, SPPO

    rule = RecordingRule(task_rule(task, seed=seed))
    env = make_vec_env(task, n_envs=1, seed=seed)
    cls = {"sppo": SPPO, "sailr": SAILR}[algo]
    kwargs = algo_kwargs(algo, task)
    model = cls(kwargs.pop("policy"), env, shield=rule, seed=seed, **kwargs)
    model.learn(steps)
    obs, actions = rule.pairs()
    return {
        "obs": obs[:steps],
        "actions": actions[:steps],
        "violations": np.array(model.safety_metrics.violations),
        "interventions": np.array(model.safety_metrics.interventions),
    }


def load_or_record(path: Path, algo: str, task: str, steps: int, seed: int) -> dict[str, np.ndarray]:
    """The recorded run at ``path``, recorded first when missing."""
    if not path.exists():
        start = time.perf_counter()
        run = record_run(algo, task, steps, seed)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **run)
        print(f"recorded {len(run['obs'])} steps of shielded {algo} on {task} in {time.perf_counter() - start:.0f} s")
    with np.load(path) as run:
        return dict(run)


# ---------------------------------------------------------------------------------------------------- replay
def env_sequences(obs: np.ndarray, actions: np.ndarray, n_envs: int) -> tuple[np.ndarray, np.ndarray]:
    """The run cut into ``n_envs`` consecutive pieces of equal length: ``(T, n_envs, ...)`` per step of all envs."""
    length = len(obs) // n_envs
    cut = n_envs * length
    return (
        obs[:cut].reshape(n_envs, length, -1).swapaxes(0, 1),
        actions[:cut].reshape(n_envs, length, -1).swapaxes(0, 1),
    )


def replay(rule: MujocoShieldingRule, obs: np.ndarray, actions: np.ndarray) -> dict[str, Any]:
    """Shield each step ``(n_envs, ...)`` of ``obs``/``actions`` in one call; times, decisions and solve counts."""
    seconds, executed, intervened = [], [], []
    for step_obs, step_actions in zip(obs, actions):
        start = time.perf_counter()
        decision = rule.shield(step_obs, step_actions)
        seconds.append(time.perf_counter() - start)
        executed.append(decision.actions)
        intervened.append(decision.intervened)
    counts = rule.solve_counts
    ms_per_env_step = 1e3 * np.asarray(seconds) / obs.shape[1]
    return {
        "env_steps": counts.steps,
        "mean_ms": float(ms_per_env_step.mean()),
        "p95_ms": float(np.percentile(ms_per_env_step, 95)),
        "q_solves": counts.q_solves / counts.steps,
        "backup_solves": counts.backup_solves / counts.steps,
        "backup_value_solves": counts.backup_value_solves / counts.steps,
        "interventions": int(np.sum(intervened)),
        "executed": np.asarray(executed),
        "intervened": np.asarray(intervened),
    }


def bench_replay(
    run: dict[str, np.ndarray], task: str, envs: list[int], full_steps: int | None, threads: int
) -> list[dict[str, Any]]:
    """Certified and full rule on the recorded run, for each number of envs; decisions compared step by step."""
    rows = []
    for n_envs in envs:
        obs, actions = env_sequences(run["obs"], run["actions"], n_envs)
        certified = replay(task_rule(task, n_threads=threads), obs, actions)
        limit = len(obs) if full_steps is None else max(1, full_steps // n_envs)
        full = replay(task_rule(task, n_threads=threads, certify=False), obs[:limit], actions[:limit])
        same = np.all(certified["executed"][:limit] == full["executed"], axis=2) & (
            certified["intervened"][:limit] == full["intervened"]
        )
        for name, result in (("certified", certified), ("full", full)):
            row = {k: v for k, v in result.items() if k not in ("executed", "intervened")}
            # the full rule as the run's own reference: a machine's speed cancels out of the share
            of_full = result["mean_ms"] / full["mean_ms"]
            rows.append(
                {"rule": name, "n_envs": n_envs, **row, "of_full": of_full, "same_decisions": f"{int(same.sum())}/{same.size}"}
            )
    return rows


# ---------------------------------------------------------------------------------------------------- point, rollouts
def visited_observations(env_id: str, n: int, seed: int = 0) -> np.ndarray:
    """``n`` observations visited by random actions (a few steps after reset)."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    visited = []
    for i in range(n):
        obs, _ = env.reset(seed=seed + i)
        for _ in range(3):
            obs, *_ = env.step(env.action_space.sample())
        visited.append(obs)
    env.close()
    return np.asarray(visited, dtype=np.float64)


def best_time(fn: Any, repeats: int) -> float:
    """Best wall time of ``repeats`` calls after one warm-up call, in seconds."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def bench_point(repeats: int) -> list[dict[str, Any]]:
    """ms per env step of the Point rule, 1 and 8 envs in one call."""
    rule: ShieldingRule = PointCircleShieldingRule()
    obs = visited_observations("SafePointCircle-v0", 8)
    actions = np.random.default_rng(0).uniform(-1, 1, (8, 2))
    rows = []
    for n_envs in (1, 8):
        seconds = best_time(lambda n=n_envs: rule.shield(obs[:n], actions[:n]), repeats)
        rows.append({"rule": "point", "n_envs": n_envs, "ms_per_env_step": 1e3 * seconds / n_envs})
    return rows


def bench_rollouts(threads: int, repeats: int, sizes: tuple[int, ...]) -> list[dict[str, Any]]:
    """Rollouts per second of ``sizes`` rollouts: native on the calling thread and on ``threads`` threads, Python loop."""
    serial = HalfCheetahHeightShieldingRule(n_threads=0)
    pooled = HalfCheetahHeightShieldingRule(n_threads=threads)
    obs = visited_observations(ENV_ID, 8)
    rows = []
    for size in sizes:
        states = serial.layout.states_from_obs(serial.model, obs[np.arange(size) % len(obs)])
        controls = np.clip(0.5 * np.random.default_rng(size).standard_normal((size, serial.horizon, 6)), -1, 1)
        rows.append(time_rollouts(serial, pooled, states, controls, repeats))
    return rows


def time_rollouts(
    serial: HalfCheetahHeightShieldingRule,
    pooled: HalfCheetahHeightShieldingRule,
    states: np.ndarray,
    controls: np.ndarray,
    repeats: int,
) -> dict[str, Any]:
    """One row of :func:`bench_rollouts`: the same rollouts in Python, natively, natively on the pool."""
    data = mujoco.MjData(serial.model)
    python = best_time(lambda: rollout_heights_python(serial.model, data, states, controls), 1)
    native = best_time(lambda: serial.rollout_heights(states, controls), repeats)
    threaded = best_time(lambda: pooled.rollout_heights(states, controls), repeats)
    reference = rollout_heights_python(serial.model, data, states, controls)
    return {
        "rollouts": len(states),
        "python_ms": 1e3 * python,
        "native_ms": 1e3 * native,
        f"{pooled.n_threads}_threads_ms": 1e3 * threaded,
        "threads_speedup": native / threaded,
        "us_per_physics_step": 1e6 * native / (len(states) * (5 * controls.shape[1] + 1)),
        "heights_equal": bool(np.array_equal(pooled.rollout_heights(states, controls), reference)),
    }


def print_table(title: str, rows: list[dict[str, Any]]) -> None:
    """A fixed-width table of ``rows`` (the keys of the first row)."""
    keys = list(rows[0])
    print(f"\n{title}")
    print("  ".join(f"{k:>19}" for k in keys))
    for row in rows:
        print("  ".join(f"{row[k]:>19.3f}" if isinstance(row[k], float) else f"{row[k]!s:>19}" for k in keys))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default=ENV_ID, help="a MuJoCo task with a registered MujocoShieldingRule")
    parser.add_argument("--algo", choices=sorted(HYPERPARAMS), default="sppo", help="the recorded training run")
    parser.add_argument("--steps", type=int, default=3000, help="env steps of the recorded run")
    parser.add_argument("--seed", type=int, default=0, help="seed of the recorded run")
    parser.add_argument("--states", type=Path, default=None, help="recorded run (default: results/bench_shield/...)")
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 8], help="envs per shield call in the replay")
    parser.add_argument("--full-steps", type=int, default=None, help="replay only this many env steps with the full rule")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)), help="rollout threads")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats of the point and rollout figures")
    parser.add_argument("--skip", nargs="*", default=[], choices=["replay", "point", "rollouts"], help="parts to skip")
    parser.add_argument("--quick", action="store_true", help="a 400-step recording and 200 full-rule steps")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures to this file")
    args = parser.parse_args()
    if args.quick:
        args.steps, args.full_steps, args.repeats = 400, args.full_steps or 200, 1
    name = f"{args.algo}_{args.steps}_seed{args.seed}.npz"
    if args.task != ENV_ID:
        name = f"{args.task.replace('/', '-')}_{name}"
    states = args.states or ROOT / "results" / "bench_shield" / name

    figures: dict[str, Any] = {"threads": args.threads}
    if "replay" not in args.skip:
        run = load_or_record(states, args.algo, args.task, args.steps, args.seed)
        print(
            f"{len(run['obs'])} steps of a shielded {args.algo} run on {args.task} ({states}): "
            f"{int(run['violations'])} violations, {int(run['interventions'])} interventions"
        )
        figures["replay"] = bench_replay(run, args.task, args.envs, args.full_steps, args.threads)
        print_table(f"{args.task}'s rule on the run's states (rollout threads = {args.threads})", figures["replay"])
    if "point" not in args.skip:
        figures["point"] = bench_point(args.repeats)
        print_table("Point rule on visited states", figures["point"])
    if "rollouts" not in args.skip:
        figures["rollouts"] = bench_rollouts(args.threads, args.repeats, (1, 65, 8 * 65))
        print_table(f"Half-Cheetah native rollouts ({5 * 15 + 1} physics steps each)", figures["rollouts"])
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
