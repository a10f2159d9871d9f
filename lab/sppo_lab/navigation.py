"""The navigation benchmark's tables: our runs beside OmniSafe's published rows on the three tasks of ``--navigation``.

OmniSafe publishes the navigation tasks at three budgets and two cost limits (``lab/runs/omnisafe_navigation.md``,
every row with its lines): off-policy at 3e6 env steps (SAC, SACLag; PointGoal1 and CarGoal1), on-policy at 1e7 (PPOLag,
CPO; all three tasks), and model-based at 1e6 with a cost limit of 1 (PETS, SafeLOOP, CCEPETS; PointGoal1 and CarGoal1;
these agents observed the robot's coordinates, OmniSafe's ``-modelbased`` variant of the task, not the lidar).
"""

from __future__ import annotations

import pandas as pd

from sppo_lab.suites import OMNISAFE_COMMIT, PublishedRow, overview_markdown, published_tables_markdown

POINT_GOAL1, CAR_GOAL1, POINT_BUTTON1 = (f"sppo_sb3/Safety{name}-v0" for name in ("PointGoal1", "CarGoal1", "PointButton1"))


def _rows(*values: tuple[str, float, float, float, float, float, float]) -> tuple[PublishedRow, ...]:
    """Rows from ``(algorithm, budget, reward, reward std, cost, cost std, cost limit)`` each."""
    return tuple(
        PublishedRow(name, budget, (r, r_std), (c, c_std), limit) for name, budget, r, r_std, c, c_std, limit in values
    )


#: OmniSafe's rows of the algorithms this package runs (SAC, SACLag, PPOLag for PDO, CPO) and of the model-based
#: agents, per task of :data:`~sppo_lab.grid.NAVIGATION`
OMNISAFE_NAVIGATION: dict[str, tuple[PublishedRow, ...]] = {
    POINT_GOAL1: _rows(
        ("SAC", 3e6, 27.04, 1.49, 67.57, 32.13, 25.0),
        ("SACLag", 3e6, 21.45, 6.97, 19.17, 9.72, 25.0),
        ("PPOLag", 1e7, 12.96, 6.95, 25.80, 34.99, 25.0),
        ("CPO", 1e7, 20.46, 1.38, 28.84, 7.76, 25.0),
        ("PETS", 1e6, 27.66, 0.07, 49.16, 2.69, 1.0),
        ("SafeLOOP", 1e6, 22.94, 0.72, 0.04, 0.07, 1.0),
        ("CCEPETS", 1e6, 24.98, 0.05, 1.87, 1.27, 1.0),
    ),
    CAR_GOAL1: _rows(
        ("SAC", 3e6, 35.71, 2.24, 54.73, 46.74, 25.0),
        ("SACLag", 3e6, 10.83, 11.29, 22.67, 28.91, 25.0),
        ("PPOLag", 1e7, 13.27, 9.26, 21.72, 32.06, 25.0),
        ("CPO", 1e7, 25.52, 2.65, 43.32, 14.35, 25.0),
        ("PETS", 1e6, 33.07, 1.33, 61.20, 7.23, 1.0),
        ("SafeLOOP", 1e6, 22.09, 0.30, 0.16, 0.15, 1.0),
        ("CCEPETS", 1e6, 27.60, 1.21, 1.03, 0.29, 1.0),
    ),
    POINT_BUTTON1: _rows(
        ("PPOLag", 1e7, 4.60, 4.73, 20.8, 35.78, 25.0),
        ("CPO", 1e7, 4.04, 4.54, 40.00, 4.52, 25.0),
    ),
}
#: the tasks' names in the overview
NAVIGATION_TASK_NAMES = {POINT_GOAL1: "PointGoal1", CAR_GOAL1: "CarGoal1", POINT_BUTTON1: "PointButton1"}


def navigation_tables_markdown(table: pd.DataFrame) -> str:
    """One table per navigation task: our algorithms (mean [95% CI] over seeds), then OmniSafe's published rows.

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    """
    caption = (
        "Ours: the training runs' last 10 episodes; the final policy deployed for 10 deterministic episodes with its\n"
        "shield (an unshielded algorithm: the same as alone) and alone (its cost per episode is OmniSafe's measure);\n"
        "the cost paid over training (a step with any cost term costs 1) and the share of training episodes that paid\n"
        "none; shield interventions; wall clock per run. OmniSafe: the final policy's episode reward and cost at its\n"
        "own budget, cost limit 25 unless stated (the model-based agents: 1, and they observed the robot's\n"
        f"coordinates, not the lidar; commit {OMNISAFE_COMMIT[:8]})."
    )
    return published_tables_markdown(table, OMNISAFE_NAVIGATION, caption, "--navigation")


def navigation_overview_markdown(table: pd.DataFrame) -> str:
    """The navigation grid at a glance (:func:`~sppo_lab.suites.overview_markdown`).

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    """
    return overview_markdown(table, NAVIGATION_TASK_NAMES, "--navigation")
