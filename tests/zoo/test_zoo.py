"""rl-zoo3 integration: train / enjoy through the CLI for every algorithm, the yml files, Optuna with SQLite storage.

Budgets and networks are tiny (50-step episodes through ``--env-kwargs max_episode_steps:50``): this file checks the
plumbing, not learning.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import optuna
import pandas as pd
import pytest
import yaml
from tiny_hyperparams import TINY_ROLLOUT, TINY_ZOO

from sppo_sb3 import zoo
from sppo_sb3.algorithms import ALGORITHMS, DISPLAY_ORDER, ZOO_BASELINES, Algorithm
from sppo_sb3.common.monitor import COST_INFO_KEYWORDS, CostEvalCallback, EpisodeCostInfo, cost_monitored_make_vec_env
from sppo_sb3.shield import ShieldingRule, ShieldWrapper
from sppo_sb3.shield.evaluation import deployment_rule

REPO = Path(__file__).resolve().parents[2]
HYPERPARAMS = REPO / "hyperparams"
LAB_HYPERPARAMS = REPO / "lab" / "hyperparams"
ENV = "SafePointCircle-v0"
SHORT_EPISODES = ["--env-kwargs", "max_episode_steps:50"]

# tiny networks and budgets per algorithm, as rl-zoo3 --hyperparams overrides
TINY: dict[str, list[str]] = {name: TINY_ZOO[name] for name in ("sppo", "pdo", "sailr", "cpo", "csc", "saclag")}
ALGOS = sorted(TINY)


@pytest.fixture(autouse=True)
def _one_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.delenv(zoo.BUDGET_ENV_VAR, raising=False)
    monkeypatch.delenv(zoo.PENALTY_ENV_VAR, raising=False)


def train_args(algo: str, folder: Path, n_timesteps: int = 128, extra: list[str] | None = None) -> list[str]:
    return [
        "--algo", algo, "--env", ENV, "-conf", str(HYPERPARAMS / f"{algo}.yml"), "-n", str(n_timesteps),
        "-f", str(folder), "--seed", "0", "--eval-freq", "-1", "--num-threads", "1", "--device", "cpu",
        *SHORT_EPISODES, "--hyperparams", *TINY[algo], *(extra or []),
    ]  # fmt: skip


def test_all_algorithms_registered() -> None:
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER
    from rl_zoo3.utils import ALGOS as ZOO_ALGOS

    classes = zoo.register_algos()
    assert not zoo.UNAVAILABLE, zoo.UNAVAILABLE
    for name in ALGOS:
        assert ZOO_ALGOS[name] is classes[name]
        assert name in HYPERPARAMS_SAMPLER and name in HYPERPARAMS_CONVERTER


def test_one_list_of_algorithms_drives_the_zoo(monkeypatch: pytest.MonkeyPatch) -> None:
    """The zoo registers exactly the algorithms of ``sppo_sb3.algorithms`` with the search space each one names."""
    from rl_zoo3 import hyperparams_opt as opt

    assert set(TINY) == set(ALGORITHMS)  # this file exercises every algorithm of the list
    assert sorted(DISPLAY_ORDER) == sorted([*ALGORITHMS, *ZOO_BASELINES])  # the plots know each one's place
    classes = zoo.register_algos()
    assert {name: cls.__name__ for name, cls in classes.items()} == {n: a.class_name for n, a in ALGORITHMS.items()}
    assert opt.HYPERPARAMS_SAMPLER["sppo"] is zoo.sample_sppo_params
    assert opt.HYPERPARAMS_SAMPLER["cpo"] is opt.sample_trpo_params
    assert all(opt.HYPERPARAMS_SAMPLER[n] is opt.sample_ppo_params for n in ("pdo", "sailr", "csc"))
    assert opt.HYPERPARAMS_SAMPLER["saclag"] is opt.sample_sac_params
    assert opt.HYPERPARAMS_CONVERTER["saclag"] is opt.convert_offpolicy_params
    # an algorithm added to the list is registered from it; one that does not import is skipped and reported
    broken = Algorithm("broken", "sppo_sb3.no_such_module", "Broken", "Broken", "k", sampler="ppo")
    monkeypatch.setitem(ALGORITHMS, "broken", broken)
    try:
        with pytest.warns(UserWarning, match="'broken' is not available"):
            classes = zoo.register_algos()
        assert "broken" not in classes and set(classes) == set(ALGORITHMS) - {"broken"}
        assert "ModuleNotFoundError" in zoo.UNAVAILABLE["broken"]
    finally:
        zoo.UNAVAILABLE.pop("broken", None)


@pytest.mark.parametrize("algo", ALGOS)
def test_train_then_enjoy(algo: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    from sppo_sb3 import enjoy, train

    train.main(train_args(algo, tmp_path, n_timesteps=150 if algo == "sppo" else 128))
    run = tmp_path / algo / f"{ENV}_1"
    assert (run / f"{ENV}.zip").is_file()
    out = capsys.readouterr().out
    assert f"Safety summary: {algo} on {ENV}" in out and "cumulative violations=" in out

    # monitor.csv carries the episode cost columns
    monitor = pd.read_csv(run / "0.monitor.csv", skiprows=1)
    assert set(COST_INFO_KEYWORDS) <= set(monitor.columns) and len(monitor) >= 2
    assert (monitor["episode_violations"] <= monitor["l"]).all()

    cls = zoo.algo_classes()[algo]
    loaded: list[Any] = []
    original = cls.load.__func__  # type: ignore[attr-defined]

    def spy(klass: type, *args: Any, **kwargs: Any) -> Any:
        model = original(klass, *args, **kwargs)
        loaded.append(model)
        return model

    monkeypatch.setattr(cls, "load", classmethod(spy))
    enjoy.main(["--algo", algo, "--env", ENV, "-f", str(tmp_path), "--no-render", "-n", "60", "--device", "cpu"])
    out = capsys.readouterr().out
    assert "Episode Reward" in out and "Episode cost:" in out
    assert len(loaded) == 1
    if algo == "sppo":
        assert loaded[0].replay_buffer is None  # watching a model allocates no replay buffer
    if algo == "csc":
        assert loaded[0]._cost_buffer is None  # nor a cost buffer


def test_train_cli_prints_safety_summary(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "sppo_sb3.train", *train_args("pdo", tmp_path, 128)]
    cmd[cmd.index("--eval-freq") + 1] = "64"
    cmd += ["--eval-episodes", "2", "--deployment-episodes", "2"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"Safety summary: pdo on {ENV}" in result.stdout
    assert "cumulative violations=" in result.stdout and "safety rate=" in result.stdout
    assert "eval/" in result.stdout and "mean_cost" in result.stdout
    assert "with / without the shield" in result.stdout and "eval_unshielded/" in result.stdout

    run = tmp_path / "pdo" / f"{ENV}_1"
    summary = json.loads((run / "safety_summary.json").read_text())
    assert summary["num_timesteps"] == 128 and summary["episodes"] >= 2
    assert {"cumulative_violations", "safety_rate", "ep_return_mean", "eval_mean_cost", "deployment"} <= set(summary)
    assert set(summary["deployment"]) == {"eval", "eval_unshielded"}
    assert set(summary["deployment"]["eval_unshielded"]) == {
        "mean_reward",
        "mean_violations",
        "safe_episode_rate",
        "mean_interventions",
    }
    evaluations = np.load(run / "evaluations.npz")
    assert evaluations["costs"].shape == evaluations["results"].shape == (2, 2)


def test_train_cli_deploys_a_zoo_algorithm_that_keeps_no_safety_metrics(tmp_path: Path) -> None:
    """rl-zoo3's own SAC keeps no safety metrics: its training costs are monitor.csv's, and its final policy's deployment
    is still measured and saved, so a grid's table has the unconstrained reference's deployed cost too."""
    from sppo_lab.spec import RunSpec
    from sppo_lab.summary import model_safety_summary, read_monitor_curve, summarize

    cmd = [sys.executable, "-m", "sppo_sb3.train", "--algo", "sac", "--env", ENV, "-n", "128", "-f", str(tmp_path)]
    cmd += ["--seed", "0", "--eval-freq", "-1", "--num-threads", "1", "--device", "cpu", *SHORT_EPISODES]
    cmd += ["--hyperparams", "learning_starts:64", "policy_kwargs:dict(net_arch=[8])", "--deployment-episodes", "2"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "SAC keeps no safety metrics" in result.stdout and "eval_unshielded/" in result.stdout

    safety = model_safety_summary(tmp_path)
    assert safety is not None and set(safety) == {"num_timesteps", "deployment"} and safety["num_timesteps"] == 128
    curve = read_monitor_curve(tmp_path)
    summary = summarize(RunSpec(ENV, "sac", 0, str(tmp_path)), curve, safety, 1.0, cmd)
    assert summary["safety_source"] == "monitor" and summary["episodes"] == len(curve) >= 2
    assert summary["cumulative_violations"] == int(curve["violations"].sum())
    assert summary["eval_unshielded_return"] == safety["deployment"]["eval_unshielded"]["mean_reward"]
    assert 0.0 <= summary["eval_unshielded_safe_rate"] <= 100.0


def _yml_file_entries() -> list[tuple[Path, str]]:
    """Every entry of the production files, ``hyperparams/*.yml`` and its suite folders, and of the lab's probe and sweep
    configs (``lab/hyperparams/``), which the benchmark's resume must still build (the dm_control ones have
    test_dmc.py)."""
    suites = [path for path in sorted(HYPERPARAMS.glob("*/**/*.yml")) if path.relative_to(HYPERPARAMS).parts[0] != "dmc"]
    lab = [
        path for path in sorted(LAB_HYPERPARAMS.glob("**/*.yml")) if path.relative_to(LAB_HYPERPARAMS).parts[0] != "dmc_cpu"
    ]
    files = sorted(HYPERPARAMS.glob("*.yml")) + suites + lab
    return [(path, env_id) for path in files for env_id in yaml.safe_load(path.read_text())]


def _yml_entries() -> list[tuple[str, str]]:
    """``(algo, env_id)`` of the top-level yml files, the ones ``sppo-train --algo ALGO`` reads by default."""
    return [(path.stem, env_id) for path, env_id in _yml_file_entries() if path.parent == HYPERPARAMS]


def test_yml_coverage() -> None:
    entries = set(_yml_entries())
    for algo in ALGOS:
        assert {(algo, "SafePointCircle-v0"), (algo, "SafeHalfCheetahHeight-v1")} <= entries
    assert {("sppo", "Pendulum-v1"), ("sppo", "HalfCheetah-v5")} <= entries


def _entry_id(value: object) -> str:
    return str(value.relative_to(REPO)) if isinstance(value, Path) else str(value)


#: tasks of hyperparams/ that an example registers (``--gym-packages examples.<module>``)
EXAMPLE_TASKS = {"ConstrainedPendulum-v0": "constrained_pendulum"}


@pytest.mark.parametrize(("config", "env_id"), _yml_file_entries(), ids=_entry_id)
def test_yml_entry_constructs(config: Path, env_id: str, tmp_path: Path, load_example: Callable[[str], ModuleType]) -> None:
    """Each entry, processed by rl-zoo3's own code (schedules, policy_kwargs, normalize, ...), builds its model."""
    algo = config.stem
    if env_id in EXAMPLE_TASKS:
        load_example(EXAMPLE_TASKS[env_id])
    manager_cls = zoo.install()
    manager = manager_cls(argparse.Namespace(), algo, env_id, str(tmp_path), eval_freq=-1, config=str(config), verbose=0)
    from rl_zoo3.utils import ALGOS as ZOO_ALGOS

    cls = zoo.algo_classes().get(algo) or ZOO_ALGOS[algo]  # the package's, or one of rl-zoo3's (velocity/sac.yml)
    accepted = set(inspect.signature(cls.__init__).parameters)
    unprocessed, _ = manager.read_hyperparameters()
    hyperparams, *_ = manager._preprocess_hyperparams(dict(unprocessed))
    unknown = set(hyperparams) - accepted
    assert not unknown, f"{algo}.yml[{env_id}] has keys {cls.__name__} does not accept: {unknown}"
    model, _ = manager.setup_experiment()
    assert isinstance(model, cls)
    assert model.n_envs >= 1
    if "ShieldWrapper" in str(unprocessed.get("env_wrapper", "")):  # shielded through rl-zoo3's env_wrapper
        assert isinstance(deployment_rule(model), ShieldingRule)
    model.env.close()


def test_sppo_sampler_builds_models() -> None:
    from sppo_sb3.sppo import SPPO

    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(3):
        params = zoo.sample_sppo_params(study.ask(), 1, 1, {})
        assert params["planner_kwargs"]["num_elites"] <= params["planner_kwargs"]["num_samples"]
        SPPO("TOLDPolicy", "Pendulum-v1", shield=None, **params)
    trial = study.trials[0]
    assert zoo.convert_sppo_params(trial.params) == zoo.sample_sppo_params(optuna.trial.FixedTrial(trial.params), 1, 1, {})


def test_saclag_sampler_builds_models() -> None:
    """rl-zoo3's SAC search space (registered for SACLag) gives SACLag arguments it accepts."""
    from rl_zoo3 import hyperparams_opt as opt

    from sppo_sb3.saclag import SACLag

    zoo.register_algos()
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(2):
        params = opt.HYPERPARAMS_SAMPLER["saclag"](study.ask(), 1, 1, {"using_her_replay_buffer": False})
        model = SACLag("MlpPolicy", ENV, buffer_size=1_000, **params)
        assert model.batch_size == params["batch_size"] and model.gradient_steps == params["gradient_steps"]


def test_optimize_with_sqlite_storage(tmp_path: Path) -> None:
    """Two trials through rl-zoo3's -optimize on an RDB (SQLite) study, with the violation penalty objective."""
    from sppo_sb3 import train

    storage = f"sqlite:///{tmp_path / 'study.db'}"
    args = train_args("pdo", tmp_path, 128)
    args[args.index("--eval-freq") : args.index("--eval-freq") + 2] = []
    args += ["-optimize", "--n-trials", "2", "--n-jobs", "1", "--sampler", "random", "--pruner", "none"]
    args += ["--n-evaluations", "1", "--eval-episodes", "1", "--storage", storage, "--study-name", "pdo_point"]
    args += ["--no-optim-plots", "--violation-budget", "-1", "--violation-penalty", "10"]
    train.main(args)

    study = optuna.load_study(study_name="pdo_point", storage=storage)
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(complete) == 2
    for trial in complete:
        attrs = trial.user_attrs
        assert attrs["violation_budget"] == -1 and attrs["violation_budget_mode"] == "penalty"
        expected = attrs["eval_mean_reward"] - 10 * (attrs["cumulative_violations"] + 1)
        assert trial.value == pytest.approx(expected)
        assert "n_steps_pow" in trial.params

    # --trial-id: the trial's values, with the *_kwargs fields it did not search kept from the yml
    manager = zoo.install()(argparse.Namespace(), "pdo", ENV, str(tmp_path), config=str(HYPERPARAMS / "pdo.yml"), verbose=0)
    params = manager.load_trial(storage, "pdo_point", trial_id=1)
    assert params["n_steps"] == 2 ** study.trials[1].params["n_steps_pow"]
    assert params["policy_kwargs"]["cost_net_arch"] == [64, 64] and "activation_fn" in params["policy_kwargs"]


def test_violation_budget_prunes(tmp_path: Path) -> None:
    from sppo_sb3.pdo import PDO

    zoo.install()
    callback_cls = zoo.SafeTrialEvalCallback
    study = optuna.create_study()
    trial = study.ask()
    trial.set_user_attr("violation_budget", 2.0)
    trial.set_user_attr("violation_budget_mode", "prune")
    eval_env = cost_monitored_make_vec_env(ENV, n_envs=1, env_kwargs={"max_episode_steps": 50})
    model = PDO("MlpPolicy", ENV, **TINY_ROLLOUT, policy_kwargs={"net_arch": [8]})
    callback = callback_cls(eval_env, trial, eval_freq=1000)
    callback.init_callback(model)
    assert callback.on_step()
    model.safety_metrics.violations = 3
    assert not callback.on_step() and callback.is_pruned
    assert trial.user_attrs["budget_exceeded_at"] == 0


def test_record_video(tmp_path: Path) -> None:
    pytest.importorskip("moviepy")
    from sppo_sb3 import record_video, train

    train.main(train_args("pdo", tmp_path, 64))
    videos = tmp_path / "videos"
    record_video.main(["--algo", "pdo", "--env", ENV, "-f", str(tmp_path), "-n", "20", "-o", str(videos), "--no-render"])
    assert list(videos.glob("*.mp4"))


def test_episode_interventions_count_a_shield_wrappers_replacements(tmp_path: Path) -> None:
    """monitor.csv's episode_interventions: the ShieldWrapper's replaced actions per episode, NaN without a shield; a
    run's summary reads them (an rl-zoo3 algorithm behind the shield keeps no safety metrics of its own)."""
    import gymnasium as gym
    from stable_baselines3.common.monitor import Monitor

    from sppo_lab.summary import monitor_interventions

    for name, shielded in (("shielded", True), ("alone", False)):
        env: gym.Env = gym.make(ENV, max_episode_steps=40)
        env = Monitor(
            EpisodeCostInfo(ShieldWrapper(env, "auto") if shielded else env),
            filename=str(tmp_path / name / "0"),
            info_keywords=COST_INFO_KEYWORDS,
        )
        env.reset(seed=0)
        replaced, done, info = 0, False, {}
        while not done:  # full thrust along x: into the Point's wall
            _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
            replaced += int(info.get("shield_intervened", False))
            done = terminated or truncated
        env.close()
        if shielded:
            assert info["episode_interventions"] == replaced > 0
            assert monitor_interventions(tmp_path / name) == replaced
        else:
            assert np.isnan(info["episode_interventions"]) and info["episode_violations"] > 0
            assert monitor_interventions(tmp_path / name) is None


def test_episode_cost_info_and_eval_callback(tmp_path: Path) -> None:
    import gymnasium as gym
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.monitor import Monitor

    env = Monitor(EpisodeCostInfo(gym.make(ENV, max_episode_steps=20)), info_keywords=COST_INFO_KEYWORDS)
    env.reset(seed=0)
    total, done, info = 0.0, False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        total += info["cost"]
        done = terminated or truncated
    assert info["episode"]["episode_cost"] == total == info["episode_cost"]

    from sppo_sb3.pdo import PDO

    eval_env = cost_monitored_make_vec_env(ENV, n_envs=2, env_kwargs={"max_episode_steps": 20})
    model = PDO("MlpPolicy", ENV, **{**TINY_ROLLOUT, "n_steps": 32}, policy_kwargs={"net_arch": [8]})
    model.set_logger(Logger(folder=None, output_formats=[]))
    callback = CostEvalCallback(eval_env, n_eval_episodes=3, eval_freq=1, log_path=str(tmp_path), verbose=0)
    callback.init_callback(model)
    callback.on_step()
    data = np.load(tmp_path / "evaluations.npz")
    assert data["costs"].shape == (1, 3) and data["violations"].shape == (1, 3)
    assert np.isfinite(callback.last_mean_cost)


def test_constructor_kwargs_are_the_yml_entry_as_the_constructor_takes_it(tmp_path: Path) -> None:
    path = tmp_path / "sppo.yml"
    path.write_text(
        "MyTask-v0:\n  n_timesteps: !!float 1e4\n  policy: 'TOLDPolicy'\n  shield: 'auto'\n  normalize: true\n"
        '  env_wrapper: [gymnasium.wrappers.ClipAction]\n  policy_kwargs: "dict(latent_dim=8)"\n'
        '  planner_kwargs: "dict(num_samples=16)"\n  batch_size: 32\n'
    )
    kwargs = zoo.constructor_kwargs(path, "MyTask-v0")
    assert kwargs == {
        "policy": "TOLDPolicy",
        "shield": "auto",
        "policy_kwargs": {"latent_dim": 8},
        "planner_kwargs": {"num_samples": 16},
        "batch_size": 32,
    }
    with pytest.raises(KeyError, match=r"has no entry for Other-v0 \(it has: MyTask-v0\)"):
        zoo.constructor_kwargs(path, "Other-v0")


def test_monitor_records_the_episodes_an_absorbing_shield_ends(tmp_path: Path) -> None:
    """rl-zoo3's env_wrapper goes inside Monitor: an episode that ShieldWrapper ends at an intervention is recorded."""
    shield = {"rule": "auto", "on_intervention": "terminate"}
    env = cost_monitored_make_vec_env(
        "SafePointCircle-v0", 1, wrapper_class=ShieldWrapper, wrapper_kwargs=shield, monitor_dir=str(tmp_path)
    )
    env.reset()
    for _ in range(500):  # full thrust along x, into the wall
        _, _, dones, infos = env.step(np.array([[1.0, 0.0]]))
        if infos[0].get("shield_absorbed"):
            break
    assert infos[0]["shield_absorbed"] and dones[0] and "episode" in infos[0]
    assert len(pd.read_csv(next(tmp_path.glob("*monitor.csv")), skiprows=1)) == 1


def test_train_cli_writes_the_records_of_costly_episodes_to_the_run_folder(tmp_path: Path, capsys) -> None:
    """Every episode that paid cost behind a ShieldWrapper lands in ``costly_episodes/`` of the run folder, replayable."""
    from types import SimpleNamespace

    import gymnasium as gym
    from recording import AcceptsAll
    from stable_baselines3.common.vec_env import DummyVecEnv

    from sppo_sb3.shield.records import CostlyEpisode
    from sppo_sb3.zoo.experiment import SafeExperimentManager

    env = DummyVecEnv([lambda: ShieldWrapper(gym.make(ENV), AcceptsAll())])
    env.seed(3)
    env.reset()
    for _ in range(60):  # full thrust, nothing shielded: into the wall, the episode ends and another starts
        env.step(np.array([[1.0, 0.3]], dtype=np.float32))
    manager = SimpleNamespace(save_path=str(tmp_path))
    SafeExperimentManager.save_costly_episodes(manager, SimpleNamespace(get_env=lambda: env))  # type: ignore[arg-type]
    saved = sorted((tmp_path / "costly_episodes").glob("*.json"))
    assert saved and CostlyEpisode.load(saved[0]).costly_steps
    assert "replay_costly.py" in capsys.readouterr().out
