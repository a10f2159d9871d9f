"""The navigation benchmark's tables: OmniSafe's rows as its README prints them, beside ours."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

from sppo_lab import grid, stats
from sppo_lab.navigation import OMNISAFE_NAVIGATION, navigation_overview_markdown, navigation_tables_markdown

DOC = Path(__file__).resolve().parents[2] / "lab" / "runs" / "omnisafe_navigation.md"
ROW = re.compile(
    r"^\| (\w+)(?: \(unconstrained\))? \| [\w-]+ \| ([\de.]+)[^|]* \| ([-\d.]+) ± ([\d.]+) \| ([-\d.]+) ± ([\d.]+) \|"
)


def documented_rows(task: str) -> dict[str, tuple[float, ...]]:
    """The rows of the doc's section on ``task``: algorithm → (budget, reward, its std, cost, its std)."""
    section = DOC.read_text().split(f"## {task.split('/')[-1]}\n", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        match = ROW.match(line)
        if match:
            rows[match[1]] = tuple(float(value) for value in match.groups()[1:])
    return rows


def test_the_published_rows_are_the_documented_ones() -> None:
    assert set(OMNISAFE_NAVIGATION) == set(grid.NAVIGATION.tasks)
    for task, rows in OMNISAFE_NAVIGATION.items():
        documented = documented_rows(task)
        for row in rows:
            assert documented[row.algorithm] == (row.budget, *row.reward, *row.cost), (task, row.algorithm)
            assert row.cost_limit == (1.0 if row.budget == 1e6 else 25.0)  # the model-based table's limit


def summary(task: str, algo: str, seed: int, ret: float, cost: float) -> dict[str, object]:
    return {"task": task, "algo": algo, "variant": "", "seed": seed, "steps": 100_000, "return_last_n": ret,
            "cumulative_violations": cost, "safety_rate": 100.0, "wall_clock_s": 600.0}  # fmt: skip


def test_tables_put_our_rows_beside_omnisafes_and_the_overview_compares_the_means() -> None:
    task = grid.NAVIGATION.tasks[0]
    table = stats.aggregate(pd.DataFrame([summary(task, "sppo", s, 12.0 + s, 0) for s in range(3)]
                                         + [summary(task, "saclag", s, 9.0, 30.0) for s in range(3)]))  # fmt: skip
    markdown = navigation_tables_markdown(table)
    # OmniSafe deployed without a shield: its rows fill those columns only
    assert "| OmniSafe SafeLOOP (cost limit 1) | 1e+06 | – | – | – | 22.94 ± 0.72 | 0.04 ± 0.07 |" in markdown
    assert "| OmniSafe SACLag | 3e+06 | – | – | – | 21.45 ± 6.97 | 19.17 ± 9.72 |" in markdown
    overview = navigation_overview_markdown(table)
    assert "| PointGoal1 |" in overview and overview.rstrip().endswith("on 1 of 1 tasks.")
