"""The comparison's figures (Figs. 5–7 of the paper): curves over env steps and violation bars, one panel per task.

Means over seeds are drawn with their 95% bootstrap confidence intervals
(:func:`~sppo_lab.stats.curve_band`, :func:`~sppo_lab.stats.seed_intervals`). Needs matplotlib
and scipy (``pip install "sppo_sb3[plots]"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sppo_lab.display import algo_color, algo_sort_key, display_name, env_steps_per_step, task_title
from sppo_lab.stats import curve_band, seed_intervals

#: what the bands and error bars show
INTERVAL_NOTE = "mean, 95% bootstrap CI"


def _pyplot() -> Any:
    try:
        import matplotlib
    except ImportError as exc:
        raise SystemExit('plot_results.py needs matplotlib: pip install "sppo_sb3[plots]"') from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: most panels in a row of a figure; more tasks wrap onto further rows
PANELS_PER_ROW = 3


def _panels(plt: Any, n: int) -> tuple[Any, list[Any]]:
    """A figure of ``n`` panels, :data:`PANELS_PER_ROW` per row; the unused ones of the last row are hidden."""
    cols = min(n, PANELS_PER_ROW)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.0 * cols, 3.6 * rows), squeeze=False)
    flat = list(axes.flat)
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def plot_band(ax: Any, band: pd.DataFrame, steps_per_step: int, color: str | None, label: str) -> None:
    """The mean line and its 95% CI band, in one colour: with ``color=None`` (a variant) the band takes the colour
    matplotlib chose for the line.

    :param ax: the panel.
    :param band: :func:`~sppo_lab.stats.curve_band`'s output.
    :param steps_per_step: env steps per agent step (action repeat).
    :param color: the line's colour (``None``: matplotlib's next one).
    :param label: the legend's entry.
    """
    steps = band["timesteps"] * steps_per_step
    (line,) = ax.plot(steps, band["mean"], color=color, label=label, lw=1.6)
    ax.fill_between(steps, band["ci_low"], band["ci_high"], color=line.get_color(), alpha=0.2, lw=0)


def plot_curves(
    curves: dict[tuple[str, str], list[pd.DataFrame]],
    tasks: Sequence[str],
    column: str,
    ylabel: str,
    path: Path,
    points: int = 100,
    smooth: int = 1,
    dpi: int = 100,
) -> None:
    """One panel per task: ``column`` vs env steps, one line per algorithm: the mean over seeds and its 95% CI band.

    An algorithm with a single seed has no band.

        :param curves: the runs' curves by ``(task, algo)``.
        :param tasks: the panels, in order.
        :param column: the curve column plotted.
        :param ylabel: its axis label.
        :param path: the PNG written.
        :param points: grid size of the mean and its interval.
        :param smooth: rolling mean over this many episodes (per seed, before averaging).
        :param dpi: resolution.
    """
    plt = _pyplot()
    fig, axes = _panels(plt, len(tasks))
    for ax, task in zip(axes, tasks):
        algos = sorted({a for (t, a) in curves if t == task}, key=algo_sort_key)
        for algo in algos:
            band = curve_band(curves[(task, algo)], column, points, smooth)
            if band.empty:
                continue
            n_seeds = len(curves[(task, algo)])
            label = f"{display_name(algo)} ({n_seeds} seed{'s' if n_seeds != 1 else ''})"
            plot_band(ax, band, env_steps_per_step(task), algo_color(algo), label)
        ax.set_title(task_title(task), fontsize=10)
        ax.set_xlabel("env steps" if env_steps_per_step(task) == 1 else "env steps (action repeat included)")
        ax.set_ylabel(ylabel)
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 3))
        ax.grid(alpha=0.3)
        if algos:
            ax.legend(fontsize=8, title=INTERVAL_NOTE, title_fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def plot_violation_bars(summaries: pd.DataFrame, tasks: Sequence[str], path: Path, dpi: int = 100) -> None:
    """One panel per task: cumulative violations at the end of training per algorithm.

    Bar: mean over seeds; line: its 95% bootstrap CI (none with a single seed); dots: the seeds.

        :param summaries: the runs' ``summary.json`` rows.
        :param tasks: the panels, in order.
        :param path: the PNG written.
        :param dpi: resolution.
    """
    plt = _pyplot()
    fig, axes = _panels(plt, len(tasks))
    for ax, task in zip(axes, tasks):
        runs = summaries[summaries["task"] == task]
        algos = sorted(runs["algo"].unique(), key=algo_sort_key)
        for x, algo in enumerate(algos):
            values = runs.loc[runs["algo"] == algo, "cumulative_violations"].astype(float).to_numpy()
            mean, interval = float(values.mean()), seed_intervals(values)
            low, high = interval["ci_low"], interval["ci_high"]
            error = [[mean - low], [high - mean]] if np.isfinite(low) else None
            ax.bar(x, mean, yerr=error, color=algo_color(algo), alpha=0.75, capsize=4)
            ax.scatter(np.full(values.size, x) + np.linspace(-0.15, 0.15, values.size), values, color="k", s=10, zorder=3)
            top = max(mean, high) if np.isfinite(high) else mean
            ax.annotate(
                f"{mean:.3g}", (x, top), ha="center", va="bottom", fontsize=8, xytext=(0, 2), textcoords="offset points"
            )
        ax.set_xticks(range(len(algos)), [display_name(a) for a in algos], fontsize=8)
        ax.set_ylabel(f"cumulative violations ({INTERVAL_NOTE})")
        ax.set_title(task_title(task), fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.set_ylim(bottom=0)
        ax.margins(y=0.15)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def plot_efficiency(runs: pd.DataFrame, task: str, target: float, path: Path, dpi: int = 100) -> None:
    """Two panels for ``task``: the env steps at which each algorithm's training return first reached ``target``, and
    the training cost it paid until then. Bar: mean over the seeds that reached it; dots: those seeds; an algorithm
    none of whose seeds reached it is marked "not reached" (its cost of the whole run is drawn hollow instead).

    :param runs: :func:`~sppo_lab.velocity.seed_efficiency`'s rows.
    :param task: the task (the title).
    :param target: the return.
    :param path: the PNG written.
    :param dpi: resolution.
    """
    plt = _pyplot()
    fig, (steps_ax, cost_ax) = plt.subplots(1, 2, figsize=(10.0, 3.6))
    algos = list(dict.fromkeys(runs["algo"]))
    for x, algo in enumerate(algos):
        group = runs[runs["algo"] == algo]
        hit = group.dropna(subset=["steps"])
        color = algo_color(algo)
        if hit.empty:
            steps_ax.annotate("not reached", (x, 0), ha="center", va="bottom", fontsize=8, rotation=90)
            cost_ax.bar(x, float(group["cost_total"].mean()), fill=False, edgecolor=color, hatch="//")
            continue
        for ax, key in ((steps_ax, "steps"), (cost_ax, "cost")):
            values = hit[key].astype(float).to_numpy()
            ax.bar(x, float(values.mean()), color=color, alpha=0.75)
            ax.scatter(np.full(values.size, x) + np.linspace(-0.15, 0.15, values.size), values, color="k", s=10, zorder=3)
    for ax, label in ((steps_ax, "env steps to reach it"), (cost_ax, "training cost paid until then")):
        ax.set_xticks(range(len(algos)), [display_name(a) for a in algos], fontsize=8)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
        ax.set_ylim(bottom=0)
    fig.suptitle(f"{task_title(task)}: training return ≥ {target:.0f} (mean of the last 10 episodes)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
