"""Confidence intervals over seeds (percentile bootstrap over seeds) in the aggregates, curves, tables and figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sppo_lab import figures, stats, tables

TASK = "SafePointCircle-v0"
INTERVAL_COLUMNS = ("ci_low", "ci_high", "iqm", "iqm_ci_low", "iqm_ci_high")


def _seeds(n: int, mean: float = 5.0, std: float = 1.0) -> np.ndarray:
    """``n`` values, evenly spread, with exactly this mean and (population) std (one seed: the mean)."""
    if n == 1:
        return np.array([mean])
    z = np.linspace(-1.0, 1.0, n)
    return mean + std * (z - z.mean()) / z.std()


def _summaries(seeds_per_algo: dict[str, int]) -> pd.DataFrame:
    rows = []
    for algo, n in seeds_per_algo.items():
        for seed, (ret, violations, rate) in enumerate(zip(_seeds(n, 10.0), _seeds(n, 50.0, 20.0), _seeds(n, 90.0, 5.0))):
            rows.append(
                dict(
                    task=TASK,
                    algo=algo,
                    seed=seed,
                    steps=1000,
                    episodes=20,
                    return_last_n=ret,
                    cumulative_violations=violations,
                    safety_rate=rate,
                    steps_per_s=100.0,
                    train_steps_per_s=120.0,
                    wall_clock_s=10.0,
                )
            )
    return pd.DataFrame(rows)


def _curves(values: np.ndarray) -> list[pd.DataFrame]:
    """One curve per row of ``values`` (seeds × episodes), all seeds' episodes ending at the same steps."""
    steps = 100 * np.arange(1, values.shape[1] + 1)
    return [pd.DataFrame({"timesteps": steps, "return": row}) for row in values]


def test_mean_interval_contains_the_mean_and_narrows_with_more_seeds() -> None:
    widths = []
    for n in (4, 16):
        values = _seeds(n)
        interval = stats.seed_intervals(values)
        assert interval["ci_low"] < values.mean() < interval["ci_high"]
        widths.append(interval["ci_high"] - interval["ci_low"])
    assert widths[1] < widths[0]  # the same spread over 4x the seeds: about half as wide


def test_no_interval_with_one_seed_and_missing_values_are_left_out() -> None:
    assert all(np.isnan(v) for v in stats.seed_intervals(np.array([3.0])).values())
    with_missing = stats.seed_intervals(np.array([1.0, np.nan, 3.0]))
    assert 1.0 <= with_missing["ci_low"] < with_missing["ci_high"] <= 3.0
    assert np.isnan(with_missing["iqm"])  # 2 seeds with a value: too few for an IQM


def test_intervals_are_reproducible_and_leave_numpy_global_rng_alone() -> None:
    values = _seeds(6)
    np.random.seed(123)
    expected_draw = np.random.rand()
    np.random.seed(123)
    first = stats.seed_intervals(values)
    assert np.random.rand() == expected_draw  # the caller's global random stream goes on as if nothing ran
    assert stats.seed_intervals(values) == first


def test_iqm_needs_four_seeds_and_ignores_outliers() -> None:
    assert np.isnan(stats.seed_intervals(_seeds(stats.IQM_MIN_SEEDS - 1))["iqm"])
    values = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 1000.0])
    interval = stats.seed_intervals(values)
    assert interval["iqm"] == pytest.approx(np.sort(values)[2:-2].mean())  # the middle half of the 8 seeds
    assert interval["iqm_ci_low"] <= interval["iqm"] <= interval["iqm_ci_high"]
    assert interval["iqm"] < values.mean() / 10  # the outlier drags the mean, not the IQM


def test_aggregate_adds_intervals_and_keeps_mean_and_std() -> None:
    table = stats.aggregate(_summaries({"pdo": 1, "sailr": 3, "sppo": 5})).set_index("algo")
    for key in ("return_last_n", "cumulative_violations", "safety_rate"):
        assert {f"{key}_{name}" for name in ("mean", "std", *INTERVAL_COLUMNS)} <= set(table.columns)
        assert table.loc[["pdo"], [f"{key}_{name}" for name in INTERVAL_COLUMNS]].isna().all(axis=None)
        assert np.isfinite(table.loc["sailr", f"{key}_ci_low"]) and np.isnan(table.loc["sailr", f"{key}_iqm"])
        sppo = table.loc["sppo"]
        assert sppo[f"{key}_ci_low"] < sppo[f"{key}_mean"] < sppo[f"{key}_ci_high"]
        assert sppo[f"{key}_iqm_ci_low"] <= sppo[f"{key}_iqm"] <= sppo[f"{key}_iqm_ci_high"]
    assert table.loc["sppo", "return_last_n_mean"] == pytest.approx(10.0)
    assert table.loc["sppo", "safety_rate_std"] == pytest.approx(5.0)
    assert "steps_ci_low" not in table  # throughput and counts keep mean ± std only


def test_curve_band_gives_each_step_its_own_interval() -> None:
    rng = np.random.default_rng(0)
    spread = np.linspace(0.0, 2.0, 20)  # the seeds agree at the first episode and disagree more and more
    values = 1.0 + spread * rng.standard_normal((5, 20))
    band = stats.curve_band(_curves(values), "return", points=20)
    assert (band["n"] == 5).all()
    assert ((band["ci_low"] <= band["mean"] + 1e-12) & (band["mean"] <= band["ci_high"] + 1e-12)).all()
    width = (band["ci_high"] - band["ci_low"]).to_numpy()
    assert width[0] == pytest.approx(0.0) and width[-5:].mean() > width[:5].mean()
    pd.testing.assert_frame_equal(stats.curve_band(_curves(values), "return", points=20), band)


def test_curve_band_has_no_interval_where_one_seed_covers_the_steps() -> None:
    single = stats.curve_band(_curves(np.ones((1, 10))), "return", points=10)
    assert single[["ci_low", "ci_high"]].isna().all(axis=None) and np.isfinite(single["mean"]).all()
    # two seeds without common steps: each step has one seed, so no interval anywhere
    late = pd.DataFrame({"timesteps": [2000, 3000], "return": [0.0, 1.0]})
    apart = stats.curve_band([*_curves(np.zeros((1, 10))), late], "return", points=30)
    assert (apart["n"] <= 1).all() and apart[["ci_low", "ci_high"]].isna().all(axis=None)


def test_tables_print_intervals_and_iqm_where_the_seeds_allow() -> None:
    table = stats.aggregate(_summaries({"pdo": 1, "sppo": 5}))
    sppo = table.set_index("algo").loc["sppo"]
    markdown = tables.safety_tables_markdown(table)
    ours = f"{sppo['safety_rate_mean']:.2f} [{sppo['safety_rate_ci_low']:.2f}, {sppo['safety_rate_ci_high']:.2f}]"
    iqm = f"{sppo['return_last_n_iqm']:.2f} [{sppo['return_last_n_iqm_ci_low']:.2f}, {sppo['return_last_n_iqm_ci_high']:.2f}]"
    assert ours in markdown and iqm in markdown and "| IQM: Safety rate (%) |" in markdown
    assert "| PDO | 10 ↑ | 50.0 ± 0.0 | – | 90.00 ± 0.00 |" in markdown  # one seed: no interval; no curve: no share
    assert "99.73 ± 0.31" in markdown  # the paper's Table I stays beside ours
    returns = tables.returns_table_markdown(table)
    assert iqm in returns and "| IQM: Return (last episodes) |" in returns
    few_seeds = tables.safety_tables_markdown(stats.aggregate(_summaries({"sppo": 3})))
    assert "| IQM:" not in few_seeds  # no IQM column when no algorithm has 4 seeds


def test_figures_draw_intervals(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    rng = np.random.default_rng(1)
    curves = {(TASK, "sppo"): _curves(rng.standard_normal((3, 30))), (TASK, "pdo"): _curves(rng.standard_normal((1, 30)))}
    figures.plot_curves(curves, [TASK], "return", "episode return", tmp_path / "curves.png", points=30)
    figures.plot_violation_bars(_summaries({"pdo": 1, "sppo": 4}), [TASK], tmp_path / "bars.png")
    for name in ("curves.png", "bars.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_variants_band_has_its_lines_colour() -> None:
    """A variant has no colour of its own (matplotlib picks the next): its band must take its line's, not the next one."""
    pytest.importorskip("matplotlib")
    from matplotlib.colors import to_rgb

    plt = figures._pyplot()  # the figures' own backend set-up
    rng = np.random.default_rng(2)
    band = stats.curve_band(_curves(rng.standard_normal((3, 30))), "return", 30)
    fig, ax = plt.subplots()
    for label in ("sppo-learned", "sppo-unshielded"):
        figures.plot_band(ax, band, 1, None, label)
    lines, bands = ax.get_lines(), ax.collections
    assert to_rgb(lines[0].get_color()) != to_rgb(lines[1].get_color())
    for line, area in zip(lines, bands):
        assert to_rgb(area.get_facecolor()[0]) == to_rgb(line.get_color())
    plt.close(fig)


def test_training_return_mean_is_the_curves_mean_height_and_rewards_learning_sooner() -> None:
    steps = np.array([100, 200, 300, 400, 500])
    linear = pd.DataFrame({"timesteps": steps, "return": [0.0, 25.0, 50.0, 75.0, 100.0]})
    assert stats.training_return_mean(linear) == pytest.approx(50.0)
    sooner = pd.DataFrame({"timesteps": steps, "return": [0.0, 100.0, 100.0, 100.0, 100.0]})
    later = pd.DataFrame({"timesteps": steps, "return": [0.0, 0.0, 0.0, 0.0, 100.0]})
    assert stats.training_return_mean(sooner) > stats.training_return_mean(linear) > stats.training_return_mean(later)
    assert np.isnan(stats.training_return_mean(linear.iloc[:0]))


def test_early_violation_share_counts_the_episodes_ended_in_the_first_tenth() -> None:
    curve = pd.DataFrame({"timesteps": [50, 100, 101, 600, 1000], "violations": [1, 2, 4, 1, 0]})
    assert stats.early_violation_share(curve, 1000) == pytest.approx(100.0 * 3 / 8)  # the episodes ended by step 100
    assert stats.early_violation_share(curve, 1000, fraction=0.6) == pytest.approx(100.0)
    assert np.isnan(stats.early_violation_share(curve.assign(violations=0), 1000))  # none paid: no share


def test_tables_show_the_mean_return_over_training() -> None:
    summaries = _summaries({"sppo": 2})
    summaries["return_training_mean"] = [30.0, 40.0]
    table = stats.aggregate(summaries)
    row = table.set_index("algo").loc["sppo"]
    assert row["return_training_mean_mean"] == pytest.approx(35.0)
    markdown = tables.safety_tables_markdown(table)
    header = next(line for line in markdown.splitlines() if line.startswith("| Method"))
    rule = markdown.splitlines()[markdown.splitlines().index(header) + 1]
    assert "Return (mean over training)" in header and header.count(" |") == rule.count("---|")
    assert f"| {row['return_training_mean_mean']:.2f} [" in markdown
