"""The command line of ``scripts/plot_results.py``: the figures and tables of a benchmark output folder.

Writes to ``--out`` the figures of :mod:`sppo_lab.figures`, the tables of
:mod:`sppo_lab.tables` and ``aggregate.csv`` (:func:`~sppo_lab.stats.aggregate`).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from sppo_lab.display import task_sort_key
from sppo_lab.figures import plot_curves, plot_efficiency, plot_violation_bars
from sppo_lab.navigation import navigation_overview_markdown, navigation_tables_markdown
from sppo_lab.stats import aggregate, load_results
from sppo_lab.tables import returns_table_markdown, safety_tables_markdown
from sppo_lab.velocity import (
    TARGET_TASK,
    efficiency_markdown,
    efficiency_table,
    late_episodes_markdown,
    seed_efficiency,
    target_return,
    velocity_overview_markdown,
    velocity_tables_markdown,
)

DESCRIPTION = "Figures and tables of the paper's comparison from a ``scripts/benchmark.py`` output folder."


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options (see ``--help``).

    :param argv: the arguments (default: ``sys.argv[1:]``).
    """
    parser = argparse.ArgumentParser(description=DESCRIPTION)
    parser.add_argument("results", type=Path, nargs="?", default=Path("results"), help="benchmark output folder")
    parser.add_argument("--out", type=Path, default=None, help="where figures and tables go (default: RESULTS/figures)")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks to show (default: all found)")
    parser.add_argument("--algos", nargs="+", default=None, help="algorithms to show (default: all found)")
    parser.add_argument("--fig7", action="store_true", help="Fig. 7 mode: return curves and a returns table only")
    parser.add_argument(
        "--velocity",
        action="store_true",
        help="velocity-benchmark mode: curves of return and cumulative cost, tables beside OmniSafe's published rows, "
        "how the last quarter's episodes go (length, return per step, steps above the limit), "
        "and the env steps to 80%% of OmniSafe's SACLag return on HalfCheetah",
    )
    parser.add_argument(
        "--navigation",
        action="store_true",
        help="navigation-benchmark mode: curves of return and cumulative cost, tables beside OmniSafe's published rows",
    )
    parser.add_argument("--smooth", type=int, default=5, help="rolling mean over this many episodes (default: 5)")
    parser.add_argument("--points", type=int, default=100, help="env-step grid of the curves' mean and CI (default: 100)")
    parser.add_argument("--dpi", type=int, default=100, help="PNG resolution (default: 100)")
    return parser.parse_args(argv)


def write_figures(
    args: argparse.Namespace, summaries: pd.DataFrame, curves: dict[tuple[str, str], list[pd.DataFrame]], out: Path
) -> list[str]:
    """Write the figures and tables of the selected runs into ``out``; returns the files' names.

    :param args: :func:`parse_args`'s result.
    :param summaries: the selected runs' ``summary.json`` rows.
    :param curves: their curves by ``(task, algo)``.
    :param out: the output folder.
    """
    tasks = sorted(summaries["task"].unique(), key=task_sort_key)
    table = aggregate(summaries)
    if args.velocity:
        written = write_velocity_figures(args, table, curves, tasks, out)
    elif args.navigation:
        written = write_cost_curves(args, curves, tasks, out)
        (out / "navigation_tables.md").write_text(navigation_tables_markdown(table))
        (out / "navigation_overview.md").write_text(navigation_overview_markdown(table))
        written += ["navigation_tables.md", "navigation_overview.md"]
    elif args.fig7:
        plot_curves(curves, tasks, "return", "episode return", out / "fig7_curves.png", args.points, args.smooth, args.dpi)
        (out / "fig7_table.md").write_text(returns_table_markdown(table))
        written = ["fig7_curves.png", "fig7_table.md"]
    else:
        plot_curves(curves, tasks, "return", "episode return", out / "learning_curves.png", args.points, args.smooth, args.dpi)
        plot_curves(
            curves, tasks, "cumulative_violations", "cumulative violations", out / "cumulative_violations.png", args.points
        )
        plot_violation_bars(summaries, tasks, out / "violations.png", args.dpi)
        (out / "tables.md").write_text(safety_tables_markdown(table))
        written = ["learning_curves.png", "cumulative_violations.png", "violations.png", "tables.md"]
    table.to_csv(out / "aggregate.csv", index=False)
    return [*written, "aggregate.csv"]


def write_cost_curves(
    args: argparse.Namespace, curves: dict[tuple[str, str], list[pd.DataFrame]], tasks: list[str], out: Path
) -> list[str]:
    """The suites' curves: episode return, and the cost paid while learning; returns the files' names."""
    with_cost = {key: [curve.assign(cumulative_cost=curve["cost"].cumsum()) for curve in runs] for key, runs in curves.items()}
    plot_curves(with_cost, tasks, "return", "episode return", out / "learning_curves.png", args.points, args.smooth, args.dpi)
    plot_curves(with_cost, tasks, "cumulative_cost", "cumulative training cost", out / "cumulative_cost.png", args.points)
    return ["learning_curves.png", "cumulative_cost.png"]


def write_velocity_figures(
    args: argparse.Namespace,
    table: pd.DataFrame,
    curves: dict[tuple[str, str], list[pd.DataFrame]],
    tasks: list[str],
    out: Path,
) -> list[str]:
    """The velocity benchmark's figures and tables (:mod:`sppo_lab.velocity`); returns the files' names."""
    written = write_cost_curves(args, curves, tasks, out)
    (out / "velocity_tables.md").write_text(velocity_tables_markdown(table))
    (out / "velocity_overview.md").write_text(velocity_overview_markdown(table))
    (out / "late_episodes.md").write_text(late_episodes_markdown(curves))
    written += ["velocity_tables.md", "velocity_overview.md", "late_episodes.md"]
    if TARGET_TASK in tasks:
        target = target_return()
        runs = seed_efficiency(curves, TARGET_TASK, target)
        plot_efficiency(runs, TARGET_TASK, target, out / "sample_efficiency.png", args.dpi)
        (out / "sample_efficiency.md").write_text(efficiency_markdown(efficiency_table(runs), TARGET_TASK, target))
        written += ["sample_efficiency.png", "sample_efficiency.md"]
    return written


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
    out = args.out or args.results / "figures"
    out.mkdir(parents=True, exist_ok=True)
    written = write_figures(args, summaries, curves, out)
    print(f"{len(summaries)} runs, {summaries['task'].nunique()} tasks -> {out}: {', '.join(written)}")
    return 0
