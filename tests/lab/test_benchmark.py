"""The experiment tooling end to end: the benchmark on a tiny grid, then the plots on its output.

The command lines of scripts/benchmark.py and scripts/plot_results.py (:mod:`sppo_lab`), called in process;
2 algorithms x 1 task x 2 seeds with a few hundred env steps and tiny networks (a hyperparameter folder written to
``tmp_path``), each run a real ``python -m sppo_sb3.train`` subprocess. Most of the time is the runs' start-up.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import yaml
from tiny_hyperparams import tiny_pdo_yml

from sppo_lab import benchmark, configs, display, grid, layout, plot, provenance, runner, stats, tables
from sppo_lab.spec import run_name

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"
TASK = "SafePointCircle-v0"
ALGOS = ("pdo", "sailr")
SEEDS = (0, 1)
STEPS = 512

TINY_HYPERPARAMS = {
    "pdo.yml": tiny_pdo_yml(TASK, STEPS),
    "sailr.yml": f"""
{TASK}:
  n_timesteps: {STEPS}
  policy: 'MlpPolicy'
  shield: 'auto'
  n_steps: 256
  batch_size: 64
  n_epochs: 1
  policy_kwargs: "dict(net_arch=dict(pi=[8], vf=[8]))"
""",
}
SUMMARY_KEYS = {
    "task",
    "algo",
    "seed",
    "steps",
    "episodes",
    "return_last_n",
    "cumulative_violations",
    "safety_rate",
    "cumulative_interventions",
    "wall_clock_s",
    "steps_per_s",
    "command",
}


@pytest.fixture(scope="module")
def tiny_hyperparams(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("hyperparams")
    for name, text in TINY_HYPERPARAMS.items():
        (folder / name).write_text(text)
    return folder


def _grid_args(out: Path, hyperparams: Path) -> list[str]:
    return [
        "--algos",
        *ALGOS,
        "--tasks",
        TASK,
        "--seeds",
        str(len(SEEDS)),
        "--steps",
        str(STEPS),
        "--hyperparams-dir",
        str(hyperparams),
        "--device",
        "cpu",
        "--workers",
        "2",
        "--out",
        str(out),
    ]


@pytest.fixture(scope="module")
def grid_out(tiny_hyperparams: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Run the tiny grid once for the tests of this module."""
    out = tmp_path_factory.mktemp("results")
    assert benchmark.main(_grid_args(out, tiny_hyperparams)) == 0
    return out


def test_runner_writes_curves_and_summaries(grid_out: Path) -> None:
    for algo in ALGOS:
        for seed in SEEDS:
            run_dir = grid_out / TASK / algo / f"seed_{seed}"
            for name in ("DONE", "summary.json", "curve.csv", "train.log", "hyperparams.yml"):
                assert (run_dir / name).is_file(), f"{run_dir / name} missing"
            assert not (run_dir / "FAILED").exists()
            assert list((run_dir / "zoo").rglob("*monitor.csv")), "rl-zoo3's monitor.csv missing"
            curve = pd.read_csv(run_dir / "curve.csv")
            assert tuple(curve.columns) == layout.CURVE_COLUMNS
            assert len(curve) >= 1 and curve["timesteps"].is_monotonic_increasing
            assert (curve["cumulative_violations"] == curve["violations"].cumsum()).all()
            summary = json.loads((run_dir / "summary.json").read_text())
            assert set(summary) >= SUMMARY_KEYS
            assert (summary["task"], summary["algo"], summary["seed"]) == (TASK, algo, seed)
            assert summary["steps"] >= STEPS and summary["episodes"] >= 1
            assert 0.0 <= summary["safety_rate"] <= 100.0
            assert summary["safety_source"] == "safety_metrics"  # the package's algorithms keep SafetyMetrics
            assert "-m sppo_sb3.train" in summary["command"] and f"--seed {seed}" in summary["command"]
            provenance = summary["provenance"]  # where the figures came from: code, settings, packages
            assert len(provenance["commit"]) == 40 and isinstance(provenance["dirty"], bool)
            assert provenance["packages"]["torch"] and provenance["packages"]["stable-baselines3"]
            assert provenance["hyperparameters"]["seed"] == seed and 0 < provenance["hyperparameters"]["gamma"] < 1


def test_provenance_is_the_code_a_run_started_with(
    tiny_hyperparams: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The checkout moves on (a commit) while a run trains: its summary still names the commit it started from."""
    moved = {"after_training": False}
    started, later = {"commit": "a" * 40, "dirty": False}, {"commit": "b" * 40, "dirty": False}
    monkeypatch.setattr(provenance, "source_revision", lambda *args: later if moved["after_training"] else started)
    monkeypatch.setattr(runner, "source_revision", provenance.source_revision)
    real_run = subprocess.run

    def train_then_commit(*args: Any, **kwargs: Any) -> subprocess.CompletedProcess:
        done = real_run(*args, **kwargs)
        moved["after_training"] = True
        return done

    monkeypatch.setattr(runner.subprocess, "run", train_then_commit)
    args = _grid_args(tmp_path, tiny_hyperparams)
    args[args.index("--algos") + 1 : args.index("--tasks")] = ["pdo"]
    args[args.index("--seeds") + 1] = "1"
    args[args.index("--workers") + 1] = "1"
    assert benchmark.main(args) == 0
    summary = json.loads((tmp_path / TASK / "pdo" / "seed_0" / "summary.json").read_text())
    assert summary["provenance"]["commit"] == started["commit"]


def test_runner_skips_finished_runs(grid_out: Path, tiny_hyperparams: Path, capsys: pytest.CaptureFixture[str]) -> None:
    markers = sorted(grid_out.glob("*/*/seed_*/DONE"))
    assert len(markers) == len(ALGOS) * len(SEEDS)
    stamps = [m.stat().st_mtime_ns for m in markers]
    assert benchmark.main(_grid_args(grid_out, tiny_hyperparams)) == 0
    assert f"{len(markers)} already finished, 0 to run" in capsys.readouterr().out
    assert [m.stat().st_mtime_ns for m in markers] == stamps


def test_plotter_writes_figures_and_tables(grid_out: Path, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    out = tmp_path / "figures"
    assert plot.main([str(grid_out), "--out", str(out)]) == 0
    for name in ("learning_curves.png", "violations.png", "cumulative_violations.png"):
        assert (out / name).stat().st_size > 1000
    tables = (out / "tables.md").read_text()
    assert "Table I: Point Robot" in tables
    for column in ("Violations (10^*)", "Safety rate (%)", "Paper: violations", "Paper: safety rate (%)"):
        assert column in tables
    assert "| PDO |" in tables and "| SAILR |" in tables
    assert "74.53 ± 7.53" in tables and "97.56 ± 0.95" in tables  # the paper's Table I beside ours
    aggregate = pd.read_csv(out / "aggregate.csv")
    assert set(aggregate["algo"]) == set(ALGOS) and (aggregate["seeds"] == len(SEEDS)).all()
    assert set(aggregate) >= {"cumulative_violations_mean", "safety_rate_mean", "safety_rate_std", "return_last_n_mean"}
    # 2 seeds each: a bootstrap interval of the mean, which the tables print, but too few seeds for an IQM
    assert (aggregate["safety_rate_ci_low"] <= aggregate["safety_rate_mean"]).all()
    assert (aggregate["safety_rate_mean"] <= aggregate["safety_rate_ci_high"]).all()
    assert aggregate["safety_rate_iqm"].isna().all() and "| IQM:" not in tables
    pdo = aggregate.set_index("algo").loc["pdo"]
    assert f"| {pdo['safety_rate_mean']:.2f} [{pdo['safety_rate_ci_low']:.2f}, {pdo['safety_rate_ci_high']:.2f}] |" in tables
    # Fig. 7 mode on the same folder: return curves and a returns table
    assert plot.main([str(grid_out), "--out", str(out), "--fig7"]) == 0
    assert (out / "fig7_curves.png").is_file() and "| Return (last episodes) |" in (out / "fig7_table.md").read_text()


def test_order_of_magnitude_notation() -> None:
    notation = [stats.order_of_magnitude(v) for v in (0, 3, 10, 99, 250, 4000)]
    assert notation == ["0", "10 ↓", "10 ↑", "10 ↑", "10^2 ↑", "10^3 ↑"]


def test_steps_and_config_resolution(tiny_hyperparams: Path) -> None:
    assert grid.parse_steps(["1e4", f"{TASK}=300"]) == (10000, {TASK: 300})
    with pytest.raises(ValueError, match="TASK=N"):
        grid.parse_steps(["lots"])
    # the package's algorithms need an entry for the task
    with pytest.raises(ValueError, match="no entry for Hopper-v5"):
        configs.resolve_config("pdo", "Hopper-v5", tiny_hyperparams)
    # rl-zoo3's built-in algorithms: its own file, or its -v4 entry under the -v5 id (Fig. 7)
    assert configs.resolve_config("ppo", "CartPole-v1", tiny_hyperparams) is None
    config = configs.resolve_config("ddpg", "HalfCheetah-v5", tiny_hyperparams)
    assert config is not None and "HalfCheetah-v5:" in config and "HalfCheetah-v4" in config


def test_default_grid_holds_the_papers_five_algorithms() -> None:
    """An algorithm the paper does not compare (SACLag) is in the one list, runs with ``--algos``, but is not in the
    default grid nor in the paper-scale plan."""
    from sppo_lab import plan
    from sppo_sb3.algorithms import ALGORITHMS

    assert grid.OUR_ALGOS == plan.PAPER_ALGOS == ("sppo", "pdo", "cpo", "sailr", "csc")
    assert not ALGORITHMS["saclag"].paper and "saclag" not in grid.OUR_ALGOS
    config = configs.resolve_config("saclag", TASK, Path(__file__).resolve().parents[2] / "hyperparams")
    assert config is not None and f"{TASK}:" in config  # hyperparams/saclag.yml: a grid may name it


def test_velocity_preset_runs_its_grid_from_its_own_folder(capsys: pytest.CaptureFixture[str]) -> None:
    """``--velocity``: SPPO, SACLag, PDO, CPO and SAC on four velocity tasks, configured by hyperparams/velocity at
    1e5 env steps, each final policy deployed for 10 episodes (a user's ``--zoo-args`` come after, and win)."""
    args = benchmark.parse_args(["--velocity", "--zoo-args", "--deployment-episodes 3"])
    assert args.hyperparams_dir == configs.REPO_HYPERPARAMS_DIR / "velocity"
    assert args.zoo_args == "--deployment-episodes 10 --deployment-episodes 3"
    algos, tasks, seeds = benchmark.grid_axes(args)
    assert (tuple(algos), tuple(tasks), seeds) == (grid.VELOCITY.algos, grid.VELOCITY.tasks, [0, 1, 2])
    assert len(tasks) == 4 and all(task.startswith("sppo_sb3/Safety") for task in tasks)
    specs = grid.build_grid(algos, tasks, seeds[:1], Path("out"), args.hyperparams_dir)
    for spec in specs:  # every pair has an entry in the folder, at the grid's budget
        entry = yaml.safe_load(spec.config_text or "")[spec.task]
        assert entry["n_timesteps"] == 1e5, spec.label
        if spec.algo in ("saclag", "pdo", "cpo"):
            assert entry["cost_limit"] == 25.0, spec.label  # OmniSafe's velocity benchmark's limit, per episode
    assert {spec.algo for spec in specs if "shield" in yaml.safe_load(spec.config_text or "")[spec.task]} == {"sppo"}
    with pytest.raises(SystemExit):
        benchmark.parse_args(["--velocity", "--fig7"])
    assert "separate grids" in capsys.readouterr().err


def test_navigation_preset_runs_its_grid_from_its_own_folder() -> None:
    """``--navigation``: the same algorithms on PointGoal1, CarGoal1 and PointButton1, from hyperparams/navigation,
    every pair configured at the suite's budget, SPPO shielded by the task's rule."""
    args = benchmark.parse_args(["--navigation"])
    assert args.hyperparams_dir == configs.REPO_HYPERPARAMS_DIR / "navigation"
    algos, tasks, seeds = benchmark.grid_axes(args)
    assert (tuple(algos), tuple(tasks), seeds) == (grid.NAVIGATION.algos, grid.NAVIGATION.tasks, [0, 1, 2])
    for spec in grid.build_grid(algos, tasks, seeds[:1], Path("out"), args.hyperparams_dir):
        entry = yaml.safe_load(spec.config_text or "")[spec.task]
        assert entry["n_timesteps"] == 1e5, spec.label
        assert ("shield" in entry) == (spec.algo == "sppo"), spec.label


def test_scripts_are_thin_command_lines_over_the_module(tmp_path: Path) -> None:
    """``python scripts/benchmark.py`` keeps its flags, presets and output; its default config folder is the repo's."""
    out = tmp_path / "quick"
    cmd = [sys.executable, str(SCRIPTS / "benchmark.py"), "--quick", "--dry-run", "--out", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True, check=True)
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"10 runs (5 algorithms x 1 tasks x 2 seeds) -> {out}; 0 already finished, 10 to run with")
    commands = lines[1:]
    assert len(commands) == 10 and all("-m sppo_sb3.train" in c and "-n 2048" in c for c in commands)
    assert [c.split("--algo ")[1].split()[0] for c in commands[::2]] == list(grid.OUR_ALGOS)
    assert not out.exists()  # a dry run writes nothing
    help_text = subprocess.run(
        [sys.executable, str(SCRIPTS / "plot_results.py"), "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "--fig7" in help_text and "benchmark output folder" in help_text


def test_run_folder_format_is_read_as_written(tmp_path: Path) -> None:
    run_dir = layout.run_dir_for(tmp_path, "dm_control/cheetah-run-v0", "sppo", 3)
    assert run_dir == tmp_path / "dm_control_cheetah-run-v0" / "sppo" / "seed_3"
    run_dir.mkdir(parents=True)
    layout.write_failed(run_dir, 2, "boom")
    assert not layout.is_finished(run_dir) and layout.finished_run_dirs(tmp_path) == []
    curve = pd.DataFrame({column: [1] for column in layout.CURVE_COLUMNS})
    layout.write_finished(run_dir, {"task": "dm_control/cheetah-run-v0", "algo": "sppo"}, curve.to_csv(index=False))
    assert layout.is_finished(run_dir) and not (run_dir / layout.FAILED_FILE).exists()
    assert layout.finished_run_dirs(tmp_path) == [run_dir]
    assert layout.read_summary(run_dir)["algo"] == "sppo"
    assert tuple(layout.read_curve(run_dir).columns) == layout.CURVE_COLUMNS
    summaries, curves = stats.load_results(tmp_path)
    assert list(summaries["algo"]) == ["sppo"] and len(curves[("dm_control/cheetah-run-v0", "sppo")]) == 1


def test_fig7_counts_dm_control_steps_with_the_action_repeat() -> None:
    assert [display.env_steps_per_step(t) for t in ("DMC-cartpole-swingup-v0", "DMC-walker-run-v0", "DMC-hopper-hop-v0")] == [
        8,
        2,
        4,
    ]
    assert display.env_steps_per_step("SafePointCircle-v0") == display.env_steps_per_step("HalfCheetah-v5") == 1
    rows = [
        {"task": task, "algo": "ppo", "seed": seed, "steps": 2500, "train_steps_per_s": 100.0, "return_last_n": 1.0 + seed}
        for task in ("DMC-cartpole-swingup-v0", "Hopper-v5")
        for seed in range(2)
    ]
    table = tables.returns_table_markdown(stats.aggregate(pd.DataFrame(rows)))
    assert "| DMC-cartpole-swingup-v0 | PPO | 2 | 20000 |" in table and table.count("| 800.0 |") == 1
    assert "| Hopper-v5 | PPO | 2 | 2500 |" in table and table.count("| 100.0 |") == 1


def test_a_variant_is_its_own_row_beside_its_algorithm(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--variant shielded``: the same algorithm under other settings gets its own folders and table row."""
    (tmp_path / "pdo.yml").write_text(tiny_pdo_yml(TASK, STEPS))
    specs = grid.build_grid(["pdo"], [TASK], [0], tmp_path / "out", tmp_path, variant="shielded")
    assert [(s.algo, s.name, s.label) for s in specs] == [("pdo", "pdo-shielded", f"{TASK} / pdo-shielded / seed 0")]
    assert Path(specs[0].run_dir) == tmp_path / "out" / TASK / "pdo-shielded" / "seed_0"
    with pytest.raises(ValueError, match="letters, digits and '_'"):
        grid.build_grid(["pdo"], [TASK], [0], tmp_path / "out", tmp_path, variant="with/shield")
    argv = ["--algos", "pdo", "--tasks", TASK, "--seeds", "1", "--hyperparams-dir", str(tmp_path), "--out", str(tmp_path)]
    assert benchmark.main([*argv, "--variant", "shielded", "--dry-run"]) == 0
    assert "--algo pdo --env" in capsys.readouterr().out  # the train command runs the algorithm itself
    # one finished run of each: the variant is read back as its own row, after its algorithm's, named after it
    for variant, violations in (("", 40), ("shielded", 0)):
        run_dir = layout.run_dir_for(tmp_path / "out", TASK, run_name("pdo", variant), 0)
        run_dir.mkdir(parents=True)
        summary = {"task": TASK, "algo": "pdo", "variant": variant, "seed": 0, "steps": STEPS, "episodes": 2}
        summary |= {"cumulative_violations": violations, "safety_rate": 50.0, "return_last_n": 1.0}
        curve = pd.DataFrame({"timesteps": [256, 512], "return": [0.0, 1.0]})
        layout.write_finished(run_dir, summary, curve.to_csv(index=False))
    summaries, curves = stats.load_results(tmp_path / "out")
    assert sorted(summaries["algo"]) == ["pdo", "pdo-shielded"] and set(curves) == {(TASK, "pdo"), (TASK, "pdo-shielded")}
    table = stats.aggregate(summaries)
    assert list(table["algo"]) == ["pdo", "pdo-shielded"]
    markdown = tables.safety_tables_markdown(table)
    assert "| PDO | 10 ↑ |" in markdown and "| PDO (shielded) | 0 |" in markdown
    assert markdown.count("74.53 ± 7.53") == 1  # the paper's PDO row is PDO's, not its variant's
    assert sorted(["sppo", "pdo-shielded", "cpo", "pdo"], key=display.algo_sort_key) == ["cpo", "pdo", "pdo-shielded", "sppo"]


def test_every_committed_run_is_named_by_its_folder() -> None:
    """The tables group runs by ``run_name(algo, variant)`` from each summary: a run moved to another variant's folder
    (``sppo`` → ``sppo-previous``) must say so in its summary, or its seeds are pooled with the folder it left."""
    root = Path(__file__).resolve().parents[2] / "lab" / "runs"
    summaries = sorted(root.rglob("summary.json"))
    assert summaries
    for path in summaries:
        summary = json.loads(path.read_text())
        assert run_name(summary["algo"], summary.get("variant", "")) == path.parent.parent.name, path


@pytest.mark.parametrize(
    "wrapper, agent_steps",
    [
        ("", 1000),
        ("  env_wrapper:\n    - sppo_sb3.shield.ShieldWrapper:\n        rule: auto\n        action_repeat: 5\n", 200),
        ("  env_wrapper:\n    - sppo_sb3.common.action_repeat.ActionRepeat:\n        repeat: 4\n", 250),
    ],
)
def test_a_run_of_held_actions_trains_its_env_steps_in_agent_steps(tmp_path: Path, wrapper: str, agent_steps: int) -> None:
    """``--steps`` counts env steps: where the yml holds each action for k env steps, the train command's ``-n`` (agent
    steps) is a k-th of them, so that every row of a grid sees the same env steps."""
    config = f"SafePointCircle-v0:\n  policy: 'MlpPolicy'\n{wrapper}"
    spec = grid.RunSpec("SafePointCircle-v0", "sppo", 0, str(tmp_path), steps=1000, config_text=config)
    command = runner.train_command(spec, tmp_path / "zoo", tmp_path / "sppo.yml")
    assert command[command.index("-n") + 1] == str(agent_steps)
    assert spec.action_repeat * agent_steps == 1000
