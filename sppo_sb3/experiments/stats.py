"""Statistics over a grid's runs: curves on a common step grid, and per-(task, algorithm) aggregates over seeds."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sppo_sb3.experiments import layout
from sppo_sb3.experiments.display import algo_sort_key

#: the ``summary.json`` figures aggregated as mean and std over seeds
AGGREGATED_KEYS: tuple[str, ...] = (
    "cumulative_violations",
    "safety_rate",
    "return_last_n",
    "episodes",
    "steps",
    "steps_per_s",
    "train_steps_per_s",
    "eval_return",
    "eval_violations",
    "eval_safe_rate",
    "eval_unshielded_return",
    "eval_unshielded_violations",
    "eval_unshielded_safe_rate",
)


def load_results(root: Path) -> tuple[pd.DataFrame, dict[tuple[str, str], list[pd.DataFrame]]]:
    """The finished runs under a grid's output folder (:mod:`sppo_sb3.experiments.layout`).

    :param root: the benchmark's output folder.
    :return: one row of ``summary.json`` per run, and the runs' curves by ``(task, algo)`` (seed order).
    """
    rows: list[dict[str, Any]] = []
    curves: dict[tuple[str, str], list[pd.DataFrame]] = {}
    for run_dir in layout.finished_run_dirs(root):
        summary = layout.read_summary(run_dir)
        rows.append(summary)
        curves.setdefault((summary["task"], summary["algo"]), []).append(layout.read_curve(run_dir))
    return pd.DataFrame(rows), curves


def order_of_magnitude(violations: float) -> str:
    """The paper's notation for cumulative violations: ``0``, ``10 ↓`` (1–9), ``10^k ↑`` (at least ``10^k``).

    :param violations: a (mean) number of cumulative violations.
    """
    if not np.isfinite(violations):
        return "–"
    if violations < 0.5:
        return "0"
    if violations < 10:
        return "10 ↓"
    k = math.floor(math.log10(violations))
    return "10 ↑" if k == 1 else f"10^{k} ↑"


def curve_band(curves: Sequence[pd.DataFrame], column: str, points: int = 100, smooth: int = 1) -> pd.DataFrame:
    """Mean and std over seeds of ``column`` vs env steps, on a common grid of ``points`` steps.

    Each seed's column (a rolling mean over ``smooth`` episodes) is interpolated linearly between its episode ends,
    on the range of env steps that all seeds cover (their episodes end at different steps); when the seeds' ranges do
    not overlap, on their union, where a seed outside its range is left out of the mean.

    :param curves: the seeds' ``curve.csv`` frames (``timesteps`` and ``column``).
    :param column: e.g. ``return`` or ``cumulative_violations``.
    :param points: grid size.
    :param smooth: episodes in the rolling mean (1: raw).
    :return: columns ``timesteps``, ``mean``, ``std``, ``n`` (seeds at that step).
    """
    usable = [c for c in curves if not c.empty and column in c]
    if not usable:
        return pd.DataFrame(columns=["timesteps", "mean", "std", "n"])
    # the env steps that every seed covers (episodes end at different steps), else (no overlap) all of them
    start = max(float(c["timesteps"].iloc[0]) for c in usable)
    stop = min(float(c["timesteps"].iloc[-1]) for c in usable)
    if stop < start:
        start = min(float(c["timesteps"].iloc[0]) for c in usable)
        stop = max(float(c["timesteps"].iloc[-1]) for c in usable)
    grid = np.linspace(start, stop, points) if stop > start else np.array([stop])
    values = np.full((len(usable), grid.size), np.nan)
    for i, curve in enumerate(usable):
        x = curve["timesteps"].to_numpy(dtype=float)
        y = curve[column].rolling(max(1, smooth), min_periods=1).mean().to_numpy(dtype=float)
        inside = (grid >= x[0]) & (grid <= x[-1])
        values[i, inside] = np.interp(grid[inside], x, y)
    n = np.sum(~np.isnan(values), axis=0)
    with warnings.catch_warnings():  # grid points that no seed reached: "mean of empty slice"
        warnings.simplefilter("ignore", category=RuntimeWarning)
        mean = np.nanmean(values, axis=0)
        std = np.nanstd(values, axis=0)
    return pd.DataFrame({"timesteps": grid, "mean": mean, "std": std, "n": n})


def _mean_std(values: pd.Series) -> tuple[float, float]:
    values = values.astype(float)
    return float(values.mean()), float(values.std(ddof=0)) if len(values) > 1 else 0.0


def aggregate(summaries: pd.DataFrame) -> pd.DataFrame:
    """Per ``(task, algo)``: seeds, env steps, episodes, violations, safety rate and return (mean ± std over seeds).

    :param summaries: the runs' ``summary.json`` rows.
    """
    rows = []
    for (task, algo), group in summaries.groupby(["task", "algo"], sort=False):
        row: dict[str, Any] = {"task": task, "algo": algo, "seeds": len(group)}
        for key in AGGREGATED_KEYS:
            if key in group:
                row[f"{key}_mean"], row[f"{key}_std"] = _mean_std(group[key])
        if "cumulative_interventions" in group and group["cumulative_interventions"].notna().any():
            row["cumulative_interventions_mean"] = float(group["cumulative_interventions"].astype(float).mean())
        else:
            row["cumulative_interventions_mean"] = float("nan")
        if "wall_clock_s" in group:
            row["wall_clock_s_sum"] = float(group["wall_clock_s"].sum())
        rows.append(row)
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    table["_order"] = [algo_sort_key(a) for a in table["algo"]]
    return table.sort_values(["task", "_order"]).drop(columns="_order").reset_index(drop=True)
