"""The markdown tables of the comparison: Tables I–II beside the paper's numbers, and the Fig. 7 returns."""

from __future__ import annotations

import numpy as np
import pandas as pd

from sppo_sb3.experiments.display import display_name, task_title
from sppo_sb3.experiments.stats import order_of_magnitude

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


def _throughput(row: pd.Series) -> str:
    """Training env steps/s (monitor clock), else over the whole command."""
    for key in ("train_steps_per_s_mean", "steps_per_s_mean"):
        value = row.get(key, float("nan"))
        if value is not None and np.isfinite(value):
            return f"{value:.1f}"
    return "–"


def _pm(mean: float, std: float, digits: int = 2) -> str:
    return "–" if not np.isfinite(mean) else f"{mean:.{digits}f} ± {std:.{digits}f}"


def _safety_row(row: pd.Series, paper: dict[str, tuple[str, float, float]]) -> str:
    """One algorithm's line of a Table I–II: ours, then the paper's when the task is one of its tables."""
    algo = str(row["algo"])
    interventions = row.get("cumulative_interventions_mean", float("nan"))
    cells = [
        display_name(algo),
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
    return "| " + " | ".join(cells) + " |"


def safety_tables_markdown(table: pd.DataFrame) -> str:
    """Tables I–II in markdown: ours (order of magnitude, mean ± std, safety rate) beside the paper's.

    :param table: :func:`~sppo_sb3.experiments.stats.aggregate`'s output.
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
        lines += [_safety_row(row, paper) for _, row in group.iterrows()]
        lines.append("")
    return "\n".join(lines)


def returns_table_markdown(table: pd.DataFrame) -> str:
    """Final training returns (mean ± std over seeds) per task and algorithm, for the Fig. 7 comparison.

    :param table: :func:`~sppo_sb3.experiments.stats.aggregate`'s output.
    """
    lines = ["<!-- written by scripts/plot_results.py --fig7 -->", ""]
    lines += ["| Task | Method | Seeds | Env steps | Return (last episodes) | Env steps/s |", "|---|---|---|---|---|---|"]
    for _, row in table.iterrows():
        lines.append(
            f"| {row['task']} | {display_name(str(row['algo']))} | {row['seeds']} | {row['steps_mean']:.0f} | "
            f"{_pm(row['return_last_n_mean'], row['return_last_n_std'])} | {_throughput(row)} |"
        )
    return "\n".join(lines) + "\n"
