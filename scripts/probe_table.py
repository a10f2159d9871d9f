"""The probe table: episode length and reward per step per block of env steps, for finished benchmark runs.

Reads every ``<out>/<task>/<algo>-<variant>/seed_<s>/`` with a ``DONE`` marker (the layout of ``scripts/benchmark.py``)
and prints one markdown row per run: the mean episode length and the reward per env step of the episodes that
*ended* in each block, the last-10 return, the cost paid while learning, the shield's interventions and env steps/s.
A learner that stalls shows as flat blocks; one that falls early shows as short episodes.

    python scripts/probe_table.py results/velocity_probe --block 5000
    python scripts/probe_table.py lab/runs/velocity --block 20000 --runs sppo sppo-previous   # two grid rows
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from sppo_lab import layout


def block_means(curve: pd.DataFrame, block: int, steps: int) -> tuple[list[float], list[float]]:
    """Mean episode length and total reward / total length of the episodes ending in each ``block`` of steps."""
    lengths, per_step = [], []
    for start in range(0, steps, block):
        episodes = curve[(curve.timesteps > start) & (curve.timesteps <= start + block)]
        lengths.append(float(episodes.length.mean()) if len(episodes) else float("nan"))
        per_step.append(float(episodes["return"].sum() / episodes.length.sum()) if len(episodes) else float("nan"))
    return lengths, per_step


def run_row(run: Path, block: int) -> dict[str, object]:
    """One row of the table from a finished run's ``curve.csv`` and ``summary.json``."""
    summary = layout.read_summary(run)
    lengths, per_step = block_means(layout.read_curve(run), block, int(summary["steps"]))
    return {
        "task": summary["task"].split("/")[-1].removeprefix("Safety").removesuffix("Velocity-v1"),
        "run": run.parent.name,  # <algo>[-<variant>]: a folder renamed after its run (sppo-previous) says so
        "seed": summary["seed"],
        "ep. length per block": ", ".join(f"{x:.0f}" for x in lengths),
        "reward / step per block": ", ".join(f"{x:.2f}" for x in per_step),
        "return (last 10)": f"{summary['return_last_n']:.1f}",
        "deployed, shielded / alone": " / ".join(
            f"{summary[key]:.0f}" if summary.get(key) is not None else "–" for key in ("eval_return", "eval_unshielded_return")
        ),
        "violations": f"{summary['cumulative_violations']}",
        "interventions": f"{summary.get('cumulative_interventions', '–')}",
        "steps/s": f"{summary['steps_per_s']:.0f}",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, nargs="+", help="benchmark output folders (searched for DONE runs)")
    parser.add_argument("--block", type=int, default=5000, help="env steps per block (default: 5000)")
    parser.add_argument("--runs", nargs="+", default=None, help="only these <algo>[-<variant>] folders (default: all)")
    args = parser.parse_args()
    runs = sorted(
        run for out in args.out for run in layout.finished_run_dirs(out) if args.runs is None or run.parent.name in args.runs
    )
    if not runs:
        raise SystemExit(f"no finished runs under {', '.join(map(str, args.out))} (the layout of sppo_lab.layout)")
    rows = [run_row(run, args.block) for run in runs]
    print("| " + " | ".join(rows[0]) + " |")
    print("|" + "---|" * len(rows[0]))
    for row in rows:
        print("| " + " | ".join(str(value) for value in row.values()) + " |")


if __name__ == "__main__":
    main()
