"""The tables every benchmark suite shares (``--velocity``, ``--navigation``): our runs beside OmniSafe's published rows,
and the grid at a glance.

OmniSafe (PKU-Alignment/omnisafe) publishes per Safety-Gymnasium task the final policy's episode reward and episode
cost, mean ± std over 5 seeds, at its own budget and cost limit (``lab/runs/omnisafe_*.md`` has every row with
its lines). Our rows are :func:`~sppo_lab.stats.aggregate`'s; on these tasks a step costs 0 or 1, so a
run's violations are its cost.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from sppo_lab.display import algo_sort_key, display_name, task_title
from sppo_lab.spec import split_run_name
from sppo_lab.tables import INTERVAL_LEGEND, estimate_cell

#: the OmniSafe commit the published rows were read at
OMNISAFE_COMMIT = "15603dd7a654a991d0a4648216b69d60b81a6366"
#: the cost limit of OmniSafe's velocity and navigation tables (its model-based table's is 1)
OMNISAFE_COST_LIMIT = 25.0


@dataclass(frozen=True)
class PublishedRow:
    """One of OmniSafe's published results.

    :param algorithm: OmniSafe's name of the algorithm.
    :param budget: env steps of training.
    :param reward: the final policy's episode reward, mean and std over seeds.
    :param cost: its episode cost, mean and std over seeds.
    :param cost_limit: the episode cost it was trained to keep under (:data:`OMNISAFE_COST_LIMIT` but for the
        model-based table's 1; an unconstrained algorithm ignores it).
    """

    algorithm: str
    budget: float
    reward: tuple[float, float]
    cost: tuple[float, float]
    cost_limit: float = OMNISAFE_COST_LIMIT


#: the columns of a suite's table: (summary key, digits, title)
SUITE_ESTIMATES: tuple[tuple[str, int, str], ...] = (
    ("return_last_n", 1, "Return, last 10 training episodes"),
    ("eval_return", 1, "Deployed with its shield: return"),
    ("eval_violations", 2, "Deployed with its shield: cost per episode"),
    ("eval_unshielded_return", 1, "Deployed without shield: return"),
    ("eval_unshielded_violations", 2, "Deployed without shield: cost per episode"),
    ("cumulative_violations", 0, "Training cost (sum over training)"),
    ("safety_rate", 1, "Training episodes with cost 0 (%)"),
)
#: the method the overview sets against the best of the others
OURS = "sppo"


def _our_row(row: pd.Series) -> str:
    steps = row.get("steps_mean", float("nan"))
    interventions = row.get("cumulative_interventions_mean", float("nan"))
    wall = row.get("wall_clock_s_mean", float("nan"))
    cells = [display_name(str(row["algo"])), f"{steps:.0e}" if np.isfinite(steps) else "–"]
    cells += [estimate_cell(row, key, digits) for key, digits, _ in SUITE_ESTIMATES]
    cells += [
        "–" if not np.isfinite(interventions) else f"{interventions:.0f}",
        "–" if not np.isfinite(wall) else f"{wall / 60:.0f}",
    ]
    return "| " + " | ".join(cells) + " |"


def _published_row(row: PublishedRow) -> str:
    """OmniSafe's final policy, deployed without a shield: its reward and cost in those columns, "–" elsewhere."""
    reward, cost = (f"{mean:.2f} ± {std:.2f}" for mean, std in (row.reward, row.cost))
    limit = "" if row.cost_limit == OMNISAFE_COST_LIMIT else f" (cost limit {row.cost_limit:g})"
    published = {"eval_unshielded_return": reward, "eval_unshielded_violations": cost}
    cells = [published.get(key, "–") for key, _, _ in SUITE_ESTIMATES] + ["–", "–"]  # interventions, wall clock
    return "| " + " | ".join([f"OmniSafe {row.algorithm}{limit}", f"{row.budget:.0e}", *cells]) + " |"


def published_tables_markdown(
    table: pd.DataFrame, published: Mapping[str, tuple[PublishedRow, ...]], caption: str, mode: str
) -> str:
    """One table per task: our algorithms (mean [95% CI] over seeds), then OmniSafe's published rows.

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    :param published: OmniSafe's rows by task id.
    :param caption: what the columns are, above the tables.
    :param mode: ``scripts/plot_results.py``'s option that writes the tables (named in their first line).
    """
    lines = [f"<!-- written by scripts/plot_results.py {mode} -->", caption, INTERVAL_LEGEND, ""]
    header = "| Method | Env steps |" + "".join(f" {title} |" for _, _, title in SUITE_ESTIMATES)
    header += " Shield interventions | Wall clock (min) |"
    for task, group in table.groupby("task", sort=True):
        lines += [f"### {task_title(str(task))}", "", header, "|" + "---|" * header.count(" |")]
        lines += [_our_row(row) for _, row in group.iterrows()]
        lines += [_published_row(row) for row in published.get(str(task), ())]
        lines.append("")
    return "\n".join(lines)


def _overview_cell(row: pd.Series) -> str:
    """Return of the last 10 training episodes (mean [95% CI] over seeds), mean training cost and seeds."""
    seeds = int(row["seeds"])
    mean = row["return_last_n_mean"]
    returns = estimate_cell(row, "return_last_n", 0) if seeds > 1 else f"{mean:.0f}"
    return f"{returns}, cost {row['cumulative_violations_mean']:.0f}, {seeds} seed{'s' if seeds > 1 else ''}"


def overview_markdown(table: pd.DataFrame, task_names: Mapping[str, str], mode: str) -> str:
    """The grid at a glance: per task, every algorithm's final training return and training cost, the best of the
    other methods (not :data:`OURS`'s variants: earlier settings of the same method), and whether :data:`OURS` is at or
    above it (on the means).

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    :param task_names: the tasks' display names (their ids where missing).
    :param mode: ``scripts/plot_results.py``'s option that writes the overview.
    """
    algos = sorted(table["algo"].unique(), key=algo_sort_key)
    header = "| Task |" + "".join(f" {display_name(str(algo))} |" for algo in algos) + " Best of the others | SPPO ≥ it? |"
    lines = [
        f"<!-- written by scripts/plot_results.py {mode} -->",
        "Return of the last 10 training episodes (mean [95% CI] over seeds), the training cost paid (mean over seeds)",
        "and the seeds. The last columns compare the means.",
        "",
        header,
        "|" + "---|" * header.count(" |"),
    ]
    at_or_above = compared = 0
    for task, group in table.groupby("task", sort=True):
        by_algo = group.set_index("algo")
        cells = [_overview_cell(by_algo.loc[algo]) if algo in by_algo.index else "–" for algo in algos]
        ours_too = [name for name in by_algo.index if split_run_name(str(name))[0] == OURS]  # SPPO and its variants
        others = by_algo.drop(index=ours_too)["return_last_n_mean"].dropna()
        best, verdict = "–", "–"
        if len(others):
            best = f"{display_name(str(others.idxmax()))} {others.max():.0f}"
        if len(others) and OURS in by_algo.index:
            compared += 1
            ours_wins = bool(by_algo.loc[OURS, "return_last_n_mean"] >= others.max())
            at_or_above += ours_wins
            verdict = "yes" if ours_wins else "no"
        lines.append("| " + " | ".join([task_names.get(str(task), str(task)), *cells, best, verdict]) + " |")
    lines += ["", f"SPPO's mean is at or above the best of the others on {at_or_above} of {compared} tasks.", ""]
    return "\n".join(lines)
