"""The velocity benchmark's read-out: steps to a return, our rows beside OmniSafe's, and ``plot_results --velocity``."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from tiny_hyperparams import TINY_SPPO

from sppo_lab import layout, plot, stats
from sppo_lab.spec import run_name
from sppo_lab.velocity import (
    OMNISAFE_VELOCITY,
    TARGET_TASK,
    efficiency_table,
    late_episodes,
    late_episodes_markdown,
    seed_efficiency,
    steps_to_return,
    target_return,
    velocity_overview_markdown,
    velocity_tables_markdown,
)
from sppo_sb3 import SPPO
from sppo_sb3.common.keys import COST_KEY, INTERVENED_KEY
from sppo_sb3.envs.velocity import ANT

EPISODE = 1000
SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def _curve(returns: list[float], costs: list[float]) -> pd.DataFrame:
    """A learning curve of 1000-step episodes, one second each."""
    n = len(returns)
    return pd.DataFrame(
        {
            "timesteps": EPISODE * np.arange(1, n + 1),
            "episode": np.arange(1, n + 1),
            "return": returns,
            "length": EPISODE,
            "cost": costs,
            "violations": costs,
            "cumulative_violations": np.cumsum(costs),
            "time": np.arange(1, n + 1, dtype=float),
        }
    )


def test_steps_to_return_reads_the_first_episode_whose_window_reaches_it() -> None:
    curve = _curve([0.0, 10.0, 20.0, 30.0, 40.0], [1.0, 2.0, 0.0, 3.0, 0.0])
    # rolling means over 2 episodes: 0, 5, 15, 25, 35; the first at 20 or more is the 4th episode
    assert steps_to_return(curve, 20.0, window=2) == {"steps": 4000.0, "seconds": 4.0, "cost": 6.0, "cost_total": 6.0}
    never = steps_to_return(curve, 36.0, window=2)
    assert np.isnan(never["steps"]) and np.isnan(never["cost"]) and never["cost_total"] == 6.0


def test_efficiency_table_averages_over_the_seeds_that_reached_it() -> None:
    curves = {
        (TARGET_TASK, "sac"): [_curve([0.0, 3000.0], [5.0, 900.0]), _curve([0.0, 1000.0], [0.0, 700.0])],
        (TARGET_TASK, "sppo"): [_curve([0.0, 100.0], [0.0, 0.0])],
    }
    target = target_return()
    assert target == pytest.approx(0.8 * 2833.72)
    runs = seed_efficiency(curves, TARGET_TASK, target)
    table = efficiency_table(runs).set_index("algo")
    # SAC's first seed: the mean of its 2 episodes is 1500 < target, so not reached at 10 episodes' window either
    assert table.loc["sac", "reached"] == 0 and table.loc["sac", "cost_total"] == pytest.approx(802.5)
    single = efficiency_table(seed_efficiency({(TARGET_TASK, "sac"): [_curve([3000.0], [4.0])]}, TARGET_TASK, target))
    assert single.loc[0, "reached"] == 1 and single.loc[0, "steps"] == 1000.0 and single.loc[0, "cost"] == 4.0
    assert table.loc["sppo", "reached"] == 0 and np.isnan(table.loc["sppo", "steps"])


def _episodes(lengths: list[int], returns: list[float], costs: list[float]) -> pd.DataFrame:
    """A learning curve of episodes of the given lengths."""
    return _curve(returns, costs).assign(length=lengths, timesteps=np.cumsum(lengths))


def test_late_episodes_reads_the_episodes_that_end_in_the_last_quarter() -> None:
    # 400 env steps: the last quarter is after step 300, so the episodes ending at 350 and 400 count, not the one at 300
    curve = _episodes([100, 200, 50, 50], [100.0, 500.0, 30.0, 90.0], [0.0, 100.0, 5.0, 15.0])
    assert late_episodes(curve) == pytest.approx({"length": 50.0, "return_per_step": 1.2, "cost_share": 20.0})
    whole = late_episodes(curve, share=1.0)
    assert whole["length"] == 100.0 and whole["return_per_step"] == pytest.approx(1.8)


def test_late_episodes_markdown_gives_each_task_and_algorithm_a_row() -> None:
    falls = _episodes([100, 20, 20], [100.0, 40.0, 40.0], [0.0, 10.0, 10.0])  # late: 20-step episodes at 2 per step
    stays = _episodes([100, 100, 100], [100.0, 100.0, 100.0], [0.0, 0.0, 0.0])
    markdown = late_episodes_markdown({(ANT.env_id, "sac"): [falls, falls], (ANT.env_id, "sppo"): [stays]})
    lines = markdown.splitlines()
    assert "| Method | Seeds | Episode length (steps) | Return per env step | Steps above the limit (%) |" in lines
    assert "| SAC | 2 | 20 [20, 20] | 2.00 [2.00, 2.00] | 50 [50, 50] |" in lines
    assert "| SPPO (ours) | 1 | 100 | 1.00 | 0 |" in lines


def _write_run(
    root: Path, algo: str, seed: int, returns: list[float], costs: list[float], task: str = TARGET_TASK, variant: str = ""
) -> None:
    run_dir = layout.run_dir_for(root, task, run_name(algo, variant), seed)
    run_dir.mkdir(parents=True)
    summary = {"task": task, "algo": algo, "variant": variant, "seed": seed, "steps": EPISODE * len(returns)}
    summary |= {"episodes": len(returns), "return_last_n": float(np.mean(returns[-10:])), "safety_rate": 50.0}
    summary |= {"cumulative_violations": int(sum(costs)), "wall_clock_s": 600.0, "eval_unshielded_violations": 1.5}
    summary |= {"eval_unshielded_return": 2500.0, "cumulative_interventions": 7 if algo == "sppo" else None}
    summary |= {"eval_return": 2600.0, "eval_violations": 0.0 if algo == "sppo" else 1.5}
    layout.write_finished(run_dir, summary, _curve(returns, costs).to_csv(index=False))


def test_velocity_tables_put_omnisafes_published_rows_beside_ours(tmp_path: Path) -> None:
    for seed in (0, 1):
        _write_run(tmp_path, "saclag", seed, [1000.0, 2500.0], [10.0, 0.0])
        _write_run(tmp_path, "sppo", seed, [500.0, 900.0], [0.0, 0.0])
    summaries, _ = stats.load_results(tmp_path)
    markdown = velocity_tables_markdown(stats.aggregate(summaries))
    lines = markdown.splitlines()
    ours = next(line for line in lines if line.startswith("| SPPO"))
    assert ours.startswith(
        "| SPPO (ours) | 2e+03 | 700.0 [700.0, 700.0] | 2600.0 [2600.0, 2600.0] | 0.00 [0.00, 0.00] "
        "| 2500.0 [2500.0, 2500.0] | 1.50 [1.50, 1.50] | 0 [0, 0] |"
    )
    assert ours.endswith("| 7 | 10 |")  # interventions, wall clock in minutes
    published = [line for line in lines if line.startswith("| OmniSafe")]
    assert len(published) == len(OMNISAFE_VELOCITY[TARGET_TASK]) == 4
    assert "| OmniSafe SACLag | 1e+06 | – | – | – | 2833.72 ± 3.62 | 0.00 ± 0.00 |" in markdown
    assert lines.index(ours) < lines.index(published[0])


def test_velocity_overview_sets_sppo_against_the_best_of_the_others(tmp_path: Path) -> None:
    for seed in (0, 1):  # HalfCheetah: SPPO 700 against SACLag's 1750 over 2 seeds
        _write_run(tmp_path, "saclag", seed, [1000.0, 2500.0], [10.0, 0.0])
        _write_run(tmp_path, "sppo", seed, [500.0, 900.0], [0.0, 0.0])
    _write_run(tmp_path, "sppo", 0, [300.0], [0.0], task=ANT.env_id)  # Ant: SPPO 300 against CPO's 200, one seed each
    _write_run(tmp_path, "cpo", 0, [200.0], [4.0], task=ANT.env_id)
    summaries, _ = stats.load_results(tmp_path)
    lines = velocity_overview_markdown(stats.aggregate(summaries)).splitlines()
    assert "| Task | CPO | SACLag | SPPO (ours) | Best of the others | SPPO ≥ it? |" in lines
    assert "| Ant velocity | 200, cost 4, 1 seed | – | 300, cost 0, 1 seed | CPO 200 | yes |" in lines
    cheetah = next(line for line in lines if line.startswith("| HalfCheetah velocity"))
    assert cheetah.endswith("| 700 [700, 700], cost 0, 2 seeds | SACLag 1750 | no |")
    assert "SPPO's mean is at or above the best of the others on 1 of 2 tasks." in lines


def test_the_overview_sets_sppo_against_other_methods_not_its_own_earlier_settings(tmp_path: Path) -> None:
    _write_run(tmp_path, "sppo", 0, [900.0], [0.0], variant="previous")  # SPPO's earlier settings: a column, not a rival
    _write_run(tmp_path, "sppo", 0, [700.0], [0.0])
    _write_run(tmp_path, "sac", 0, [800.0], [0.0], variant="shielded")  # another method behind the shield: a rival
    _write_run(tmp_path, "cpo", 0, [600.0], [5.0])
    summaries, _ = stats.load_results(tmp_path)
    lines = velocity_overview_markdown(stats.aggregate(summaries)).splitlines()
    assert "| Task | CPO | SAC (shielded) | SPPO (ours) | SPPO (ours, previous) | Best of the others | SPPO ≥ it? |" in lines
    cheetah = next(line for line in lines if line.startswith("| HalfCheetah velocity"))
    assert cheetah.endswith("| 900, cost 0, 1 seed | SAC (shielded) 800 | no |")


def test_plot_results_velocity_mode_writes_its_figures_and_tables(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    _write_run(tmp_path, "sac", 0, [1000.0, 3000.0, 3500.0], [0.0, 400.0, 900.0])
    _write_run(tmp_path, "sppo", 0, [200.0, 400.0, 600.0], [0.0, 0.0, 0.0])
    out = tmp_path / "figures"
    assert plot.main([str(tmp_path), "--out", str(out), "--velocity"]) == 0
    for name in (
        "learning_curves.png",
        "cumulative_cost.png",
        "velocity_tables.md",
        "velocity_overview.md",
        "late_episodes.md",
        "sample_efficiency.png",
    ):
        assert (out / name).is_file(), name
    efficiency = (out / "sample_efficiency.md").read_text()
    assert "| SAC | 1 of 1 | 3000 | 0.1 | 1300 | 1300 |" in efficiency  # the window's mean reaches 2267 at episode 3
    assert "| SPPO (ours) | 0 of 1 | – | – | – | 0 |" in efficiency


class _FallingEnv(gym.Env):
    """Falls (terminates) at step 5 of every episode; the step before the last reports an intervention."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,))
    action_space = gym.spaces.Box(-1.0, 1.0, (1,))

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        info = {COST_KEY: float(self.t == 2), INTERVENED_KEY: self.t == 3}
        return np.zeros(1, dtype=np.float32), 1.0, self.t == 5, False, info


class _ConstantPolicy:
    def predict(self, obs: np.ndarray, **kwargs: object) -> tuple[np.ndarray, None]:
        return np.zeros(1, dtype=np.float32), None


def test_deployment_falls_counts_the_falls_after_an_intervention(monkeypatch: pytest.MonkeyPatch) -> None:
    spec = importlib.util.spec_from_file_location("deployment_falls", SCRIPTS / "deployment_falls.py")
    assert spec is not None and spec.loader is not None
    falls = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, falls)  # its dataclass looks its module up
    spec.loader.exec_module(falls)
    deployment = falls.deploy(_ConstantPolicy(), _FallingEnv(), episodes=3, seed=0)
    assert deployment.lengths == [5, 5, 5] and deployment.falls == [True] * 3 and deployment.gaps == [2, 2, 2]
    assert deployment.costs == [1, 1, 1] and deployment.interventions == [1, 1, 1] and deployment.returns == [5.0] * 3
    report = deployment.report("with the shield")
    assert report.startswith("with the shield: return 5.0, length 5.0, fell in 3 of 3 episodes, cost 1.0 and 1.0")
    assert "3 falls came after an intervention: 3 within 10 steps of it (median 2 steps)" in report


def load_value_diagnostic(monkeypatch: pytest.MonkeyPatch) -> Any:
    spec = importlib.util.spec_from_file_location("value_diagnostic", SCRIPTS / "value_diagnostic.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    return module


def test_value_diagnostic_return_to_go(monkeypatch: pytest.MonkeyPatch) -> None:
    diagnostic = load_value_diagnostic(monkeypatch)
    returns = diagnostic.discounted_return_to_go(np.array([1.0, 2.0, 3.0]), 0.5, bootstrap=8.0)
    np.testing.assert_allclose(returns, [1 + 0.5 * 2 + 0.25 * 3 + 0.125 * 8, 2 + 0.5 * 3 + 0.25 * 8, 3 + 0.5 * 8])


def test_value_diagnostic_reports_q_beside_the_return_before_falls(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    diagnostic = load_value_diagnostic(monkeypatch)
    model = SPPO("TOLDPolicy", "sppo_sb3/SafetyHopperVelocity-v1", seed=0, **{**TINY_SPPO, "learning_starts": 50})
    model.learn(60).save(tmp_path / "hopper")
    diagnostic.main([str(tmp_path / "hopper.zip"), "--env", "sppo_sb3/SafetyHopperVelocity-v1", "--episodes", "2"])
    out = capsys.readouterr().out
    assert "2 episodes" in out and "ended in a fall" in out
    assert "| 1–10 |" in out  # an untrained Hopper falls within its first hundred steps
