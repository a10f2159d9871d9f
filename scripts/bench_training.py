"""Training throughput: env steps per second of SPPO against SB3's SAC on the same env, in the same run (SPEC §7).

Both learn ``--steps`` env steps from the same number of warm-up steps (SPPO's ``learning_starts`` of its yml entry),
one gradient step per env step, on the same device and threads. SPPO plans with MPPI at every step and updates its
TOLD model with TOPO; SAC samples its policy and updates an actor and twin critics. The ratio says what SPPO's
sample efficiency costs in wall-clock time. Throughput is measured after the warm-up, when both are updating.

    python scripts/bench_training.py                                  # Pendulum-v1 and SafePointCircle-v0
    python scripts/bench_training.py --envs Pendulum-v1 --steps 2000  # a quick look
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import torch as th
import yaml
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from sppo_sb3 import SPPO
from sppo_sb3.zoo import eval_kwargs_strings, eval_yml_string

HYPERPARAMS = Path(__file__).resolve().parents[1] / "hyperparams" / "sppo.yml"


class UpdatePhaseTimer(BaseCallback):
    """Wall-clock time and env steps from the first step after ``learning_starts`` to the end of ``learn``."""

    def __init__(self, learning_starts: int) -> None:
        super().__init__()
        self.learning_starts = learning_starts
        self.start_time: float | None = None
        self.start_steps = 0

    def _on_step(self) -> bool:
        if self.start_time is None and self.num_timesteps > self.learning_starts:
            self.start_time, self.start_steps = time.perf_counter(), self.num_timesteps
        return True

    def steps_per_second(self) -> float:
        if self.start_time is None:
            raise ValueError("learn() ended before learning started: raise --steps above learning_starts")
        return (self.num_timesteps - self.start_steps) / (time.perf_counter() - self.start_time)


def sppo_kwargs(env_id: str) -> dict[str, Any]:
    """SPPO's hyperparameters for ``env_id`` from ``hyperparams/sppo.yml`` (without the zoo-only keys)."""
    entries = yaml.safe_load(HYPERPARAMS.read_text())
    if env_id not in entries:
        raise SystemExit(f"{HYPERPARAMS} has no entry for {env_id} (it has: {', '.join(entries)})")
    kwargs = eval_kwargs_strings(dict(entries[env_id]))
    if isinstance(kwargs.get("policy_kwargs"), str):  # rl-zoo3 evaluates this one itself
        kwargs["policy_kwargs"] = eval_yml_string(kwargs["policy_kwargs"])
    for key in ("n_timesteps", "policy", "n_envs", "normalize"):
        kwargs.pop(key, None)
    return kwargs


def steps_per_second(model: BaseAlgorithm, steps: int, learning_starts: int) -> float:
    timer = UpdatePhaseTimer(learning_starts)
    model.learn(steps, callback=timer)
    return timer.steps_per_second()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=["Pendulum-v1", "SafePointCircle-v0"])
    parser.add_argument("--steps", type=int, default=3000, help="env steps per algorithm (default: 3000)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: all cores)")
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    if args.threads:
        th.set_num_threads(args.threads)
    print(f"torch {th.__version__}, {th.get_num_threads()} CPU threads, {args.steps} env steps per run")
    print(f"{'env':22} {'SAC steps/s':>12} {'SPPO steps/s':>13} {'SPPO / SAC':>11}")
    for env_id in args.envs:
        kwargs = sppo_kwargs(env_id)
        starts = int(kwargs.get("learning_starts", 5000))
        sppo = SPPO("TOLDPolicy", env_id, seed=0, device=args.device, **kwargs)
        sac = SAC("MlpPolicy", env_id, seed=0, device=args.device, learning_starts=starts)
        sac_sps = steps_per_second(sac, args.steps, starts)
        sppo_sps = steps_per_second(sppo, args.steps, starts)
        print(f"{env_id:22} {sac_sps:12.1f} {sppo_sps:13.1f} {sppo_sps / sac_sps:10.2f}x")


if __name__ == "__main__":
    main()
