"""A grid in core-hours, from the throughput that a benchmark's finished runs measured: the paper-scale grid, or
the grid a preset names (``--velocity``), with what is left of it.

Each run of the grid is costed as its measured fixed cost (start-up, saving, the final deployment
evaluations) plus the grid's env steps times its measured seconds per env step (the monitor's training clock,
:func:`~sppo_lab.summary.summarize`'s ``train_steps_per_s``). One core per run: the benchmark runs every
train command with one thread (``--num-threads 1``, ``OMP_NUM_THREADS=1``) on the CPU.
"""

from __future__ import annotations

import heapq
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from sppo_lab import layout
from sppo_lab.display import algo_sort_key, display_name, task_title
from sppo_lab.grid import OUR_ALGOS

#: the paper's seeds per task: Point Robot (Table I) 8, Half-Cheetah (Table II) 5
PAPER_SEEDS: dict[str, range] = {"SafePointCircle-v0": range(8), "SafeHalfCheetahHeight-v1": range(5)}
#: the paper's env steps per run
PAPER_STEPS = 1_000_000
#: the paper's algorithms
PAPER_ALGOS: tuple[str, ...] = OUR_ALGOS


def load_summaries(root: Path) -> pd.DataFrame:
    """The ``summary.json`` rows of the finished runs under a benchmark's output folder.

    :param root: the benchmark's output folder.
    """
    return pd.DataFrame([layout.read_summary(run_dir) for run_dir in layout.finished_run_dirs(root)])


def run_costs(summary: pd.Series) -> tuple[float, float]:
    """A run's measured seconds per env step and fixed seconds (its wall clock less its training time).

    Without a training clock (no finished episode), the whole command's rate and no fixed cost.

    :param summary: the run's ``summary.json`` row.
    :return: seconds per env step, fixed seconds.
    """
    steps, wall_s = float(summary["steps"]), float(summary["wall_clock_s"])
    train_rate = float(summary.get("train_steps_per_s", float("nan")))
    if not np.isfinite(train_rate) or train_rate <= 0:
        return wall_s / steps, 0.0
    return 1.0 / train_rate, max(0.0, wall_s - steps / train_rate)


def measured_throughput(summaries: pd.DataFrame) -> pd.DataFrame:
    """Per ``(task, algo)``: the runs measured and their costs.

    :param summaries: the runs' ``summary.json`` rows (``steps``, ``wall_clock_s``, ``train_steps_per_s``).
    :return: columns ``task``, ``algo``, ``seeds`` and ``steps`` (the runs', as text), ``s_per_step`` (all the runs'
        training time over all their steps), ``fixed_s`` (median over the runs).
    """
    rows = []
    for (task, algo), group in summaries.groupby(["task", "algo"], sort=False):
        costs = np.array([run_costs(summary) for _, summary in group.iterrows()])
        steps = group["steps"].astype(float).to_numpy()
        rows.append(
            {
                "task": task,
                "algo": algo,
                "seeds": ", ".join(str(seed) for seed in sorted(group["seed"])),
                "steps": _span(steps),
                "s_per_step": float(np.sum(costs[:, 0] * steps) / np.sum(steps)),
                "fixed_s": float(np.median(costs[:, 1])),
            }
        )
    return pd.DataFrame(rows, columns=["task", "algo", "seeds", "steps", "s_per_step", "fixed_s"])


def _span(steps: np.ndarray) -> str:
    """``8192`` or ``2048–8192``."""
    low, high = int(steps.min()), int(steps.max())
    return str(low) if low == high else f"{low}–{high}"


def grid_plan(
    throughput: pd.DataFrame,
    seeds_per_task: Mapping[str, Sequence[int]] | None = None,
    algos: Sequence[str] = PAPER_ALGOS,
    steps: int = PAPER_STEPS,
    finished: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """The grid's cost per ``(task, algo)``: seconds of one run, core-hours of all its seeds and of the runs left
    (NaN: not measured).

    :param throughput: :func:`measured_throughput`'s output.
    :param seeds_per_task: the grid's tasks, in table order, and their seeds (default: the paper's, :data:`PAPER_SEEDS`).
        A finished run counts as done only for a seed listed here.
    :param algos: the grid's algorithms.
    :param steps: env steps per run.
    :param finished: ``summary.json`` rows of finished runs: those of ``steps`` env steps or more are done (``None``: none).
    :return: :func:`measured_throughput`'s columns (NaN where not measured), ``grid_seeds``, ``left`` (runs not yet
        finished), ``run_s``, ``core_hours`` and ``left_core_hours``.
    """
    seeds: Mapping[str, Sequence[int]] = PAPER_SEEDS if seeds_per_task is None else seeds_per_task
    pairs = [(task, algo) for task in seeds for algo in sorted(algos, key=algo_sort_key)]
    plan = pd.DataFrame(pairs, columns=["task", "algo"]).merge(throughput, on=["task", "algo"], how="left")
    plan["grid_seeds"] = [len(seeds[task]) for task in plan["task"]]
    done = set() if finished is None or finished.empty else finished_runs(finished, steps)
    plan["left"] = [sum((t, a, seed) not in done for seed in seeds[t]) for t, a in zip(plan["task"], plan["algo"])]
    plan["run_s"] = plan["fixed_s"] + steps * plan["s_per_step"]
    plan["core_hours"] = plan["grid_seeds"] * plan["run_s"] / 3600.0
    plan["left_core_hours"] = plan["left"] * plan["run_s"] / 3600.0
    return plan


def finished_runs(summaries: pd.DataFrame, steps: int) -> set[tuple[str, str, int]]:
    """The ``(task, algo, seed)`` of the finished runs of at least ``steps`` env steps (an on-policy run ends with its
    last full rollout)."""
    at_budget = summaries[summaries["steps"].astype(int) >= steps]
    return {(task, algo, int(seed)) for task, algo, seed in zip(at_budget["task"], at_budget["algo"], at_budget["seed"])}


def makespan_s(durations: Sequence[float] | np.ndarray, workers: int) -> float:
    """Wall-clock seconds of runs of these durations on ``workers`` cores, each next-longest run on the first free core.

    :param durations: seconds of each run.
    :param workers: cores, one run each at a time.
    """
    loads = [0.0] * max(1, workers)
    for duration in sorted(durations, reverse=True):
        heapq.heappush(loads, heapq.heappop(loads) + duration)
    return max(loads)


def plan_markdown(plan: pd.DataFrame, workers: int, steps: int = PAPER_STEPS) -> str:
    """The plan as a markdown table with totals, and its wall clock on ``workers`` cores.

    :param plan: :func:`grid_plan`'s output.
    :param workers: cores available (one run each at a time).
    :param steps: env steps per run (as in :func:`grid_plan`).
    """
    measured = plan[np.isfinite(plan["core_hours"])]
    seeds = plan.groupby("task", sort=False)["grid_seeds"].first()
    tasks = "; ".join(f"{task_title(str(task))} {n} seeds" for task, n in seeds.items())
    lines = [
        "<!-- written by scripts/benchmark.py --plan -->",
        f"Grid: {plan['algo'].nunique()} algorithms, {steps:,} env steps per run; {tasks}.",
        "One CPU core per run (the benchmark trains with one thread). A run costs its measured fixed seconds (start-up,",
        "saving, final evaluation) plus its env steps times the measured seconds per env step (training clock). The",
        "measured runs are short: an algorithm whose updates start later (`learning_starts`) or slow down as it trains",
        "is underestimated. A finished run of the grid's env steps (or more) is done, and not counted as left.",
        "",
        "| Task | Method | Measured on seeds | Steps per measured run | ms / env step | Fixed s / run | Seeds | Core-hours "
        "| Runs left | Core-hours left |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, row in plan.iterrows():
        cells = [task_title(str(row["task"])), display_name(str(row["algo"]))]
        if np.isfinite(row["core_hours"]):
            cells += [row["seeds"], row["steps"], f"{1000 * row['s_per_step']:.3g}", f"{row['fixed_s']:.0f}"]
            cells += [str(row["grid_seeds"]), f"{row['core_hours']:,.1f}", str(row["left"]), f"{row['left_core_hours']:,.1f}"]
        else:
            cells += ["not measured", "–", "–", "–", str(row["grid_seeds"]), "–", str(row["left"]), "–"]
        lines.append("| " + " | ".join(cells) + " |")
    runs, left = int(measured["grid_seeds"].sum()), int(measured["left"].sum())
    total, total_left = float(measured["core_hours"].sum()), float(measured["left_core_hours"].sum())
    lines += [f"| **Total** | | | | | | {runs} runs | **{total:,.1f}** | {left} runs | **{total_left:,.1f}** |", ""]
    durations = np.repeat(measured["run_s"].to_numpy(dtype=float), measured["left"].to_numpy(dtype=int))
    if durations.size:
        wall_h = makespan_s(durations, workers) / 3600.0
        lines.append(
            f"Wall clock of the runs left on {workers} cores: {wall_h:,.1f} h ({wall_h / 24:.1f} days), each next-longest "
            f"run on the first free core; the longest run alone takes {durations.max() / 3600.0:,.1f} h."
        )
    missing = plan[~np.isfinite(plan["core_hours"])]
    if not missing.empty:
        names = ", ".join(f"{display_name(str(r['algo']))} on {r['task']}" for _, r in missing.iterrows())
        lines.append(f"Not measured, left out of the totals: {names}.")
    return "\n".join(lines) + "\n"
