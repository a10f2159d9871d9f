"""Running the benchmark's runs: the train command of a run, one run, and many in parallel (local or on Ray).

Every run is ``python -m sppo_sb3.train --algo ALGO --env TASK [-conf HYPERPARAMS/ALGO.yml] [-n STEPS] --seed S ...``
in a subprocess, so it is exactly what a user gets from ``sppo-train``. Its results go to its run folder
(:mod:`sppo_lab.layout`).
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path
from typing import Any

from sppo_lab import layout
from sppo_lab.provenance import run_provenance, source_revision
from sppo_lab.spec import RunSpec
from sppo_lab.summary import (
    final_model_path,
    model_safety_summary,
    model_timesteps,
    monitor_interventions,
    read_monitor_curve,
    summarize,
)

#: largest ``train.log`` a Ray task sends back to the driver (its tail)
MAX_REMOTE_LOG_CHARS = 200_000
#: what reports a finished run to the driver: ``report(spec, result)``
Report = Callable[[RunSpec, dict[str, Any]], None]


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
    if spec.agent_steps is not None:
        cmd += ["-n", str(spec.agent_steps)]
    cmd += ["--seed", str(spec.seed), "-f", str(zoo_dir), "--eval-freq", "-1", "--num-threads", "1"]
    cmd += ["--device", spec.device, *spec.zoo_args]
    return cmd


def dry_run_command(spec: RunSpec) -> list[str]:
    """The train command the run will execute in its run folder (what ``--dry-run`` prints).

    :param spec: the run.
    """
    run_dir = Path(spec.run_dir)
    config = run_dir / layout.CONFIG_FILE if spec.config_text is not None else None
    return train_command(spec, run_dir / layout.ZOO_DIR, config)


def execute(spec_dict: dict[str, Any], work_dir: str | None = None) -> dict[str, Any]:
    """Train one run and collect its results (runs in a local thread or as a Ray task).

    :param spec_dict: the :class:`RunSpec` as a dict (plain data, for Ray).
    :param work_dir: where the train command writes; ``None``: a temporary folder (a Ray task on another node),
        whose log and curve are sent back in the result.
    :return: ``{"ok", "summary", "curve_csv", "log", "log_tail", "returncode"}``.
    """
    spec = RunSpec(**spec_dict)
    temporary = work_dir is None
    root = Path(tempfile.mkdtemp(prefix="sppo_bench_")) if work_dir is None else Path(work_dir)
    try:
        root.mkdir(parents=True, exist_ok=True)
        layout.mark_unfinished(root)
        zoo_dir = root / layout.ZOO_DIR
        config_path = None
        if spec.config_text is not None:
            config_path = root / layout.CONFIG_FILE
            config_path.write_text(spec.config_text)
        cmd = train_command(spec, zoo_dir, config_path)
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        revision = source_revision()  # the code the run executes, before the checkout can move on
        start = time.perf_counter()
        with open(root / layout.LOG_FILE, "w") as log:
            log.write(shlex.join(cmd) + "\n")
            log.flush()
            proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, check=False)
        wall_s = time.perf_counter() - start
        log_text = (root / layout.LOG_FILE).read_text(errors="replace")
        result: dict[str, Any] = {"ok": proc.returncode == 0, "returncode": proc.returncode, "summary": None}
        result["log"] = log_text[-MAX_REMOTE_LOG_CHARS:] if temporary else None
        result["log_tail"] = log_text[-4000:]
        if proc.returncode == 0:
            curve = read_monitor_curve(zoo_dir)
            safety = model_safety_summary(zoo_dir)
            provenance = run_provenance(revision, final_model_path(zoo_dir))
            interventions = monitor_interventions(zoo_dir)
            timesteps = model_timesteps(zoo_dir)
            if timesteps is not None:  # the model counts agent steps
                timesteps *= spec.action_repeat
            result["summary"] = summarize(spec, curve, safety, wall_s, cmd, timesteps, provenance, interventions)
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
        (run_dir / layout.LOG_FILE).write_text(result["log"])
    if spec.config_text is not None and not (run_dir / layout.CONFIG_FILE).exists():
        (run_dir / layout.CONFIG_FILE).write_text(spec.config_text)
    if result["ok"]:
        layout.write_finished(run_dir, result["summary"], result["curve_csv"])
    else:
        layout.write_failed(run_dir, result["returncode"], result["log_tail"])


def progress_line(index: int, total: int, spec: RunSpec, result: dict[str, Any]) -> str:
    """One line about a finished run.

    :param index: how many runs have finished (this one included).
    :param total: runs to do in this invocation.
    :param spec: the run.
    :param result: what :func:`execute` returned.
    """
    head = f"[{index}/{total}] {spec.label}"
    if not result["ok"]:
        return f"{head}: FAILED (exit {result['returncode']}), see {Path(spec.run_dir) / layout.FAILED_FILE}"
    s = result["summary"]
    return (
        f"{head}: return(last {s['last_n']}) {s['return_last_n']:.2f}  violations {s['cumulative_violations']}  "
        f"safety {s['safety_rate']:.1f}%  episodes {s['episodes']}  {s['steps']} steps in {s['wall_clock_s']:.0f} s "
        f"({s['steps_per_s']:.1f} steps/s)"
    )


def _runner_failure(exc: Exception) -> dict[str, Any]:
    """The result of a run whose runner itself failed (disk full, a lost Ray node): recorded, the others go on."""
    return {"ok": False, "returncode": None, "log_tail": f"{type(exc).__name__}: {exc}", "log": None}


def run_local(specs: Sequence[RunSpec], workers: int, report: Report) -> None:
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
            except Exception as exc:
                result = _runner_failure(exc)
            report(spec, result)


def import_ray() -> Any:
    """Import Ray (an optional extra) or fail with the install command."""
    try:
        import ray
    except ImportError as exc:
        raise SystemExit('--ray-address needs Ray, an optional extra: pip install "sppo_sb3[ray]"') from exc
    return ray


def run_ray(
    specs: Sequence[RunSpec], address: str, report: Report, cpus_per_run: float = 1.0, shared_fs: bool = False
) -> None:
    """Run the specs as Ray tasks on an existing cluster; results are written by this (the driver's) process.

    Every node needs the package installed (each run is its ``sppo_sb3.train`` command anyway).

    :param specs: the runs.
    :param address: the cluster's address (``auto``, ``ray://host:10001``, ``local`` for a fresh local instance).
    :param report: called with each finished run.
    :param cpus_per_run: CPUs Ray reserves for each run.
    :param shared_fs: the output folder is visible from every node: runs write there directly (keeps ``zoo/``).
    """
    ray = import_ray()
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
            except Exception as exc:
                result = _runner_failure(exc)
            report(spec, result)
