"""Fig. 7's dm_control tasks (:mod:`sppo_sb3.envs.dmc`): the action-repeat wrapper, the registered ids, and a few
training steps of each Fig. 7 algorithm through ``sppo-train``.

The tests that make a dm_control env are skipped where the ``dmc`` extra is not installed; CI runs them in a second
virtual environment that has it (``.ci/run``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
import yaml
from tiny_hyperparams import TINY_ZOO

from sppo_lab import benchmark, grid
from sppo_sb3 import zoo
from sppo_sb3.envs.dmc import ACTION_REPEAT, FIG7_DMC_TASKS, INSTALL_HINT, ActionRepeat, action_repeat, dmc_id

REPO = Path(__file__).resolve().parents[2]
DMC_HYPERPARAMS = REPO / "hyperparams" / "dmc"
TASK = "cartpole-swingup"
ENV = dmc_id(TASK)
CARTPOLE_REPEAT = 8
CARTPOLE_EPISODE = 1000 // CARTPOLE_REPEAT

# tiny networks and budgets, as rl-zoo3 --hyperparams overrides (plumbing, not learning)
TINY: dict[str, list[str]] = {name: TINY_ZOO[name] for name in ("sppo", "ddpg", "ppo")}


class CountingEnv(gym.Env):
    """Reward ``1`` per step, observation the step count; terminates after ``length`` steps."""

    observation_space = gym.spaces.Box(0.0, np.inf, (1,))
    action_space = gym.spaces.Box(-1.0, 1.0, (1,))

    def __init__(self, length: int) -> None:
        self.length = length
        self.steps = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.steps = 0
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.steps += 1
        return np.array([self.steps], dtype=np.float32), 1.0, self.steps >= self.length, False, {"step": self.steps}


def test_action_repeat_sums_rewards_and_stops_at_the_end() -> None:
    env = ActionRepeat(CountingEnv(length=10), repeat=4)
    env.reset()
    assert env.step(np.zeros(1)) == (np.array([4.0]), 4.0, False, False, {"step": 4})
    env.step(np.zeros(1))
    obs, reward, terminated, truncated, info = env.step(np.zeros(1))  # 2 inner steps left: stops at termination
    assert obs[0] == 10 and reward == 2.0 and terminated and not truncated and info == {"step": 10}
    with pytest.raises(ValueError, match="at least 1"):
        ActionRepeat(CountingEnv(length=10), repeat=0)


def test_td_mpc_action_repeats() -> None:
    assert {task: action_repeat(task) for task in FIG7_DMC_TASKS} == {
        "cartpole-swingup": 8,
        "finger-spin": 2,
        "hopper-hop": 4,
        "cheetah-run": 4,
        "walker-run": 2,
        "quadruped-run": 4,
    }
    assert ACTION_REPEAT["cartpole"] == CARTPOLE_REPEAT


def test_ids_registered_and_missing_extra_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    import sppo_sb3  # noqa: F401  (registers the ids)

    assert all(dmc_id(task) in gym.registry for task in FIG7_DMC_TASKS)
    for module in ("dm_control", "shimmy"):
        monkeypatch.setitem(sys.modules, module, None)  # as if not installed
    with pytest.raises(ImportError, match=r'pip install "sppo_sb3\[dmc\]"'):
        gym.make(ENV)
    assert "sppo_sb3[dmc]" in INSTALL_HINT


def test_benchmark_fig7_task_sets(tmp_path: Path) -> None:
    """``--fig7`` keeps the MuJoCo tasks and the given config folder; ``--fig7 dmc`` runs the six dm_control tasks."""
    default = benchmark.parse_args(["--fig7"], default_hyperparams_dir=tmp_path)
    assert benchmark.grid_axes(default)[1] == list(grid.FIG7_TASKS) and default.hyperparams_dir == tmp_path
    dmc = benchmark.parse_args(["--fig7", "dmc"], default_hyperparams_dir=tmp_path)
    assert benchmark.grid_axes(dmc)[:2] == (["sppo", "ddpg", "ppo"], [dmc_id(task) for task in FIG7_DMC_TASKS])
    assert dmc.hyperparams_dir == tmp_path / "dmc"
    given = benchmark.parse_args(["--fig7", "dmc", "--hyperparams-dir", str(REPO)], default_hyperparams_dir=tmp_path)
    assert given.hyperparams_dir == REPO


def test_benchmark_fig7_dmc_configs_every_run(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Every (algorithm, task) pair of ``--fig7 dmc`` has an entry in ``hyperparams/dmc`` (a dry run needs no dm_control)."""
    argv = ["--fig7", "dmc", "--seeds", "1", "--dry-run", "--out", str(tmp_path)]
    assert benchmark.main(argv, default_hyperparams_dir=REPO / "hyperparams") == 0
    commands = [line for line in capsys.readouterr().out.splitlines() if "sppo_sb3.train" in line]
    assert len(commands) == 3 * len(FIG7_DMC_TASKS)
    assert all("-conf" in command for command in commands)


@pytest.fixture
def dm_control() -> None:
    pytest.importorskip("dm_control")
    pytest.importorskip("shimmy")


@pytest.mark.usefixtures("dm_control")
def test_cartpole_shapes_and_action_repeat() -> None:
    env = gym.make(ENV)
    inner = gym.make(f"dm_control/{TASK}-v0")
    assert env.observation_space.shape == (5,) and env.action_space.shape == (1,)
    obs, _ = env.reset(seed=3)
    inner_obs, _ = inner.reset(seed=3)
    assert obs.shape == (5,) and env.observation_space.contains(obs)
    np.testing.assert_allclose(obs, gym.spaces.flatten(inner.observation_space, inner_obs))
    action = np.array([0.5])
    obs, reward, *_ = env.step(action)
    inner_steps = [inner.step(action) for _ in range(CARTPOLE_REPEAT)]  # the same action, held for 8 physics steps
    assert reward == pytest.approx(sum(float(step[1]) for step in inner_steps))
    np.testing.assert_allclose(obs, gym.spaces.flatten(inner.observation_space, inner_steps[-1][0]))
    steps, done = 1, False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        steps, done = steps + 1, terminated or truncated
    assert steps == CARTPOLE_EPISODE and truncated and not terminated
    env.close()
    inner.close()


@pytest.mark.usefixtures("dm_control")
@pytest.mark.parametrize("algo", sorted(TINY))
def test_fig7_algorithm_trains_on_cartpole(algo: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from sppo_sb3 import train

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    n_timesteps = CARTPOLE_EPISODE + 25  # one full episode, and past sppo/ddpg's learning_starts and ppo's rollout
    train.main(
        [
            "--algo", algo, "--env", ENV, "-conf", str(DMC_HYPERPARAMS / f"{algo}.yml"), "-n", str(n_timesteps),
            "-f", str(tmp_path), "--seed", "0", "--eval-freq", "-1", "--num-threads", "1", "--device", "cpu",
            "--deployment-episodes", "0", "--hyperparams", *TINY[algo],
        ]
    )  # fmt: skip
    run = tmp_path / algo / f"{ENV}_1"
    assert (run / f"{ENV}.zip").is_file()
    monitor = pd.read_csv(run / "0.monitor.csv", skiprows=1)
    assert list(monitor["l"]) == [CARTPOLE_EPISODE]  # 1000 dm_control steps / action repeat 8


def _dmc_yml_entries() -> list[tuple[str, str]]:
    return [
        (path.stem, env_id) for path in sorted(DMC_HYPERPARAMS.glob("*.yml")) for env_id in yaml.safe_load(path.read_text())
    ]


def test_dmc_yml_covers_fig7() -> None:
    assert set(_dmc_yml_entries()) == {(algo, dmc_id(task)) for algo in grid.FIG7_ALGOS for task in FIG7_DMC_TASKS}


@pytest.mark.usefixtures("dm_control")
@pytest.mark.parametrize(("algo", "env_id"), _dmc_yml_entries())
def test_dmc_yml_entry_constructs(algo: str, env_id: str, tmp_path: Path) -> None:
    """Each entry, processed by rl-zoo3's own code, builds its model on its task; budgets are 100k env steps."""
    manager_cls = zoo.install()
    config = str(DMC_HYPERPARAMS / f"{algo}.yml")
    manager = manager_cls(argparse.Namespace(), algo, env_id, str(tmp_path), eval_freq=-1, config=config, verbose=0)
    model, _ = manager.setup_experiment()
    assert model.n_envs == 1
    assert manager.n_timesteps * action_repeat(env_id.removeprefix("DMC-").removesuffix("-v0")) == 100_000
    model.env.close()
