"""Figures and tables of the paper's comparison from a ``scripts/benchmark.py`` output folder.

Writes to ``--out``:

- ``learning_curves.png``: episode return vs env steps, mean ± std over seeds, one panel per task (Figs. 5–6 left);
- ``violations.png``: cumulative constraint violations at the end of training per algorithm, mean ± std over seeds
  with each seed as a dot, one panel per task (Figs. 5–6 right);
- ``cumulative_violations.png``: cumulative violations vs env steps (mean ± std), one panel per task;
- ``tables.md``: Tables I–II: order of magnitude of the cumulative violations and safety rate (mean ± std over seeds)
  beside the paper's numbers, with return, episodes, env steps and throughput.

``--fig7`` instead writes ``fig7_curves.png`` (return curves of SPPO, DDPG and PPO per task, as Fig. 7) and
``fig7_table.md`` (final returns). Needs matplotlib (``pip install "sppo_sb3[plots]"``).

Example::

    python scripts/plot_results.py results/quick --out results/quick/figures
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

#: display order and names (the paper's tables list the baselines first)
ALGO_ORDER: tuple[str, ...] = ("cpo", "pdo", "csc", "sailr", "ddpg", "ppo", "sac", "td3", "sppo")
ALGO_NAMES: dict[str, str] = {
    "cpo": "CPO",
    "pdo": "PDO",
    "csc": "CSC",
    "sailr": "SAILR",
    "sppo": "SPPO (ours)",
    "ddpg": "DDPG",
    "ppo": "PPO",
    "sac": "SAC",
    "td3": "TD3",
}
ALGO_COLORS: dict[str, str] = {
    "cpo": "tab:orange",
    "pdo": "tab:green",
    "csc": "tab:purple",
    "sailr": "tab:blue",
    "sppo": "tab:red",
    "ddpg": "tab:brown",
    "ppo": "tab:gray",
    "sac": "tab:olive",
    "td3": "tab:cyan",
}
TASK_NAMES: dict[str, str] = {"SafePointCircle-v0": "Point Robot", "SafeHalfCheetahHeight-v1": "Half-Cheetah"}
#: the paper's Tables I (Point Robot) and II (Half-Cheetah): violations' order of magnitude, safety rate mean, std
PAPER_TABLES: dict[str, dict[str, tuple[str, float, float]]] = {
    "SafePointCircle-v0": {
        "cpo": ("10^2 ↑", 88.99, 5.05),
        "pdo": ("10^3 ↑", 74.53, 7.53),
        "csc": ("10^3 ↑", 69.84, 7.28),
        "sailr": ("10^2 ↓", 97.56, 0.95),
        "sppo": ("10 ↓", 99.73, 0.31),
    },
    "SafeHalfCheetahHeight-v1": {
        "cpo": ("10^3 ↑", 54.85, 1.31),
        "pdo": ("10^3 ↑", 72.17, 4.05),
        "csc": ("10^3 ↑", 65.10, 1.59),
        "sailr": ("10 ↓", 99.94, 0.03),
        "sppo": ("0", 100.00, 0.00),
    },
}
PAPER_TABLE_NAMES: dict[str, str] = {"SafePointCircle-v0": "Table I", "SafeHalfCheetahHeight-v1": "Table II"}


# ---------------------------------------------------------------------------------------------------- loading
def load_results(root: Path) -> tuple[pd.DataFrame, dict[tuple[str, str], list[pd.DataFrame]]]:
    """The finished runs under ``root`` (``<task>/<algo>/seed_<s>/{summary.json,curve.csv}``).

    :param root: the benchmark's output folder.
    :return: one row of ``summary.json`` per run, and the runs' curves by ``(task, algo)`` (seed order).
    """
    rows: list[dict[str, Any]] = []
    curves: dict[tuple[str, str], list[pd.DataFrame]] = {}
    for summary_path in sorted(root.glob("*/*/seed_*/summary.json")):
        run_dir = summary_path.parent
        if not (run_dir / "DONE").exists():
            continue
        summary = json.loads(summary_path.read_text())
        rows.append(summary)
        curve_path = run_dir / "curve.csv"
        curve = pd.read_csv(curve_path) if curve_path.exists() else pd.DataFrame()
        curves.setdefault((summary["task"], summary["algo"]), []).append(curve)
    return pd.DataFrame(rows), curves


def algo_sort_key(algo: str) -> tuple[int, str]:
    """Paper order first, unknown algorithms after, alphabetically.

    :param algo: algorithm name.
    """
    return (ALGO_ORDER.index(algo) if algo in ALGO_ORDER else len(ALGO_ORDER), algo)


def task_title(task: str) -> str:
    """``Point Robot (SafePointCircle-v0)`` for the paper's tasks, the id otherwise.

    :param task: gymnasium id.
    """
    return f"{TASK_NAMES[task]} ({task})" if task in TASK_NAMES else task


# ---------------------------------------------------------------------------------------------------- statistics
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
        for key in (
            "cumulative_violations",
            "safety_rate",
            "return_last_n",
            "episodes",
            "steps",
            "steps_per_s",
            "train_steps_per_s",
        ):
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


# ---------------------------------------------------------------------------------------------------- tables
def _throughput(row: pd.Series) -> str:
    """Training env steps/s (monitor clock), else over the whole command."""
    for key in ("train_steps_per_s_mean", "steps_per_s_mean"):
        value = row.get(key, float("nan"))
        if value is not None and np.isfinite(value):
            return f"{value:.1f}"
    return "–"


def _pm(mean: float, std: float, digits: int = 2) -> str:
    return "–" if not np.isfinite(mean) else f"{mean:.{digits}f} ± {std:.{digits}f}"


def safety_tables_markdown(table: pd.DataFrame) -> str:
    """Tables I–II in markdown: ours (order of magnitude, mean ± std, safety rate) beside the paper's.

    :param table: :func:`aggregate`'s output.
    """
    lines = [
        "<!-- written by scripts/plot_results.py -->",
        "Violations (10^*): order of magnitude of the mean cumulative constraint violations over training, as in the",
        "paper (`0`: none; `10 ↓`: 1–9; `10^k ↑`: at least 10^k). Safety rate: episodes without a violation / all",
        "training episodes, mean ± std over seeds. Return: mean training-episode return of each run's last episodes",
        "(mean ± std over seeds). Env steps/s: training throughput (start-up excluded), mean over seeds.",
        "",
    ]
    for task, group in table.groupby("task", sort=True):
        paper = PAPER_TABLES.get(str(task), {})
        title = f"{PAPER_TABLE_NAMES[str(task)]}: " if str(task) in PAPER_TABLE_NAMES else ""
        steps = round(float(group["steps_mean"].max())) if "steps_mean" in group else 0
        seeds = ", ".join(sorted({str(s) for s in group["seeds"]}))
        lines += [f"### {title}{task_title(str(task))}", "", f"Ours: {steps} env steps per run, {seeds} seeds.", ""]
        header = "| Method | Violations (10^*) | Cumulative violations | Safety rate (%) | Return (last episodes) | Episodes |"
        header += " Shield interventions | Env steps/s |"
        rule = "|---|---|---|---|---|---|---|---|"
        if paper:
            header += " Paper: violations | Paper: safety rate (%) |"
            rule += "---|---|"
        lines += [header, rule]
        for _, row in group.iterrows():
            algo = str(row["algo"])
            interventions = row.get("cumulative_interventions_mean", float("nan"))
            cells = [
                ALGO_NAMES.get(algo, algo),
                order_of_magnitude(row["cumulative_violations_mean"]),
                _pm(row["cumulative_violations_mean"], row["cumulative_violations_std"], 1),
                _pm(row["safety_rate_mean"], row["safety_rate_std"]),
                _pm(row["return_last_n_mean"], row["return_last_n_std"]),
                f"{row['episodes_mean']:.0f}",
                "–" if not np.isfinite(interventions) else f"{interventions:.0f}",
                _throughput(row),
            ]
            if paper:
                ref = paper.get(algo)
                cells += [ref[0], f"{ref[1]:.2f} ± {ref[2]:.2f}"] if ref else ["–", "–"]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def returns_table_markdown(table: pd.DataFrame) -> str:
    """Final training returns (mean ± std over seeds) per task and algorithm, for the Fig. 7 comparison.

    :param table: :func:`aggregate`'s output.
    """
    lines = ["<!-- written by scripts/plot_results.py --fig7 -->", ""]
    lines += ["| Task | Method | Seeds | Env steps | Return (last episodes) | Env steps/s |", "|---|---|---|---|---|---|"]
    for _, row in table.iterrows():
        algo = str(row["algo"])
        lines.append(
            f"| {row['task']} | {ALGO_NAMES.get(algo, algo)} | {row['seeds']} | {row['steps_mean']:.0f} | "
            f"{_pm(row['return_last_n_mean'], row['return_last_n_std'])} | {_throughput(row)} |"
        )
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------------- figures
def _pyplot() -> Any:
    try:
        import matplotlib
    except ImportError as exc:
        raise SystemExit('plot_results.py needs matplotlib: pip install "sppo_sb3[plots]"') from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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
    """One panel per task: ``column`` vs env steps, mean ± std over seeds, one line per algorithm.

    :param curves: the runs' curves by ``(task, algo)``.
    :param tasks: the panels, in order.
    :param column: the curve column plotted.
    :param ylabel: its axis label.
    :param path: the PNG written.
    :param points: grid size of the mean/std.
    :param smooth: rolling mean over this many episodes (per seed, before averaging).
    :param dpi: resolution.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.0 * len(tasks), 3.6), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        algos = sorted({a for (t, a) in curves if t == task}, key=algo_sort_key)
        for algo in algos:
            band = curve_band(curves[(task, algo)], column, points, smooth)
            if band.empty:
                continue
            color = ALGO_COLORS.get(algo)
            n_seeds = len(curves[(task, algo)])
            label = f"{ALGO_NAMES.get(algo, algo)} ({n_seeds} seed{'s' if n_seeds != 1 else ''})"
            ax.plot(band["timesteps"], band["mean"], color=color, label=label, lw=1.6)
            ax.fill_between(band["timesteps"], band["mean"] - band["std"], band["mean"] + band["std"], color=color, alpha=0.2)
        ax.set_title(task_title(task), fontsize=10)
        ax.set_xlabel("env steps")
        ax.set_ylabel(ylabel)
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 3))
        ax.grid(alpha=0.3)
        if algos:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def plot_violation_bars(summaries: pd.DataFrame, tasks: Sequence[str], path: Path, dpi: int = 100) -> None:
    """One panel per task: cumulative violations at the end of training per algorithm (bar: mean; line: std; dots: seeds).

    :param summaries: the runs' ``summary.json`` rows.
    :param tasks: the panels, in order.
    :param path: the PNG written.
    :param dpi: resolution.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.0 * len(tasks), 3.6), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        runs = summaries[summaries["task"] == task]
        algos = sorted(runs["algo"].unique(), key=algo_sort_key)
        for x, algo in enumerate(algos):
            values = runs.loc[runs["algo"] == algo, "cumulative_violations"].astype(float).to_numpy()
            mean, std = float(values.mean()), float(values.std()) if values.size > 1 else 0.0
            color = ALGO_COLORS.get(algo)
            ax.bar(x, mean, yerr=std, color=color, alpha=0.75, capsize=4)
            ax.scatter(np.full(values.size, x) + np.linspace(-0.15, 0.15, values.size), values, color="k", s=10, zorder=3)
            ax.annotate(
                f"{mean:.3g}", (x, mean + std), ha="center", va="bottom", fontsize=8, xytext=(0, 2), textcoords="offset points"
            )
        ax.set_xticks(range(len(algos)), [ALGO_NAMES.get(a, a) for a in algos], fontsize=8)
        ax.set_ylabel("cumulative violations")
        ax.set_title(task_title(task), fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.set_ylim(bottom=0)
        ax.margins(y=0.15)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------- main
def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options (see ``--help``).

    :param argv: the arguments (default: ``sys.argv[1:]``).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path, nargs="?", default=Path("results"), help="benchmark output folder")
    parser.add_argument("--out", type=Path, default=None, help="where figures and tables go (default: RESULTS/figures)")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks to show (default: all found)")
    parser.add_argument("--algos", nargs="+", default=None, help="algorithms to show (default: all found)")
    parser.add_argument("--fig7", action="store_true", help="Fig. 7 mode: return curves and a returns table only")
    parser.add_argument("--smooth", type=int, default=5, help="rolling mean over this many episodes (default: 5)")
    parser.add_argument("--points", type=int, default=100, help="env-step grid of the mean ± std (default: 100)")
    parser.add_argument("--dpi", type=int, default=100, help="PNG resolution (default: 100)")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Write the figures and tables; returns the exit status.

    :param argv: command-line arguments (default: ``sys.argv[1:]``).
    """
    args = parse_args(argv)
    summaries, curves = load_results(args.results)
    if summaries.empty:
        print(f"plot_results: no finished runs under {args.results} (expected <task>/<algo>/seed_<s>/summary.json)")
        return 1
    if args.tasks:
        summaries = summaries[summaries["task"].isin(args.tasks)]
    if args.algos:
        summaries = summaries[summaries["algo"].isin(args.algos)]
    if summaries.empty:
        print("plot_results: no runs left after --tasks/--algos")
        return 1
    keep = set(zip(summaries["task"], summaries["algo"]))
    curves = {key: value for key, value in curves.items() if key in keep}
    tasks = sorted(summaries["task"].unique(), key=lambda t: (t not in TASK_NAMES, t))
    out = args.out or args.results / "figures"
    out.mkdir(parents=True, exist_ok=True)
    table = aggregate(summaries)
    written = []
    if args.fig7:
        plot_curves(curves, tasks, "return", "episode return", out / "fig7_curves.png", args.points, args.smooth, args.dpi)
        (out / "fig7_table.md").write_text(returns_table_markdown(table))
        written += ["fig7_curves.png", "fig7_table.md"]
    else:
        plot_curves(curves, tasks, "return", "episode return", out / "learning_curves.png", args.points, args.smooth, args.dpi)
        plot_curves(
            curves, tasks, "cumulative_violations", "cumulative violations", out / "cumulative_violations.png", args.points
        )
        plot_violation_bars(summaries, tasks, out / "violations.png", args.dpi)
        (out / "tables.md").write_text(safety_tables_markdown(table))
        written += ["learning_curves.png", "cumulative_violations.png", "violations.png", "tables.md"]
    table.to_csv(out / "aggregate.csv", index=False)
    written.append("aggregate.csv")
    print(f"{len(summaries)} runs, {len(tasks)} tasks -> {out}: {', '.join(written)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
