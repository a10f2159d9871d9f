"""Run the paper's comparison grid (algorithms × tasks × seeds) through the package's own training entry point.

Every run is ``python -m sppo_sb3.train --algo ALGO --env TASK [-conf HYPERPARAMS/ALGO.yml] [-n STEPS] --seed S ...``
in a subprocess, so it is exactly what a user gets from ``sppo-train``. Runs go to parallel local processes
(``--workers``, default: the number of cores) or, with ``--ray-address``, to Ray tasks on an existing cluster.

Each run writes, under ``OUT/<task>/<algo>/seed_<s>/``:

- ``curve.csv``: one row per finished training episode: ``timesteps`` (env steps at its end), ``episode``,
  ``return``, ``length``, ``cost``, ``violations``, ``cumulative_violations``, ``time`` (from rl-zoo3's ``monitor.csv``
  with the package's ``episode_cost``/``episode_violations`` columns);
- ``summary.json``: return (mean of the last ``--last-n`` episodes), cumulative violations, safety rate, episodes,
  shield interventions (algorithms that keep :class:`~sppo_sb3.common.safety.SafetyMetrics`), wall-clock seconds of
  the train command, env steps per second (``steps_per_s``: over the whole command, start-up included;
  ``train_steps_per_s``: from the monitor's clock, env creation to the last finished episode), the command;
- ``hyperparams.yml`` (the exact config used, when one is passed), ``train.log`` (the run's output) and ``zoo/``
  (rl-zoo3's run folder: model, monitor.csv, args);
- ``DONE``: the marker of a finished run; a run with it is skipped (``--force`` reruns it). A run that failed
  leaves ``FAILED`` (its log tail) and is retried by the next invocation.

The algorithms are the package's (``sppo pdo cpo sailr csc``, configured by ``--hyperparams-dir``) and any of
rl-zoo3's built-in ones (``ppo``, ``ddpg``, ``sac`` ...; rl-zoo3's own hyperparameters, or ``--hyperparams-dir/ALGO.yml``
when it has the task), e.g. for the Fig. 7 comparison (``--fig7``). rl-zoo3 ships MuJoCo entries for ``-v4`` tasks
only: for ``HalfCheetah-v5`` the runner then writes the ``HalfCheetah-v4`` entry under the ``-v5`` id into the run's
``hyperparams.yml`` and passes it with ``-conf``.

Examples::

    python scripts/benchmark.py --quick --out results/quick
    python scripts/benchmark.py --tasks SafePointCircle-v0 --seeds 8 --out results/paper   # paper scale, Table I
    python scripts/benchmark.py --fig7 --seeds 3 --steps 100000 --out results/fig7
    python scripts/benchmark.py --ray-address auto --seeds 8 --out /shared/results         # on a Ray cluster
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

#: the package's algorithms (configured by ``--hyperparams-dir/ALGO.yml``)
OUR_ALGOS: tuple[str, ...] = ("sppo", "pdo", "cpo", "sailr", "csc")
#: the paper's constrained tasks (Tables I and II)
SAFE_TASKS: tuple[str, ...] = ("SafePointCircle-v0", "SafeHalfCheetahHeight-v1")
#: Fig. 7: SPPO's planning-guided exploration against SB3's DDPG and PPO on gymnasium MuJoCo tasks
FIG7_ALGOS: tuple[str, ...] = ("sppo", "ddpg", "ppo")
FIG7_TASKS: tuple[str, ...] = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5")
#: ``--quick``: a few minutes on a laptop (on-policy algorithms still collect one full rollout of ``n_steps``)
QUICK_STEPS: dict[str, int] = {"SafePointCircle-v0": 2048, "SafeHalfCheetahHeight-v1": 256}
QUICK_DEFAULT_STEPS = 2048
QUICK_SEEDS = 2
#: what ``--quick`` runs when no ``--tasks`` are given (the Cheetah's MPC shield is slow on a CPU)
QUICK_TASKS: tuple[str, ...] = ("SafePointCircle-v0",)
#: files of a run folder
DONE_FILE, FAILED_FILE, SUMMARY_FILE, CURVE_FILE, LOG_FILE, CONFIG_FILE = (
    "DONE",
    "FAILED",
    "summary.json",
    "curve.csv",
    "train.log",
    "hyperparams.yml",
)
CURVE_COLUMNS: tuple[str, ...] = (
    "timesteps",
    "episode",
    "return",
    "length",
    "cost",
    "violations",
    "cumulative_violations",
    "time",
)
DEFAULT_HYPERPARAMS_DIR = Path(__file__).resolve().parents[1] / "hyperparams"
#: largest ``train.log`` a Ray task sends back to the driver (its tail)
MAX_REMOTE_LOG_CHARS = 200_000


@dataclass
class RunSpec:
    """One run of the grid.

    :param task: gymnasium id of the task.
    :param algo: rl-zoo3 name of the algorithm.
    :param seed: random seed.
    :param run_dir: the run's output folder (``OUT/<task>/<algo>/seed_<s>``), as seen by the driver.
    :param steps: env steps (``-n``); ``None``: the hyperparameter file's ``n_timesteps``.
    :param config_text: the yml given to ``-conf`` (written into the run folder); ``None``: rl-zoo3's own.
    :param device: PyTorch device (``--device`` of the train command).
    :param zoo_args: extra arguments for the train command (after the runner's own, so they win).
    :param last_n: number of final episodes averaged into the reported return.
    """

    task: str
    algo: str
    seed: int
    run_dir: str
    steps: int | None = None
    config_text: str | None = None
    device: str = "auto"
    zoo_args: list[str] = field(default_factory=list)
    last_n: int = 10

    @property
    def label(self) -> str:
        """``task / algo / seed`` for progress lines."""
        return f"{self.task} / {self.algo} / seed {self.seed}"


def task_dirname(task: str) -> str:
    """Folder name of a task id (``dm_control/cheetah-run-v0`` -> ``dm_control_cheetah-run-v0``).

    :param task: gymnasium id.
    """
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", task)


def run_dir_for(out: Path, task: str, algo: str, seed: int) -> Path:
    """``OUT/<task>/<algo>/seed_<s>``.

    :param out: the grid's output folder.
    :param task: gymnasium id.
    :param algo: algorithm name.
    :param seed: seed.
    """
    return out / task_dirname(task) / algo / f"seed_{seed}"


# ---------------------------------------------------------------------------------------------------- hyperparams
def _load_yml(path: Path) -> dict[str, Any]:
    with open(path) as file:
        return dict(yaml.safe_load(file) or {})


def _zoo_hyperparams_path(algo: str) -> Path:
    """rl-zoo3's own ``hyperparams/ALGO.yml`` (located without importing rl-zoo3, which is slow to import)."""
    spec = importlib.util.find_spec("rl_zoo3")
    if spec is None or spec.origin is None:
        raise ValueError("rl-zoo3 is not installed")
    return Path(spec.origin).parent / "hyperparams" / f"{algo}.yml"


def _other_versions(task: str, entries: dict[str, Any]) -> list[str]:
    """Keys of ``entries`` that are ``task`` with another ``-vN`` suffix, newest first."""
    match = re.fullmatch(r"(.+)-v(\d+)", task)
    if match is None:
        return []
    base = match.group(1)
    found = [(int(m.group(1)), key) for key in entries if (m := re.fullmatch(re.escape(base) + r"-v(\d+)", key))]
    return [key for _, key in sorted(found, reverse=True)]


def resolve_config(algo: str, task: str, hyperparams_dir: Path) -> str | None:
    """The yml to pass with ``-conf`` for ``algo`` on ``task`` (``None``: rl-zoo3's own file has the task).

    The package's algorithms read ``hyperparams_dir/ALGO.yml`` (it must have an entry for the task). rl-zoo3's
    built-in algorithms read ``hyperparams_dir/ALGO.yml`` when it exists and has the task, else rl-zoo3's own file; when
    that one only has another version of the task (``HalfCheetah-v4`` for ``HalfCheetah-v5``), its entry is copied
    under the requested id (rather than falling back to the file's generic ``default`` entry).

    :param algo: algorithm name.
    :param task: gymnasium id.
    :param hyperparams_dir: folder of the package's hyperparameter files.
    :raises ValueError: no hyperparameters for the pair.
    """
    own = hyperparams_dir / f"{algo}.yml"
    if algo in OUR_ALGOS or own.exists():
        if own.exists():
            entries = _load_yml(own)
            if task in entries or "default" in entries:
                return own.read_text()
            if algo in OUR_ALGOS:
                raise ValueError(f"{own} has no entry for {task} (it has: {', '.join(entries)}); add one")
        elif algo in OUR_ALGOS:
            raise ValueError(f"no hyperparameter file {own} for the package's algorithm {algo!r} (see --hyperparams-dir)")
    zoo_file = _zoo_hyperparams_path(algo)
    if not zoo_file.exists():
        raise ValueError(
            f"{algo!r} is neither one of the package's algorithms {OUR_ALGOS} nor one with rl-zoo3 hyperparameters"
        )
    entries = _load_yml(zoo_file)
    versions = _other_versions(task, entries)
    if task in entries or (not versions and "default" in entries):
        return None
    if not versions:
        raise ValueError(f"rl-zoo3's {zoo_file.name} has no entry for {task}; put one in {own}")
    header = f"# rl-zoo3's {algo} hyperparameters for {versions[0]} (its {zoo_file.name} has no {task} entry)\n"
    return header + yaml.safe_dump({task: entries[versions[0]]}, sort_keys=False)


# ---------------------------------------------------------------------------------------------------- one run
def train_command(spec: RunSpec, zoo_dir: Path, config_path: Path | None, python: str | None = None) -> list[str]:
    """The ``python -m sppo_sb3.train ...`` command of a run.

    :param spec: the run.
    :param zoo_dir: rl-zoo3's log folder (``-f``).
    :param config_path: the yml for ``-conf`` (``None``: rl-zoo3's own).
    :param python: the interpreter (default: this one).
    """
    cmd = [python or sys.executable, "-m", "sppo_sb3.train", "--algo", spec.algo, "--env", spec.task]
    if config_path is not None:
        cmd += ["-conf", str(config_path)]
    if spec.steps is not None:
        cmd += ["-n", str(int(spec.steps))]
    cmd += ["--seed", str(spec.seed), "-f", str(zoo_dir), "--eval-freq", "-1", "--num-threads", "1"]
    cmd += ["--device", spec.device, *spec.zoo_args]
    return cmd


def read_monitor_curve(zoo_dir: Path) -> pd.DataFrame:
    """The learning curve of a run from rl-zoo3's ``*.monitor.csv`` files (all training envs, in time order).

    :param zoo_dir: rl-zoo3's log folder of the run (searched recursively).
    :return: a frame with :data:`CURVE_COLUMNS` (empty when no episode finished).
    """
    frames = []
    for path in sorted(zoo_dir.rglob("*monitor.csv")):
        frame = pd.read_csv(path, skiprows=1)
        if not frame.empty:
            frames.append(frame)
    if not frames:
        return pd.DataFrame({column: pd.Series(dtype=float) for column in CURVE_COLUMNS})
    monitor = pd.concat(frames, ignore_index=True).sort_values("t", kind="stable").reset_index(drop=True)
    cost = monitor["episode_cost"] if "episode_cost" in monitor else pd.Series(np.zeros(len(monitor)))
    violations = monitor["episode_violations"] if "episode_violations" in monitor else pd.Series(np.zeros(len(monitor)))
    curve = pd.DataFrame(
        {
            "timesteps": monitor["l"].cumsum().astype(np.int64),
            "episode": np.arange(1, len(monitor) + 1),
            "return": monitor["r"].astype(float),
            "length": monitor["l"].astype(np.int64),
            "cost": cost.astype(float).to_numpy(),
            "violations": violations.astype(np.int64).to_numpy(),
        }
    )
    curve["cumulative_violations"] = curve["violations"].cumsum()
    curve["time"] = monitor["t"].astype(float)
    return curve


def model_timesteps(zoo_dir: Path) -> int | None:
    """``num_timesteps`` of the final model that rl-zoo3 saved (``<env>.zip``; SB3 stores it in the zip's ``data``).

    :param zoo_dir: rl-zoo3's log folder of the run.
    """
    import zipfile

    for path in sorted(zoo_dir.glob("*/*/*.zip")):  # <algo>/<env>_<id>/<env>.zip, not best_model.zip or checkpoints
        if path.stem == "best_model" or "_steps" in path.stem:
            continue
        try:
            with zipfile.ZipFile(path) as archive:
                return int(json.loads(archive.read("data"))["num_timesteps"])
        except (KeyError, ValueError, OSError, zipfile.BadZipFile):
            return None
    return None


def summarize(
    spec: RunSpec,
    curve: pd.DataFrame,
    safety: dict[str, Any] | None,
    wall_s: float,
    cmd: Sequence[str],
    timesteps: int | None = None,
) -> dict:
    """The ``summary.json`` of a run.

    Cumulative violations, safety rate, episodes and interventions come from the model's own safety summary
    (``safety_summary.json`` written by ``sppo-train``) when the algorithm keeps one, else from the monitor curve.

    :param spec: the run.
    :param curve: its learning curve (:func:`read_monitor_curve`).
    :param safety: the model's safety summary, or ``None``.
    :param wall_s: wall-clock seconds of the train command.
    :param cmd: the train command.
    :param timesteps: env steps of the run (the saved model's ``num_timesteps``); ``None``: the safety summary's, else
        the finished episodes' total length.
    """
    last = curve.tail(spec.last_n)
    episodes = len(curve)
    unsafe = int((curve["violations"] > 0).sum())
    if timesteps is None:
        timesteps = int(safety["num_timesteps"]) if safety and "num_timesteps" in safety else int(curve["length"].sum())
    summary: dict[str, Any] = {
        "task": spec.task,
        "algo": spec.algo,
        "seed": spec.seed,
        "steps": timesteps,
        "episodes": episodes,
        "return_last_n": float(last["return"].mean()) if episodes else float("nan"),
        "return_last_n_std": float(last["return"].std(ddof=0)) if episodes else float("nan"),
        "last_n": int(min(spec.last_n, episodes)),
        "cumulative_violations": int(curve["violations"].sum()),
        "safety_rate": 100.0 * (episodes - unsafe) / episodes if episodes else float("nan"),
        "cumulative_interventions": None,
        "safety_source": "monitor",
        "wall_clock_s": round(wall_s, 3),
        "steps_per_s": timesteps / wall_s if wall_s > 0 else float("nan"),
        "train_steps_per_s": float("nan"),
        "command": shlex.join(cmd),
    }
    if episodes and float(curve["time"].iloc[-1]) > 0:  # without start-up: env creation to the last episode's end
        summary["train_steps_per_s"] = float(curve["timesteps"].iloc[-1] / curve["time"].iloc[-1])
    if safety:
        summary.update(
            episodes=int(safety.get("episodes", episodes)),
            cumulative_violations=int(safety.get("cumulative_violations", summary["cumulative_violations"])),
            safety_rate=float(safety.get("safety_rate", summary["safety_rate"])),
            cumulative_interventions=int(safety.get("cumulative_interventions", 0)),
            safety_source="safety_metrics",
        )
        if "eval_mean_reward" in safety:
            summary["eval_mean_reward"] = float(safety["eval_mean_reward"])
    return summary


def execute(spec_dict: dict[str, Any], work_dir: str | None = None) -> dict[str, Any]:
    """Train one run and collect its results (runs in a local thread or as a Ray task).

    :param spec_dict: the :class:`RunSpec` as a dict (plain data, for Ray).
    :param work_dir: where the train command writes; ``None``: a temporary folder (a Ray task on another node),
        whose log and curve are sent back in the result.
    :return: ``{"ok", "summary", "curve_csv", "log", "returncode"}``.
    """
    spec = RunSpec(**spec_dict)
    temporary = work_dir is None
    root = Path(tempfile.mkdtemp(prefix="sppo_bench_")) if temporary else Path(work_dir)  # type: ignore[arg-type]
    try:
        root.mkdir(parents=True, exist_ok=True)
        zoo_dir = root / "zoo"
        (root / DONE_FILE).unlink(missing_ok=True)  # --force: the run is unfinished until it finishes again
        shutil.rmtree(zoo_dir, ignore_errors=True)  # an interrupted earlier attempt restarts from scratch
        config_path = None
        if spec.config_text is not None:
            config_path = root / CONFIG_FILE
            config_path.write_text(spec.config_text)
        cmd = train_command(spec, zoo_dir, config_path)
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        start = time.perf_counter()
        with open(root / LOG_FILE, "w") as log:
            log.write(shlex.join(cmd) + "\n")
            log.flush()
            proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, check=False)
        wall_s = time.perf_counter() - start
        log_text = (root / LOG_FILE).read_text(errors="replace")
        result: dict[str, Any] = {"ok": proc.returncode == 0, "returncode": proc.returncode, "summary": None}
        result["log"] = log_text[-MAX_REMOTE_LOG_CHARS:] if temporary else None
        result["log_tail"] = log_text[-4000:]
        if proc.returncode == 0:
            curve = read_monitor_curve(zoo_dir)
            safety_files = sorted(zoo_dir.rglob("safety_summary.json"))
            safety = json.loads(safety_files[-1].read_text()) if safety_files else None
            result["summary"] = summarize(spec, curve, safety, wall_s, cmd, model_timesteps(zoo_dir))
            result["curve_csv"] = curve.to_csv(index=False)
        return result
    finally:
        if temporary:
            shutil.rmtree(root, ignore_errors=True)


def finalize(spec: RunSpec, result: dict[str, Any]) -> None:
    """Write a run's results into its folder (and its ``DONE`` or ``FAILED`` marker).

    :param spec: the run.
    :param result: what :func:`execute` returned.
    """
    run_dir = Path(spec.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if result.get("log") is not None:
        (run_dir / LOG_FILE).write_text(result["log"])
    if spec.config_text is not None and not (run_dir / CONFIG_FILE).exists():
        (run_dir / CONFIG_FILE).write_text(spec.config_text)
    if not result["ok"]:
        (run_dir / FAILED_FILE).write_text(f"exit status {result['returncode']}\n\n{result['log_tail']}")
        return
    (run_dir / CURVE_FILE).write_text(result["curve_csv"])
    with open(run_dir / SUMMARY_FILE, "w") as file:
        json.dump(result["summary"], file, indent=2)
    (run_dir / FAILED_FILE).unlink(missing_ok=True)
    (run_dir / DONE_FILE).write_text(time.strftime("%Y-%m-%dT%H:%M:%S") + "\n")


# ---------------------------------------------------------------------------------------------------- the grid
def parse_steps(values: Iterable[str]) -> tuple[int | None, dict[str, int]]:
    """``--steps`` values: ``N`` (every task) and/or ``TASK=N`` (one task).

    :param values: the strings given.
    :return: the default for all tasks (``None``: the yml's) and the per-task overrides.
    """
    default: int | None = None
    per_task: dict[str, int] = {}
    for value in values:
        task, sep, number = value.rpartition("=")
        try:
            steps = int(float(number))
        except ValueError:
            raise ValueError(f"--steps {value!r}: expected N or TASK=N with an integer N") from None
        if steps <= 0:
            raise ValueError(f"--steps {value!r}: N must be positive")
        if sep:
            per_task[task] = steps
        else:
            default = steps
    return default, per_task


def build_grid(
    algos: Sequence[str],
    tasks: Sequence[str],
    seeds: Sequence[int],
    out: Path,
    hyperparams_dir: Path,
    steps_default: int | None = None,
    steps_per_task: dict[str, int] | None = None,
    device: str = "auto",
    zoo_args: Sequence[str] = (),
    last_n: int = 10,
) -> list[RunSpec]:
    """All runs of the grid, tasks outermost (configs are checked for every pair before anything runs).

    :param algos: algorithm names.
    :param tasks: gymnasium ids.
    :param seeds: seeds.
    :param out: the grid's output folder.
    :param hyperparams_dir: folder of the package's hyperparameter files.
    :param steps_default: env steps of every run (``None``: the yml's ``n_timesteps``).
    :param steps_per_task: per-task overrides of ``steps_default``.
    :param device: PyTorch device.
    :param zoo_args: extra train-command arguments.
    :param last_n: final episodes averaged into the reported return.
    :raises ValueError: a pair without hyperparameters.
    """
    per_task = steps_per_task or {}
    specs = []
    for task in tasks:
        for algo in algos:
            config_text = resolve_config(algo, task, hyperparams_dir)
            for seed in seeds:
                specs.append(
                    RunSpec(
                        task=task,
                        algo=algo,
                        seed=seed,
                        run_dir=str(run_dir_for(out, task, algo, seed)),
                        steps=per_task.get(task, steps_default),
                        config_text=config_text,
                        device=device,
                        zoo_args=list(zoo_args),
                        last_n=last_n,
                    )
                )
    return specs


def is_done(spec: RunSpec) -> bool:
    """Whether the run finished in an earlier invocation (its ``DONE`` marker and summary exist).

    :param spec: the run.
    """
    run_dir = Path(spec.run_dir)
    return (run_dir / DONE_FILE).exists() and (run_dir / SUMMARY_FILE).exists()


def progress_line(index: int, total: int, spec: RunSpec, result: dict[str, Any]) -> str:
    """One line about a finished run.

    :param index: how many runs have finished (this one included).
    :param total: runs to do in this invocation.
    :param spec: the run.
    :param result: what :func:`execute` returned.
    """
    head = f"[{index}/{total}] {spec.label}"
    if not result["ok"]:
        return f"{head}: FAILED (exit {result['returncode']}), see {Path(spec.run_dir) / FAILED_FILE}"
    s = result["summary"]
    return (
        f"{head}: return(last {s['last_n']}) {s['return_last_n']:.2f}  violations {s['cumulative_violations']}  "
        f"safety {s['safety_rate']:.1f}%  episodes {s['episodes']}  {s['steps']} steps in {s['wall_clock_s']:.0f} s "
        f"({s['steps_per_s']:.1f} steps/s)"
    )


def run_local(specs: Sequence[RunSpec], workers: int, report: Callable[[RunSpec, dict[str, Any]], None]) -> None:
    """Run the specs as parallel local processes (one thread waits on each train subprocess).

    :param specs: the runs.
    :param workers: how many at once.
    :param report: called in the main thread with each finished run.
    """
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        futures = {pool.submit(execute, asdict(spec), spec.run_dir): spec for spec in specs}
        for future in as_completed(futures):
            spec = futures[future]
            try:
                result = future.result()
            except Exception as exc:  # the runner itself failed (e.g. disk full): record it, keep the others
                result = {"ok": False, "returncode": None, "log_tail": f"{type(exc).__name__}: {exc}", "log": None}
            report(spec, result)


def import_ray() -> Any:
    """Import Ray (an optional extra) or fail with the install command."""
    try:
        import ray
    except ImportError as exc:
        raise SystemExit('--ray-address needs Ray, an optional extra: pip install "sppo_sb3[ray]"') from exc
    return ray


def run_ray(
    specs: Sequence[RunSpec],
    address: str,
    report: Callable[[RunSpec, dict[str, Any]], None],
    cpus_per_run: float = 1.0,
    shared_fs: bool = False,
) -> None:
    """Run the specs as Ray tasks on an existing cluster; results are written by this (the driver's) process.

    :param specs: the runs.
    :param address: the cluster's address (``auto``, ``ray://host:10001``, ``local`` for a fresh local instance).
    :param report: called with each finished run.
    :param cpus_per_run: CPUs Ray reserves for each run.
    :param shared_fs: the output folder is visible from every node: runs write there directly (keeps ``zoo/``).
    """
    ray = import_ray()
    module = sys.modules.get(execute.__module__)
    if module is not None and module.__name__ != "__main__":  # imported from a path: workers cannot import it
        ray.cloudpickle.register_pickle_by_value(module)
    if not ray.is_initialized():
        ray.init(address=None if address == "local" else address)
    remote = ray.remote(num_cpus=cpus_per_run)(execute)
    pending = {remote.remote(asdict(spec), spec.run_dir if shared_fs else None): spec for spec in specs}
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        for ref in done:
            spec = pending.pop(ref)
            try:
                result = ray.get(ref)
            except Exception as exc:  # a Ray task that died (node lost, out of memory)
                result = {"ok": False, "returncode": None, "log_tail": f"{type(exc).__name__}: {exc}", "log": None}
            report(spec, result)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options (see ``--help``).

    :param argv: the arguments (default: ``sys.argv[1:]``).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("results"), help="output folder (default: results)")
    parser.add_argument("--algos", nargs="+", default=None, help=f"algorithms (default: {' '.join(OUR_ALGOS)})")
    parser.add_argument("--tasks", nargs="+", default=None, help=f"tasks (default: {' '.join(SAFE_TASKS)})")
    parser.add_argument("--seeds", type=int, default=None, help="number of seeds 0..N-1 (default: 3; --quick: 2)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed (default: 0)")
    parser.add_argument(
        "--steps",
        action="append",
        default=[],
        metavar="[TASK=]N",
        help="env steps per run: N for every task, TASK=N for one (repeatable; default: the yml's n_timesteps)",
    )
    parser.add_argument("--hyperparams-dir", type=Path, default=DEFAULT_HYPERPARAMS_DIR, help="folder of ALGO.yml files")
    parser.add_argument("--quick", action="store_true", help="tiny preset: 2 seeds, 2048 steps (Half-Cheetah: 256)")
    parser.add_argument("--fig7", action="store_true", help=f"Fig. 7 grid: {' '.join(FIG7_ALGOS)} on {' '.join(FIG7_TASKS)}")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="parallel local runs (default: cores)")
    parser.add_argument("--ray-address", default=None, help="run as Ray tasks on this cluster (auto, ray://host:port)")
    parser.add_argument("--ray-cpus-per-run", type=float, default=1.0, help="CPUs Ray reserves per run (default: 1)")
    parser.add_argument("--ray-shared-fs", action="store_true", help="--out is on a filesystem shared by all Ray nodes")
    parser.add_argument("--device", default="auto", help="PyTorch device of every run (default: auto)")
    parser.add_argument("--last-n", type=int, default=10, help="episodes averaged into the final return (default: 10)")
    parser.add_argument(
        "--zoo-args", default="", help='extra train arguments, one string (e.g. "--eval-freq 10000 --n-eval-envs 2")'
    )
    parser.add_argument("--force", action="store_true", help="rerun finished runs too")
    parser.add_argument("--dry-run", action="store_true", help="print the runs' commands and exit")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the grid; returns the exit status (1 when a run failed).

    :param argv: command-line arguments (default: ``sys.argv[1:]``).
    """
    args = parse_args(argv)
    algos = args.algos or (list(FIG7_ALGOS) if args.fig7 else list(OUR_ALGOS))
    tasks = args.tasks or (list(FIG7_TASKS) if args.fig7 else list(QUICK_TASKS if args.quick else SAFE_TASKS))
    n_seeds = args.seeds if args.seeds is not None else (QUICK_SEEDS if args.quick else 3)
    if n_seeds < 1 or args.workers < 1 or args.last_n < 1:
        raise SystemExit("--seeds, --workers and --last-n must be at least 1")
    try:
        steps_default, steps_per_task = parse_steps(args.steps)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    if args.quick:  # the preset's budgets, under an explicit --steps N, under explicit --steps TASK=N
        quick = {t: QUICK_STEPS.get(t, QUICK_DEFAULT_STEPS) if steps_default is None else steps_default for t in tasks}
        steps_per_task = {**quick, **steps_per_task}
    if args.ray_address is not None:
        import_ray()  # fail before anything runs
    seeds = list(range(args.first_seed, args.first_seed + n_seeds))
    try:
        specs = build_grid(
            algos,
            tasks,
            seeds,
            args.out,
            args.hyperparams_dir,
            steps_default,
            steps_per_task,
            args.device,
            shlex.split(args.zoo_args),
            args.last_n,
        )
    except ValueError as exc:
        raise SystemExit(f"benchmark: {exc}") from None
    todo = [spec for spec in specs if args.force or not is_done(spec)]
    skipped = len(specs) - len(todo)
    print(
        f"{len(specs)} runs ({len(algos)} algorithms x {len(tasks)} tasks x {n_seeds} seeds) -> {args.out}; "
        f"{skipped} already finished, {len(todo)} to run "
        + (f"on Ray ({args.ray_address})" if args.ray_address else f"with {min(args.workers, max(len(todo), 1))} workers"),
        flush=True,
    )
    if args.dry_run:
        for spec in todo:
            config = Path(spec.run_dir) / CONFIG_FILE if spec.config_text is not None else None
            print(shlex.join(train_command(spec, Path(spec.run_dir) / "zoo", config)))
        return 0
    if not todo:
        return 0
    from tqdm import tqdm

    failed: list[RunSpec] = []
    start = time.perf_counter()
    with tqdm(total=len(todo), unit="run", dynamic_ncols=True, file=sys.stderr) as bar:

        def report(spec: RunSpec, result: dict[str, Any]) -> None:
            finalize(spec, result)
            if not result["ok"]:
                failed.append(spec)
            bar.update(1)
            bar.write(progress_line(bar.n, len(todo), spec, result))

        if args.ray_address is not None:
            run_ray(todo, args.ray_address, report, args.ray_cpus_per_run, args.ray_shared_fs)
        else:
            run_local(todo, args.workers, report)
    print(f"{len(todo) - len(failed)}/{len(todo)} runs finished in {time.perf_counter() - start:.0f} s -> {args.out}")
    for spec in failed:
        print(f"FAILED: {spec.label}: {Path(spec.run_dir) / FAILED_FILE}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
