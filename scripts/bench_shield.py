"""Shield benchmark: the shield's overhead per env step on both tasks, and the Cheetah MPC's native rollouts.

Runs, in one process:

- ``overhead``: wall time of one ``rule.shield(obs, actions)`` call (eq. 12: ``ζ(s)``, then ``Q̄(s, a)`` and
  ``Q̄(s, ζ(s))``) on real observations, for the Point rule and the Half-Cheetah MPC rule (``cheetah-mpc``: the
  certified rule; ``cheetah-full``: ``certify=False``, every quantity solved), single env (``B = 1``) and batched
  over ``n_envs`` (one call for all envs), reported per call and per env step, next to the env's own step;
- ``rollouts``: one MPPI solve's worth of particle rollouts of the Cheetah rule (``B · 64`` rollouts of ``5·15 + 1``
  physics steps), natively with :mod:`mujoco.rollout` (calling thread, and a thread pool) against a plain Python
  ``mj_step`` loop doing the same work; the heights of both are checked equal.

    python scripts/bench_shield.py              # n_envs 8, 5 repeats
    python scripts/bench_shield.py --quick      # 1 repeat, fewer rollouts
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable

import gymnasium as gym
import mujoco
import numpy as np

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.shield.base import ShieldingRule
from sppo_sb3.shield.cheetah import HalfCheetahHeightShieldingRule, rollout_heights_python, states_from_obs
from sppo_sb3.shield.point import PointCircleShieldingRule


def timed(fn: Callable[[], object], repeats: int) -> float:
    """Best wall time of ``repeats`` calls after one warm-up call, in seconds."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def sample_observations(env_id: str, n: int, seed: int = 0) -> tuple[np.ndarray, float]:
    """``n`` observations visited by random actions (a few steps after reset), and the env's seconds per step."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    obs_list, steps, start = [], 0, time.perf_counter()
    for i in range(n):
        obs, _ = env.reset(seed=seed + i)
        for _ in range(3):
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            steps += 1
            if terminated or truncated:
                obs, _ = env.reset()
        obs_list.append(obs)
    per_step = (time.perf_counter() - start) / steps
    env.close()
    return np.asarray(obs_list, dtype=np.float64), per_step


def bench_overhead(name: str, env_id: str, rule: ShieldingRule, n_envs: int, repeats: int) -> list[dict[str, object]]:
    """ms per ``shield`` call and per env step, for ``B = 1`` and ``B = n_envs``."""
    obs, env_step = sample_observations(env_id, n_envs)
    actions = np.random.default_rng(0).uniform(-1, 1, (n_envs, 2 if "Point" in env_id else 6))
    rows = []
    for batch in sorted({1, n_envs}):
        seconds = timed(lambda b=batch: rule.shield(obs[:b], actions[:b]), repeats)
        rows.append(
            dict(
                task=name,
                n_envs=batch,
                ms_per_call=1e3 * seconds,
                ms_per_env_step=1e3 * seconds / batch,
                env_ms_per_step=1e3 * env_step,
            )
        )
    return rows


def bench_rollouts(n_envs: int, repeats: int, threads: int) -> dict[str, float]:
    """Rollouts per second of one MPPI solve's particle rollouts: native (0 and ``threads`` threads) vs Python."""
    rule = HalfCheetahHeightShieldingRule(seed=0, n_threads=0)
    pooled = HalfCheetahHeightShieldingRule(seed=0, n_threads=threads)
    obs, _ = sample_observations("SafeHalfCheetahHeight-v1", n_envs)
    n = n_envs * rule.n_particles
    states = np.repeat(states_from_obs(rule.model, obs), rule.n_particles, axis=0)
    controls = np.clip(0.5 * np.random.default_rng(0).standard_normal((n, rule.horizon, rule.model.nu)), -1, 1)
    data = mujoco.MjData(rule.model)
    python = timed(lambda: rollout_heights_python(rule.model, data, states, controls), max(1, repeats // 2))
    native = timed(lambda: rule.rollout_heights(states, controls), repeats)
    threaded = timed(lambda: pooled.rollout_heights(states, controls), repeats)
    diff = np.abs(pooled.rollout_heights(states, controls) - rollout_heights_python(rule.model, data, states, controls)).max()
    physics_steps = rule.horizon * 5 + 1
    return dict(
        rollouts=n,
        physics_steps_per_rollout=physics_steps,
        python_rollouts_per_s=n / python,
        native_rollouts_per_s=n / native,
        native_threads=threads,
        native_threaded_rollouts_per_s=n / threaded,
        ratio_native_vs_python=python / native,
        ratio_threaded_vs_python=python / threaded,
        us_per_physics_step_python=1e6 * python / (n * physics_steps),
        us_per_physics_step_native=1e6 * native / (n * physics_steps),
        max_abs_height_diff=float(diff),
    )


def print_table(rows: list[dict[str, object]], keys: list[str]) -> None:
    """A small fixed-width table of ``keys`` for each row."""
    print("  ".join(f"{k:>16}" for k in keys))
    for row in rows:
        cells = [f"{row[k]:>16.3f}" if isinstance(row[k], float) else f"{row[k]!s:>16}" for k in keys]
        print("  ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n-envs", type=int, default=8, help="batch size of the batched measurements")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats (best is reported)")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)), help="rollout threads")
    parser.add_argument("--quick", action="store_true", help="1 repeat and a batch of 2 for the rollout comparison")
    parser.add_argument("--json", type=str, default=None, help="also write the figures to this file")
    args = parser.parse_args()
    repeats = 1 if args.quick else args.repeats

    cheetah = HalfCheetahHeightShieldingRule(seed=0, n_threads=args.threads)
    overhead = bench_overhead("point", "SafePointCircle-v0", PointCircleShieldingRule(), args.n_envs, repeats)
    overhead += bench_overhead("cheetah-mpc", "SafeHalfCheetahHeight-v1", cheetah, args.n_envs, repeats)
    shared = HalfCheetahHeightShieldingRule(seed=0, n_threads=args.threads, certify=False)
    overhead += bench_overhead("cheetah-full", "SafeHalfCheetahHeight-v1", shared, args.n_envs, repeats)
    print(f"Shield overhead (rule.shield on real observations; cheetah rollout threads = {args.threads})")
    print_table(overhead, ["task", "n_envs", "ms_per_call", "ms_per_env_step", "env_ms_per_step"])

    rollouts = bench_rollouts(2 if args.quick else args.n_envs, repeats, args.threads)
    print(
        f"\nCheetah MPC particle rollouts ({rollouts['rollouts']} rollouts x {rollouts['physics_steps_per_rollout']} "
        f"physics steps; heights equal to {rollouts['max_abs_height_diff']:.1e})"
    )
    print_table(
        [
            dict(impl="python mj_step", rollouts_per_s=rollouts["python_rollouts_per_s"], vs_python=1.0),
            dict(
                impl="rollout 0 thr",
                rollouts_per_s=rollouts["native_rollouts_per_s"],
                vs_python=rollouts["ratio_native_vs_python"],
            ),
            dict(
                impl=f"rollout {args.threads} thr",
                rollouts_per_s=rollouts["native_threaded_rollouts_per_s"],
                vs_python=rollouts["ratio_threaded_vs_python"],
            ),
        ],
        ["impl", "rollouts_per_s", "vs_python"],
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"overhead": overhead, "rollouts": rollouts}, f, indent=2)


if __name__ == "__main__":
    main()
