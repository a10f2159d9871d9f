"""The markdown tables of the comparison: Tables I–II beside the paper's numbers, and the Fig. 7 returns."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from sppo_lab.display import display_name, env_steps_per_step, task_title
from sppo_lab.stats import BOOTSTRAP_REPS, EARLY_FRACTION, IQM_MIN_SEEDS, order_of_magnitude, seed_intervals

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


def _throughput(row: pd.Series, scale: int = 1) -> str:
    """Training env steps/s (monitor clock), else over the whole command; times ``scale`` env steps per step."""
    for key in ("train_steps_per_s_mean", "steps_per_s_mean"):
        value = row.get(key, float("nan"))
        if value is not None and np.isfinite(value):
            return f"{value * scale:.1f}"
    return "–"


#: how the tables' ``mean [low, high]`` cells read
INTERVAL_LEGEND = (
    f"`mean [low, high]`: mean over seeds and its 95% percentile-bootstrap confidence interval over seeds "
    f"({BOOTSTRAP_REPS} resamples); `mean ± std` where there is no interval (one seed). IQM: interquartile mean over "
    f"seeds [95% CI], from {IQM_MIN_SEEDS} seeds."
)


def _with_interval(row: pd.Series, estimate: str, interval: str, digits: int) -> str | None:
    """``value [low, high]`` from the row's columns ``estimate``, ``interval_low`` and ``interval_high`` (or ``None``)."""
    value, low, high = (row.get(column, float("nan")) for column in (estimate, f"{interval}_low", f"{interval}_high"))
    if not (np.isfinite(value) and np.isfinite(low) and np.isfinite(high)):
        return None
    return f"{value:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def estimate_cell(row: pd.Series, key: str, digits: int = 2) -> str:
    """``mean [low, high]`` of ``key`` over seeds, ``mean ± std`` without an interval, ``–`` without a mean."""
    cell = _with_interval(row, f"{key}_mean", f"{key}_ci", digits)
    if cell is not None:
        return cell
    mean = row.get(f"{key}_mean", float("nan"))
    return "–" if not np.isfinite(mean) else f"{mean:.{digits}f} ± {row[f'{key}_std']:.{digits}f}"


def values_cell(values: Sequence[float], digits: int = 2) -> str:
    """``mean [low, high]`` of per-seed ``values`` (:func:`~sppo_lab.stats.seed_intervals`): the mean alone
    where fewer than 2 finite values remain, ``–`` where none do. Non-finite values (a run without the figure) are left
    out."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return "–"
    interval = seed_intervals(x)
    if not np.isfinite(interval["ci_low"]):
        return f"{x.mean():.{digits}f}"
    return f"{x.mean():.{digits}f} [{interval['ci_low']:.{digits}f}, {interval['ci_high']:.{digits}f}]"


def _iqm(row: pd.Series, key: str, digits: int = 2) -> str:
    """``iqm [low, high]`` of ``key`` over seeds, ``–`` with too few seeds."""
    return _with_interval(row, f"{key}_iqm", f"{key}_iqm_ci", digits) or "–"


def _has_iqm(table: pd.DataFrame, key: str) -> bool:
    """Whether any row of ``table`` has an IQM of ``key`` (the IQM columns are left out otherwise)."""
    column = f"{key}_iqm"
    return column in table and bool(np.isfinite(table[column].astype(float)).any())


#: the Tables I–II figures with an estimate over seeds: (key, digits, column title)
SAFETY_ESTIMATES: tuple[tuple[str, int, str], ...] = (
    ("cumulative_violations", 1, "Cumulative violations"),
    ("violations_early_share", 1, f"Violations in the first {EARLY_FRACTION:.0%} of steps (%)"),
    ("safety_rate", 2, "Safety rate (%)"),
    ("return_last_n", 2, "Return (last episodes)"),
    ("return_training_mean", 2, "Return (mean over training)"),
    ("eval_unshielded_return", 2, "Deployed without shield: return"),
    ("eval_unshielded_safe_rate", 1, "Deployed without shield: safe episodes (%)"),
)


def _safety_row(row: pd.Series, paper: dict[str, tuple[str, float, float]], iqm_keys: list[str]) -> str:
    """One algorithm's line of a Table I–II: ours, then the paper's when the task is one of its tables."""
    algo = str(row["algo"])
    interventions = row.get("cumulative_interventions_mean", float("nan"))
    cells = [display_name(algo), order_of_magnitude(row["cumulative_violations_mean"])]
    cells += [estimate_cell(row, key, digits) for key, digits, _ in SAFETY_ESTIMATES]
    cells += [
        f"{row['episodes_mean']:.0f}",
        "–" if not np.isfinite(interventions) else f"{interventions:.0f}",
        _throughput(row),
    ]
    cells += [_iqm(row, key, digits) for key, digits, _ in SAFETY_ESTIMATES if key in iqm_keys]
    if paper:
        ref = paper.get(algo)
        cells += [ref[0], f"{ref[1]:.2f} ± {ref[2]:.2f}"] if ref else ["–", "–"]
    return "| " + " | ".join(cells) + " |"


def safety_tables_markdown(table: pd.DataFrame) -> str:
    """Tables I–II in markdown: ours (order of magnitude, mean [95% CI], safety rate, IQM) beside the paper's.

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    """
    lines = [
        "<!-- written by scripts/plot_results.py -->",
        "Violations (10^*): order of magnitude of the mean cumulative constraint violations over training, as in the",
        "paper (`0`: none; `10 ↓`: 1–9; `10^k ↑`: at least 10^k). Violations in the first 10%: the share of a run's",
        "violations paid in the episodes that ended in its first tenth of env steps (`–`: none paid). Safety rate:",
        "episodes without a violation / all training episodes. Return (last episodes): mean training-episode return of",
        "each run's last episodes. Return (mean over training): each run's learning curve averaged over its env steps,",
        "its area over its length (higher: learned sooner). Deployed without shield: the final policy alone, on fresh",
        "episodes (`sppo-train`'s deployment check). Env steps/s: training throughput (start-up excluded), mean over",
        "seeds. The paper's safety rate is mean ± std.",
        INTERVAL_LEGEND,
        "",
    ]
    for task, group in table.groupby("task", sort=True):
        paper = PAPER_TABLES.get(str(task), {})
        title = f"{PAPER_TABLE_NAMES[str(task)]}: " if str(task) in PAPER_TABLE_NAMES else ""
        steps = round(float(group["steps_mean"].max())) if "steps_mean" in group else 0
        seeds = ", ".join(sorted({str(s) for s in group["seeds"]}))
        lines += [f"### {title}{task_title(str(task))}", "", f"Ours: {steps} env steps per run, {seeds} seeds.", ""]
        iqm_keys = [key for key, _, _ in SAFETY_ESTIMATES if _has_iqm(group, key)]
        header = "| Method | Violations (10^*) |" + "".join(f" {title} |" for _, _, title in SAFETY_ESTIMATES)
        header += " Episodes | Shield interventions | Env steps/s |"
        header += "".join(f" IQM: {title} |" for key, _, title in SAFETY_ESTIMATES if key in iqm_keys)
        if paper:
            header += " Paper: violations | Paper: safety rate (%) |"
        lines += [header, "|" + "---|" * header.count(" |")]
        lines += [_safety_row(row, paper, iqm_keys) for _, row in group.iterrows()]
        lines.append("")
    return "\n".join(lines)


def returns_table_markdown(table: pd.DataFrame) -> str:
    """Final training returns (mean [95% CI] over seeds, IQM) per task and algorithm, for the Fig. 7 comparison.

    Env steps count the action repeat of the dm_control tasks (:func:`~sppo_lab.display.env_steps_per_step`),
    as the paper and TD-MPC do.

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    """
    iqm = _has_iqm(table, "return_last_n")
    lines = ["<!-- written by scripts/plot_results.py --fig7 -->", INTERVAL_LEGEND, ""]
    header = "| Task | Method | Seeds | Env steps | Return (last episodes) | Env steps/s |"
    if iqm:
        header += " IQM: Return (last episodes) |"
    lines += [header, "|---|---|---|---|---|---|" + ("---|" if iqm else "")]
    for _, row in table.iterrows():
        scale = env_steps_per_step(str(row["task"]))
        line = (
            f"| {row['task']} | {display_name(str(row['algo']))} | {row['seeds']} | {row['steps_mean'] * scale:.0f} | "
            f"{estimate_cell(row, 'return_last_n')} | {_throughput(row, scale)} |"
        )
        lines.append(line + (f" {_iqm(row, 'return_last_n')} |" if iqm else ""))
    return "\n".join(lines) + "\n"
