"""Choose SPPO's absorbing-MDP defaults by measurement on SafePointCircle-v0 (SAILR at the same steps and seeds).

Each run trains one variant for ``--steps`` env steps (the hyperparameters of ``hyperparams/sppo.yml`` or
``hyperparams/sailr.yml`` for the task) and writes ``<out>/<variant>/seed_<n>.json``: training violations,
interventions, the intervention rate over the last ``--window`` steps, the mean return of the last 10 training
episodes, and the deterministic policy's return and violations deployed with and without the shield. Finished runs
are skipped (resume by running the same command again); ``--summary`` prints the table: means over seeds with their
95% percentile-bootstrap intervals (``sppo_lab.stats``, as the grid's tables).

    python scripts/bench_absorbing.py --steps 30000 --seeds 0 1 2 3 4 --variants head-restart tdmpc-restart sailr
    python scripts/bench_absorbing.py --summary
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

import sppo_sb3  # noqa: F401  (registers the task)
from sppo_lab import stats, tables
from sppo_lab.configs import RUNS_DIR
from sppo_sb3 import SAILR, SPPO
from sppo_sb3.algorithms import HYPERPARAMS_DIR
from sppo_sb3.common.keys import COST_KEY, INTERVENED_KEY
from sppo_sb3.shield.evaluation import evaluate_deployment
from sppo_sb3.zoo import constructor_kwargs

ENV_ID = "SafePointCircle-v0"
VARIANTS: dict[str, dict[str, Any]] = {
    "head-restart": dict(on_intervention="restart", termination_model=True),
    "head-terminate": dict(on_intervention="terminate", termination_model=True),
    "tdmpc-restart": dict(on_intervention="restart", termination_model=False),
    "tdmpc-terminate": dict(on_intervention="terminate", termination_model=False),
    "head-restart-R10": dict(on_intervention="restart", termination_model=True, penalty=10.0),
    "tdmpc-restart-R10": dict(on_intervention="restart", termination_model=False, penalty=10.0),
    "sailr": {},
}


class StepRecorder(BaseCallback):
    """Per-step training counts: violations and interventions (with their step), episode returns."""

    def __init__(self) -> None:
        super().__init__()
        self.intervention_steps: list[int] = []
        self.violations = 0
        self.episode_returns: list[float] = []

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            self.violations += int(float(info.get(COST_KEY, 0.0)) > 0)
            if info.get(INTERVENED_KEY, False):
                self.intervention_steps.append(self.num_timesteps)
            if "episode" in info:
                self.episode_returns.append(float(info["episode"]["r"]))
        return True


def zoo_kwargs(algo: str) -> dict[str, Any]:
    """The task's hyperparameters from ``hyperparams/<algo>.yml`` as constructor arguments (the package's loader)."""
    kwargs = constructor_kwargs(HYPERPARAMS_DIR / f"{algo}.yml", ENV_ID)
    kwargs.pop("policy", None)
    return kwargs


def run(variant: str, seed: int, steps: int, window: int, eval_episodes: int) -> dict[str, Any]:
    """Train one variant and measure it."""
    if variant == "sailr":
        model: Any = SAILR("MlpPolicy", ENV_ID, seed=seed, **zoo_kwargs("sailr"))
    else:
        model = SPPO("TOLDPolicy", ENV_ID, seed=seed, **{**zoo_kwargs("sppo"), **VARIANTS[variant]})
    recorder = StepRecorder()
    start = time.perf_counter()
    model.learn(steps, callback=recorder)
    seconds = time.perf_counter() - start
    window_start = steps - window
    in_window = sum(step > window_start for step in recorder.intervention_steps)
    result: dict[str, Any] = {
        "variant": variant,
        "seed": seed,
        "steps": steps,
        "train_seconds": seconds,
        "violations": recorder.violations,
        "interventions": len(recorder.intervention_steps),
        "intervention_rate_window": 100.0 * in_window / window,
        "last10_return": float(np.mean(recorder.episode_returns[-10:])) if recorder.episode_returns else float("nan"),
        "episodes": len(recorder.episode_returns),
    }
    for shielded, prefix in ((True, "eval"), (False, "eval_unshielded")):
        metrics = evaluate_deployment(model, lambda: gym.make(ENV_ID), eval_episodes, shielded=shielded, seed=10_000 + seed)
        result.update({f"{prefix}/{key}": value for key, value in metrics.items()})
    return result


INTERVAL_HEADER = (
    f"`mean [low, high]`: mean over seeds and its {stats.CONFIDENCE:.0%} percentile-bootstrap confidence interval over "
    f"seeds ({stats.BOOTSTRAP_REPS} resamples, sppo_lab.stats); the mean alone for one seed."
)


COLUMNS = {
    "seeds": None,
    "return (last 10 ep.)": "last10_return",
    "violations": "violations",
    "interventions": "interventions",
    "intervention rate, last window (%)": "intervention_rate_window",
    "eval return": "eval/mean_reward",
    "eval violations / ep.": "eval/mean_violations",
    "unshielded eval return": "eval_unshielded/mean_reward",
    "unshielded violations / ep.": "eval_unshielded/mean_violations",
    "unshielded safe episodes (%)": "eval_unshielded/safe_episode_rate",
    "train minutes": "train_seconds",
}


def summary(out: Path) -> str:
    """:data:`INTERVAL_HEADER`, then a markdown table, one row per variant: the seeds that finished."""
    lines = [INTERVAL_HEADER, "", "| variant | " + " | ".join(COLUMNS) + " |", "|---" * (len(COLUMNS) + 1) + "|"]
    for variant_dir in sorted(p for p in out.iterdir() if p.is_dir()):
        results = [json.loads(f.read_text()) for f in sorted(variant_dir.glob("seed_*.json"))]
        if not results:
            continue
        cells = []
        for key in COLUMNS.values():
            if key is None:
                cells.append(str(len(results)))
            else:
                scale = 1 / 60 if key == "train_seconds" else 1.0
                cells.append(tables.values_cell([scale * r[key] for r in results]))
        lines.append(f"| {variant_dir.name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", nargs="+", default=["head-restart", "tdmpc-restart", "sailr"], choices=VARIANTS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--steps", type=int, default=30_000)
    parser.add_argument("--window", type=int, default=5_000, help="the intervention rate is measured over the last steps")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RUNS_DIR / "absorbing")
    parser.add_argument("--summary", action="store_true", help="print the table of the finished runs and exit")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per process (run two processes on 2 cores)")
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    if args.summary:
        print(summary(args.out))
        return
    for seed in args.seeds:
        for variant in args.variants:
            path = args.out / variant / f"seed_{seed}.json"
            if path.exists():
                continue
            result = run(variant, seed, args.steps, args.window, args.eval_episodes)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(result, indent=1))
            print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
