"""The velocity benchmark's tables: our runs beside OmniSafe's published rows, and the env steps to a return.

OmniSafe (PKU-Alignment/omnisafe, ``benchmarks/{off,on}-policy/README.md``, Table 2) publishes, per Safety-Gymnasium
velocity task, the final policy's episode reward and episode cost (cost limit 25), mean ± std over 5 seeds, after 1e6
env steps (off-policy; Humanoid 3e6) or 1e7 (on-policy). ``lab/runs/omnisafe_velocity.md`` has every row with
its lines; :data:`OMNISAFE_VELOCITY` holds those of the algorithms this package runs. Our rows are
:func:`~sppo_lab.stats.aggregate`'s; on these tasks a step costs 0 or 1, so a run's violations are its
cost.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from sppo_lab.display import VELOCITY_TASK_NAMES, algo_sort_key, display_name, task_title
from sppo_lab.suites import OMNISAFE_COMMIT, PublishedRow, overview_markdown, published_tables_markdown
from sppo_lab.tables import values_cell
from sppo_sb3.envs.velocity import ANT, HALF_CHEETAH, HOPPER, SWIMMER, WALKER2D

#: the published algorithms of :data:`OMNISAFE_VELOCITY` and their budgets: SAC, SACLag, CPO, and PPOLag (the
#: counterpart of this package's PDO)
PUBLISHED_ALGORITHMS: tuple[tuple[str, float], ...] = (("SAC", 1e6), ("SACLag", 1e6), ("PPOLag", 1e7), ("CPO", 1e7))


def _task_rows(*values: tuple[float, float, float, float]) -> tuple[PublishedRow, ...]:
    """A task's rows of :data:`PUBLISHED_ALGORITHMS`, from ``(reward, reward std, cost, cost std)`` each."""
    return tuple(
        PublishedRow(name, budget, (reward, reward_std), (cost, cost_std))
        for (name, budget), (reward, reward_std, cost, cost_std) in zip(PUBLISHED_ALGORITHMS, values, strict=True)
    )


#: OmniSafe's Table 2 rows of :data:`PUBLISHED_ALGORITHMS` on the velocity tasks
OMNISAFE_VELOCITY: dict[str, tuple[PublishedRow, ...]] = {
    HALF_CHEETAH.env_id: _task_rows(
        (11488.86, 513.09, 981.93, 0.33),
        (2833.72, 3.62, 0.00, 0.00),
        (2946.15, 306.35, 3.44, 4.77),
        (2786.48, 173.45, 4.70, 6.72),
    ),
    HOPPER.env_id: _task_rows(
        (3537.70, 32.23, 975.23, 2.39),
        (963.49, 291.64, 20.23, 28.47),
        (961.92, 752.87, 13.96, 19.33),
        (1713.71, 18.26, 13.40, 5.82),
    ),
    WALKER2D.env_id: _task_rows(
        (4419.29, 232.06, 877.70, 8.95),
        (2676.47, 300.43, 30.67, 32.30),
        (2982.27, 681.55, 13.49, 14.55),
        (2074.76, 962.45, 21.90, 9.41),
    ),
    ANT.env_id: _task_rows(
        (5456.31, 156.04, 943.10, 47.51),
        (1897.32, 1213.74, 5.73, 7.83),
        (3261.87, 80.00, 12.05, 6.57),
        (3098.54, 78.90, 14.12, 3.41),
    ),
    SWIMMER.env_id: _task_rows(
        (46.44, 1.23, 40.97, 0.47), (11.03, 11.17, 22.70, 32.10), (64.74, 17.67, 28.02, 4.09), (65.30, 43.25, 18.22, 8.01)
    ),
}
#: the return the sample-efficiency measure asks for: this share of OmniSafe's SACLag on HalfCheetah (2833.72 at 1e6)
TARGET_FRACTION = 0.8
TARGET_TASK = HALF_CHEETAH.env_id
#: training episodes averaged before the return is compared with the target (the tables' "last 10")
TARGET_WINDOW = 10


def target_return(task: str = TARGET_TASK) -> float:
    """:data:`TARGET_FRACTION` of OmniSafe's published SACLag return on ``task``."""
    saclag = next(row for row in OMNISAFE_VELOCITY[task] if row.algorithm == "SACLag")
    return TARGET_FRACTION * saclag.reward[0]


def velocity_tables_markdown(table: pd.DataFrame) -> str:
    """One table per velocity task: our algorithms (mean [95% CI] over seeds), then OmniSafe's published rows.

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    """
    caption = (
        "Ours: the training runs' last 10 episodes; the final policy deployed for 10 deterministic episodes with its\n"
        "shield (an unshielded algorithm: the same as alone) and alone (its cost per episode is OmniSafe's measure);\n"
        "the cost paid over training (a step above the threshold costs 1) and the share of training episodes that\n"
        "paid none; shield interventions; wall clock per run. OmniSafe: the final policy's episode reward and cost,\n"
        f"mean ± std over 5 seeds, at its own budget (commit {OMNISAFE_COMMIT[:8]})."
    )
    return published_tables_markdown(table, OMNISAFE_VELOCITY, caption, "--velocity")


def velocity_overview_markdown(table: pd.DataFrame) -> str:
    """The grid at a glance (:func:`~sppo_lab.suites.overview_markdown`) with the velocity tasks' names.

    :param table: :func:`~sppo_lab.stats.aggregate`'s output.
    """
    return overview_markdown(table, VELOCITY_TASK_NAMES, "--velocity")


#: the end of training that :func:`late_episodes` reads: episodes that end in this last share of a run's env steps
LATE_SHARE = 0.25

#: the columns of :func:`late_episodes_markdown`: (key of :func:`late_episodes`, digits, title)
LATE_FIGURES: tuple[tuple[str, int, str], ...] = (
    ("length", 0, "Episode length (steps)"),
    ("return_per_step", 2, "Return per env step"),
    ("cost_share", 0, "Steps above the limit (%)"),
)


def late_episodes(curve: pd.DataFrame, share: float = LATE_SHARE) -> dict[str, float]:
    """How a run's episodes go at the end of training: over the episodes that end in its last ``share`` of env steps,
    their mean length, their return per env step, and the share of their steps that cost (in %).

    On Hopper, Walker2d and Ant a robot that falls ends its episode, so a short episode is a fall, and the reward
    pays 1 per step alive plus the forward speed; a step above the velocity limit costs 1. The three figures tell a
    learner that falls from one that buys its return with speed over the limit.

    :param curve: the run's learning curve (:data:`~sppo_lab.layout.CURVE_COLUMNS`).
    :param share: the share of the run's env steps at its end.
    """
    steps = curve["timesteps"].astype(float)
    late = curve[steps > (1.0 - share) * steps.iloc[-1]]
    lengths = late["length"].astype(float)
    return {
        "length": float(lengths.mean()),
        "return_per_step": float(late["return"].astype(float).sum() / lengths.sum()),
        "cost_share": float(100.0 * late["cost"].astype(float).sum() / lengths.sum()),
    }


def late_episodes_markdown(curves: dict[tuple[str, str], list[pd.DataFrame]], share: float = LATE_SHARE) -> str:
    """:func:`late_episodes` per task and algorithm, mean [95% CI] over seeds: who falls, and who pays for speed.

    :param curves: the runs' curves by ``(task, algo)``.
    :param share: the share of each run's env steps at its end.
    """
    header = "| Method | Seeds |" + "".join(f" {title} |" for _, _, title in LATE_FIGURES)
    lines = [
        "<!-- written by scripts/plot_results.py --velocity -->",
        f"The training episodes that end in the last {share:.0%} of each run's env steps: their length (a short one",
        "is a fall), their return per env step (on Hopper, Walker2d and Ant, 1 of it for staying up, the rest for",
        "speed) and the share of their steps above the velocity limit. Mean [95% CI] over seeds; the value alone for",
        "one seed.",
        "",
    ]
    for task in sorted({task for task, _ in curves}):
        lines += [f"### {task_title(task)}", "", header, "|" + "---|" * header.count(" |")]
        for algo in sorted((a for t, a in curves if t == task), key=algo_sort_key):
            figures = [late_episodes(curve, share) for curve in curves[(task, algo)]]
            cells = [values_cell([f[key] for f in figures], digits) for key, digits, _ in LATE_FIGURES]
            lines.append("| " + " | ".join([display_name(algo), str(len(figures)), *cells]) + " |")
        lines.append("")
    return "\n".join(lines)


def steps_to_return(curve: pd.DataFrame, target: float, window: int = TARGET_WINDOW) -> dict[str, float]:
    """When a run's training return first reaches ``target``: the mean of its last ``window`` episodes, episode by
    episode (fewer at the start), against ``target``.

    :param curve: the run's learning curve (:data:`~sppo_lab.layout.CURVE_COLUMNS`).
    :param target: the return.
    :param window: episodes averaged.
    :return: ``steps`` and ``seconds`` (monitor clock) at the end of that episode and ``cost``, the training cost paid
        until then (all NaN if the run never reaches it), and ``cost_total``, the run's whole training cost.
    """
    returns = curve["return"].astype(float).rolling(window, min_periods=1).mean().to_numpy()
    cost = curve["cost"].astype(float).cumsum().to_numpy()
    reached = np.flatnonzero(returns >= target)
    found = {"steps": float("nan"), "seconds": float("nan"), "cost": float("nan"), "cost_total": float(cost[-1])}
    if reached.size:
        first = int(reached[0])
        found.update(steps=float(curve["timesteps"].iloc[first]), seconds=float(curve["time"].iloc[first]), cost=cost[first])
    return found


def seed_efficiency(curves: dict[tuple[str, str], list[pd.DataFrame]], task: str, target: float) -> pd.DataFrame:
    """:func:`steps_to_return` of every run on ``task``, one row per run (``algo`` and its figures).

    :param curves: the runs' curves by ``(task, algo)``.
    :param task: the task.
    :param target: the return.
    """
    rows = [
        {"algo": algo, **steps_to_return(curve, target)}
        for algo in sorted((a for t, a in curves if t == task), key=algo_sort_key)
        for curve in curves[(task, algo)]
    ]
    return pd.DataFrame(rows, columns=["algo", "steps", "seconds", "cost", "cost_total"])


def efficiency_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per algorithm: how many seeds reached the target and, over those, the mean env steps, wall clock and training
    cost until then; and the mean training cost of the whole run.

    :param runs: :func:`seed_efficiency`'s rows.
    """
    rows = []
    for algo, group in runs.groupby("algo", sort=False):
        hit = group.dropna(subset=["steps"])
        means = {key: float(hit[key].mean()) if len(hit) else float("nan") for key in ("steps", "seconds", "cost")}
        rows.append(
            {"algo": algo, "seeds": len(group), "reached": len(hit), **means, "cost_total": group["cost_total"].mean()}
        )
    return pd.DataFrame(rows)


def efficiency_markdown(efficiency: pd.DataFrame, task: str, target: float) -> str:
    """:func:`efficiency_table` in markdown."""
    lines = [
        f"### {task_title(task)}: env steps to a return of {target:.0f} "
        f"({TARGET_FRACTION:.0%} of OmniSafe's SACLag at 1e6 env steps)",
        "",
        f"The first episode at which the mean of the last {TARGET_WINDOW} training episodes reaches it; means over the "
        "seeds that reached it.",
        "",
        "| Method | Seeds reaching it | Env steps | Wall clock (min) | Training cost until then | Training cost, whole run |",
        "|---|---|---|---|---|---|",
    ]
    for _, row in efficiency.iterrows():
        steps, minutes, cost = (
            "–" if not np.isfinite(row[key]) else f"{row[key] / scale:.{digits}f}"
            for key, scale, digits in (("steps", 1, 0), ("seconds", 60, 1), ("cost", 1, 0))
        )
        cells = [display_name(str(row["algo"])), f"{row['reached']} of {row['seeds']}", steps, minutes, cost]
        lines.append("| " + " | ".join([*cells, f"{row['cost_total']:.0f}"]) + " |")
    return "\n".join(lines) + "\n"
