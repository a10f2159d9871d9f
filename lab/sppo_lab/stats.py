"""Statistics over a grid's runs: curves on a common step grid, and per-(task, algorithm) aggregates over seeds.

Aggregates are the mean ± std over seeds and, for the paper's figures, the mean with its 95% bootstrap confidence
interval (and the interquartile mean, IQM, from :data:`IQM_MIN_SEEDS` seeds) as Agarwal et al. (2021) recommend for
few-seed RL results: the percentile bootstrap over seeds of ``scipy.stats.bootstrap`` (``pip install
"sppo_sb3[plots]"``). Every interval is of one task, where Agarwal et al.'s stratified bootstrap (runs resampled
within each task) is this bootstrap over seeds. rliable, their library, is not used: it pins ``arch<8``, which does
not import with pandas 3.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sppo_lab import layout
from sppo_lab.display import algo_sort_key
from sppo_lab.spec import run_name

#: the ``summary.json`` figures aggregated as mean and std over seeds
AGGREGATED_KEYS: tuple[str, ...] = (
    "cumulative_violations",
    "violations_early_share",
    "safety_rate",
    "return_last_n",
    "return_training_mean",
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
    "wall_clock_s",
)
#: the figures that also get a 95% bootstrap confidence interval of their mean over seeds, and an IQM: all but counts
#: and throughputs
INTERVAL_KEYS: tuple[str, ...] = tuple(
    key for key in AGGREGATED_KEYS if key not in ("episodes", "steps", "steps_per_s", "train_steps_per_s", "wall_clock_s")
)
#: bootstrap resamples of every confidence interval (aggregates and every point of a curve)
BOOTSTRAP_REPS = 2000
#: seed of the resampling, so that the same runs give the same intervals
BOOTSTRAP_SEED = 0
#: coverage of the confidence intervals
CONFIDENCE = 0.95
#: fewest seeds with an interquartile mean (the 25% trimmed mean drops a quarter of the seeds at each end)
IQM_MIN_SEEDS = 4
#: env steps at which :func:`training_return_mean` reads a learning curve
TRAINING_CURVE_POINTS = 100
#: the start of training whose share of the violations :func:`early_violation_share` reports
EARLY_FRACTION = 0.1


def training_return_mean(curve: pd.DataFrame, points: int = TRAINING_CURVE_POINTS) -> float:
    """A learning-efficiency figure: the mean height of a run's learning curve over its env steps.

    The training-episode returns, interpolated linearly between the episode ends at ``points`` evenly spaced env steps
    from the first episode's end to the last one's, averaged: the area under the curve over its length. Of two runs
    that end at the same return, the one that got there sooner scores higher.

    :param curve: the run's ``curve.csv`` (``timesteps``, ``return``).
    :return: the mean, NaN without an episode.
    """
    if curve.empty:
        return float("nan")
    steps = curve["timesteps"].to_numpy(dtype=float)
    grid = np.linspace(steps[0], steps[-1], points)
    return float(np.mean(np.interp(grid, steps, curve["return"].to_numpy(dtype=float))))


def early_violation_share(curve: pd.DataFrame, steps: float, fraction: float = EARLY_FRACTION) -> float:
    """How much of its cost a learner paid before it had learned: the percentage of a run's violations in the
    episodes that ended within its first ``fraction`` of ``steps``.

    :param curve: the run's ``curve.csv`` (``timesteps``, ``violations``).
    :param steps: the run's env steps.
    :param fraction: the share of the run counted as its start.
    :return: the percentage, NaN for a run without a violation.
    """
    total = float(curve["violations"].sum()) if "violations" in curve else 0.0
    if total == 0:
        return float("nan")
    early = float(curve.loc[curve["timesteps"] <= fraction * steps, "violations"].sum())
    return 100.0 * early / total


def load_results(root: Path) -> tuple[pd.DataFrame, dict[tuple[str, str], list[pd.DataFrame]]]:
    """The finished runs under a grid's output folder (:mod:`sppo_lab.layout`).

    :param root: the benchmark's output folder.
    :return: one row of ``summary.json`` per run, with its :func:`training_return_mean` as ``return_training_mean``,
        its :func:`early_violation_share` as ``violations_early_share``
        and its row name (:func:`~sppo_lab.spec.run_name`: ``cpo-shielded`` for a variant) as ``algo``, and
        the runs' curves by ``(task, algo)`` (seed order).
    """
    rows: list[dict[str, Any]] = []
    curves: dict[tuple[str, str], list[pd.DataFrame]] = {}
    for run_dir in layout.finished_run_dirs(root):
        summary, curve = layout.read_summary(run_dir), layout.read_curve(run_dir)
        name = run_name(summary["algo"], summary.get("variant", ""))
        steps = summary.get("steps") or (float(curve["timesteps"].max()) if not curve.empty else 0.0)
        early = early_violation_share(curve, steps)
        rows.append(
            {**summary, "algo": name, "return_training_mean": training_return_mean(curve), "violations_early_share": early}
        )
        curves.setdefault((summary["task"], name), []).append(curve)
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


def _scipy_stats() -> Any:
    """``scipy.stats`` (an optional extra)."""
    try:
        from scipy import stats
    except ImportError as exc:
        raise SystemExit('confidence intervals need scipy: pip install "sppo_sb3[plots]"') from exc
    return stats


def interquartile_mean(values: np.ndarray, axis: int = 0) -> Any:
    """The IQM: the mean of the middle 50% of ``values`` along ``axis`` (a 25% trimmed mean)."""
    return _scipy_stats().trim_mean(values, 0.25, axis=axis)


def bootstrap_interval(
    scores: np.ndarray, statistic: Callable[..., Any] = np.mean, reps: int = BOOTSTRAP_REPS
) -> tuple[Any, Any, Any]:
    """``statistic`` of ``scores`` over its seeds (axis 0) and its :data:`CONFIDENCE` percentile-bootstrap interval.

    The seeds are resampled with replacement, :data:`BOOTSTRAP_REPS` times from a generator seeded with
    :data:`BOOTSTRAP_SEED`, so the same runs give the same interval. Every other index of ``scores`` gets its own
    interval, from the same resamples of the seeds (vectorised: one call for all the points of a curve).

    :param scores: ``(seeds,)`` or ``(seeds, points)``.
    :param statistic: a reduction with an ``axis`` argument (``np.mean``, :func:`interquartile_mean`).
    :param reps: bootstrap resamples.
    :return: the estimate, the interval's low and high ends (scalars, or arrays over the points).
    """
    stats = _scipy_stats()
    result = stats.bootstrap(
        (scores,),
        lambda sample, axis: statistic(sample, axis=axis),
        n_resamples=reps,
        confidence_level=CONFIDENCE,
        method="percentile",
        axis=0,
        vectorized=True,
        rng=np.random.default_rng(BOOTSTRAP_SEED),
    )
    return statistic(scores, axis=0), result.confidence_interval.low, result.confidence_interval.high


def seed_intervals(values: np.ndarray) -> dict[str, float]:
    """Confidence intervals of one figure over seeds: of its mean, and its IQM with its interval.

    Non-finite values (a run without that figure) are left out. NaN where there are too few seeds: an interval needs
    2, an IQM :data:`IQM_MIN_SEEDS`.

    :param values: one value per seed.
    :return: ``ci_low``, ``ci_high``, ``iqm``, ``iqm_ci_low``, ``iqm_ci_high``.
    """
    values = np.asarray(values, dtype=float)
    scores = values[np.isfinite(values)]
    nan = float("nan")
    out = dict.fromkeys(("ci_low", "ci_high", "iqm", "iqm_ci_low", "iqm_ci_high"), nan)
    if len(scores) >= 2:
        _, low, high = bootstrap_interval(scores, np.mean)
        out.update(ci_low=float(low), ci_high=float(high))
    if len(scores) >= IQM_MIN_SEEDS:
        iqm, low, high = bootstrap_interval(scores, interquartile_mean)
        out.update(iqm=float(iqm), iqm_ci_low=float(low), iqm_ci_high=float(high))
    return out


def _pointwise_mean_intervals(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column of ``values`` (seeds × points, NaN: a seed that does not reach the point): the interval of the mean.

    Columns covered by the same seeds are bootstrapped in one call; a column with fewer than 2 seeds gets NaN.
    """
    low = np.full(values.shape[1], np.nan)
    high = np.full(values.shape[1], np.nan)
    covered = ~np.isnan(values)
    for seeds in np.unique(covered, axis=1).T:
        if seeds.sum() < 2:
            continue
        columns = np.all(covered == seeds[:, None], axis=0)
        _, low[columns], high[columns] = bootstrap_interval(values[seeds][:, columns], np.mean)
    return low, high


def curve_band(curves: Sequence[pd.DataFrame], column: str, points: int = 100, smooth: int = 1) -> pd.DataFrame:
    """Mean over seeds of ``column`` vs env steps with its 95% bootstrap interval (and std), on ``points`` steps.

    Each seed's column (a rolling mean over ``smooth`` episodes) is interpolated linearly between its episode ends,
    on the range of env steps that all seeds cover (their episodes end at different steps); when the seeds' ranges do
    not overlap, on their union, where a seed outside its range is left out of the mean.

    The interval of each grid point is a bootstrap of the seeds at that point (:func:`bootstrap_interval`, all the
    points of the seeds that cover them in one vectorised call); with a single seed there is none (NaN).

    :param curves: the seeds' ``curve.csv`` frames (``timesteps`` and ``column``).
    :param column: e.g. ``return`` or ``cumulative_violations``.
    :param points: grid size.
    :param smooth: episodes in the rolling mean (1: raw).
    :return: columns ``timesteps``, ``mean``, ``std``, ``ci_low``, ``ci_high``, ``n`` (seeds at that step).
    """
    usable = [c for c in curves if not c.empty and column in c]
    if not usable:
        return pd.DataFrame(columns=["timesteps", "mean", "std", "ci_low", "ci_high", "n"])
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
    low, high = _pointwise_mean_intervals(values)
    return pd.DataFrame({"timesteps": grid, "mean": mean, "std": std, "ci_low": low, "ci_high": high, "n": n})


def _mean_std(values: pd.Series) -> tuple[float, float]:
    values = values.astype(float)
    return float(values.mean()), float(values.std(ddof=0)) if len(values) > 1 else 0.0


def aggregate(summaries: pd.DataFrame) -> pd.DataFrame:
    """Per ``(task, algo)``: seeds, env steps, episodes, violations, safety rate and return over seeds.

    Every key of :data:`AGGREGATED_KEYS` found gives ``<key>_mean`` and ``<key>_std``; those of :data:`INTERVAL_KEYS`
    also ``<key>_ci_low``, ``<key>_ci_high`` (95% stratified-bootstrap interval of the mean), ``<key>_iqm``,
    ``<key>_iqm_ci_low`` and ``<key>_iqm_ci_high`` (:func:`seed_intervals`: NaN with too few seeds).

    :param summaries: the runs' ``summary.json`` rows.
    """
    rows = []
    for (task, algo), group in summaries.groupby(["task", "algo"], sort=False):
        row: dict[str, Any] = {"task": task, "algo": algo, "seeds": len(group)}
        for key in AGGREGATED_KEYS:
            if key in group:
                row[f"{key}_mean"], row[f"{key}_std"] = _mean_std(group[key])
            if key in group and key in INTERVAL_KEYS:
                row.update({f"{key}_{name}": value for name, value in seed_intervals(group[key].to_numpy()).items()})
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
