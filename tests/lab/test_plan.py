"""The paper-scale plan: core-hours of the paper's grid from the throughput measured in a (synthetic) results folder."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import yaml

from sppo_lab import benchmark, grid, layout, plan

REPO = Path(__file__).resolve().parents[2]
POINT, CHEETAH = "SafePointCircle-v0", "SafeHalfCheetahHeight-v1"
#: (task, algo, seed): steps, wall-clock seconds, training steps/s (NaN: no finished episode)
RUNS: dict[tuple[str, str, int], tuple[int, float, float]] = {
    (POINT, "sppo", 0): (1000, 15.0, 100.0),
    (POINT, "sppo", 1): (3000, 64.0, 50.0),
    (POINT, "pdo", 0): (2000, 4.0, 1000.0),
    (CHEETAH, "sppo", 0): (1000, 15.0, 100.0),
    (CHEETAH, "pdo", 0): (500, 50.0, float("nan")),
}


def _write_run(out: Path, task: str, algo: str, seed: int, steps: int, wall_s: float, train_rate: float) -> None:
    run_dir = layout.run_dir_for(out, task, algo, seed)
    run_dir.mkdir(parents=True)
    summary: dict[str, Any] = dict(task=task, algo=algo, seed=seed, steps=steps, wall_clock_s=wall_s)
    summary.update(steps_per_s=steps / wall_s, train_steps_per_s=train_rate)
    layout.write_finished(run_dir, summary, pd.DataFrame(columns=list(layout.CURVE_COLUMNS)).to_csv(index=False))


@pytest.fixture
def results(tmp_path: Path) -> Path:
    """A results folder with the finished :data:`RUNS` and one failed run (CPO on Point Robot)."""
    for (task, algo, seed), run in RUNS.items():
        _write_run(tmp_path, task, algo, seed, *run)
    failed = layout.run_dir_for(tmp_path, POINT, "cpo", 0)
    failed.mkdir(parents=True)
    layout.write_failed(failed, 1, "boom")
    return tmp_path


def test_throughput_is_measured_on_the_training_clock(results: Path) -> None:
    measured = plan.measured_throughput(plan.load_summaries(results)).set_index(["task", "algo"])
    assert (POINT, "cpo") not in measured.index  # the failed run measures nothing
    sppo = measured.loc[(POINT, "sppo")]
    assert (sppo["seeds"], sppo["steps"]) == ("0, 1", "1000–3000")
    train_s = 1000 / 100.0 + 3000 / 50.0  # both runs' training seconds
    assert sppo["s_per_step"] == pytest.approx(train_s / 4000)
    assert sppo["fixed_s"] == pytest.approx(np.median([15.0 - 1000 / 100.0, 64.0 - 3000 / 50.0]))
    pdo = measured.loc[(CHEETAH, "pdo")]  # no training clock: the whole command's rate, no fixed cost
    assert (pdo["s_per_step"], pdo["fixed_s"]) == (pytest.approx(50.0 / 500), 0.0)


def test_paper_plan_scales_the_measured_runs_to_the_paper_grid(results: Path) -> None:
    throughput = plan.measured_throughput(plan.load_summaries(results))
    paper = plan.grid_plan(throughput).set_index(["task", "algo"])
    assert len(paper) == len(plan.PAPER_SEEDS) * len(plan.PAPER_ALGOS) == 10
    assert (paper["grid_seeds"].loc[POINT] == 8).all() and (paper["grid_seeds"].loc[CHEETAH] == 5).all()
    # SPPO's Cheetah run ran as fast as Point's seed 0; Point's seed 1 ran slower, so Point's runs cost more
    assert paper.loc[(CHEETAH, "sppo"), "run_s"] < paper.loc[(POINT, "sppo"), "run_s"]
    for task, seeds in plan.PAPER_SEEDS.items():  # core-hours: all the grid's seeds of the pair
        assert paper.loc[(task, "sppo"), "core_hours"] == pytest.approx(len(seeds) * paper.loc[(task, "sppo"), "run_s"] / 3600)
    # a run's cost grows with the env steps at the measured rate
    longer = plan.grid_plan(throughput, steps=2 * plan.PAPER_STEPS).set_index(["task", "algo"])
    extra = longer["run_s"] - paper["run_s"]
    assert extra.loc[(POINT, "pdo")] == pytest.approx(plan.PAPER_STEPS / 1000.0)
    assert paper.loc[(POINT, "cpo"), ["s_per_step", "run_s", "core_hours"]].isna().all()


def test_makespan_of_longest_first_scheduling() -> None:
    durations = [4.0, 3.0, 2.0, 1.0]
    assert plan.makespan_s(durations, 1) == sum(durations)
    assert plan.makespan_s(durations, 2) == 5.0  # 4 + 1 | 3 + 2
    assert plan.makespan_s(durations, 8) == max(durations)
    spans = [plan.makespan_s(np.arange(1.0, 20.0), n) for n in range(1, 12)]
    assert all(later <= earlier for earlier, later in itertools.pairwise(spans))
    assert all(span >= np.arange(1.0, 20.0).sum() / n for n, span in enumerate(spans, start=1))


def test_benchmark_plan_prints_the_table_and_runs_nothing(results: Path, capsys: pytest.CaptureFixture[str]) -> None:
    files = sorted(results.rglob("*"))
    assert benchmark.main(["--plan", "--out", str(results), "--workers", "4"]) == 0
    assert sorted(results.rglob("*")) == files
    text = capsys.readouterr().out
    paper = plan.grid_plan(plan.measured_throughput(plan.load_summaries(results)))
    rows = [line for line in text.splitlines() if line.startswith("| ") and "Core-hours" not in line]
    assert len(rows) == 10 + 1  # every (task, algorithm) of the paper's grid and the total
    assert "| Point Robot (SafePointCircle-v0) | CPO | not measured |" in text
    sppo = paper.set_index(["task", "algo"]).loc[(POINT, "sppo")]
    assert f"| SPPO (ours) | 0, 1 | 1000–3000 | {1000 * sppo['s_per_step']:.3g} |" in text  # its measured runs
    measured = paper.dropna(subset=["core_hours"])
    total = f"{int(measured['grid_seeds'].sum())} runs | **{measured['core_hours'].sum():,.1f}** |"
    assert f"| **Total** | | | | | | {total}" in text
    assert "Wall clock of the runs left on 4 cores:" in text and "One CPU core per run" in text
    assert benchmark.main(["--plan", "--out", str(results / "empty"), "--workers", "4"]) == 1


def test_velocity_plan_counts_the_runs_left(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--plan --velocity`` costs the velocity grid at its budget, and a finished run of that budget is not left."""
    cheetah, hopper = grid.VELOCITY.tasks[:2]
    _write_run(tmp_path, hopper, "sppo", 0, grid.VELOCITY.steps, 2000.0, 60.0)  # a grid run: done
    _write_run(tmp_path, cheetah, "sppo", 0, 5000, 100.0, 60.0)  # a shorter run: measures the rate, is not done
    _write_run(tmp_path, cheetah, "pdo", 0, grid.VELOCITY.steps + 352, 300.0, 400.0)  # its last full rollout: done
    argv = ["--plan", "--velocity", "--algos", "sppo", "pdo", "--out", str(tmp_path), "--workers", "2"]
    assert benchmark.main(argv) == 0
    text = capsys.readouterr().out
    assert f"{grid.VELOCITY.steps:,} env steps per run" in text
    summaries = plan.load_summaries(tmp_path)
    seeds = dict.fromkeys(grid.VELOCITY.tasks, range(grid.DEFAULT_SEEDS))
    expected = plan.grid_plan(plan.measured_throughput(summaries), seeds, ["sppo", "pdo"], grid.VELOCITY.steps, summaries)
    left = expected.set_index(["task", "algo"])["left"]
    assert (left[(hopper, "sppo")], left[(cheetah, "sppo")], left[(cheetah, "pdo")]) == (2, 3, 2)
    assert (left.drop([(hopper, "sppo"), (cheetah, "sppo"), (cheetah, "pdo")]) == grid.DEFAULT_SEEDS).all()
    measured = expected.dropna(subset=["core_hours"])
    total = f"| {int(measured['left'].sum())} runs | **{measured['left_core_hours'].sum():,.1f}** |"
    assert total in text and int(measured["left"].sum()) == 2 + 3 + 2  # only the measured pairs are costed
    assert "Wall clock of the runs left on 2 cores:" in text


def test_velocity_plan_counts_only_the_seeds_asked_for(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--first-seed 1 --seeds 1``: seed 0's finished run measures the rate but does not stand in for seed 1."""
    hopper = grid.VELOCITY.tasks[1]
    _write_run(tmp_path, hopper, "sppo", 0, grid.VELOCITY.steps, 2000.0, 60.0)
    argv = ["--plan", "--velocity", "--algos", "sppo", "--tasks", hopper, "--out", str(tmp_path), "--workers", "1"]
    assert benchmark.main([*argv, "--first-seed", "1", "--seeds", "1"]) == 0
    assert "| 1 runs |" in capsys.readouterr().out
    assert benchmark.main([*argv, "--seeds", "1"]) == 0  # seed 0 alone: done
    assert "| 0 runs |" in capsys.readouterr().out


def test_the_velocity_budget_is_the_yml_files() -> None:
    for path in (REPO / "hyperparams" / grid.VELOCITY.hyperparams).glob("*.yml"):
        for task, entry in yaml.safe_load(path.read_text()).items():
            assert float(entry["n_timesteps"]) == grid.VELOCITY.steps, (path.name, task)
