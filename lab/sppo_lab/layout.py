"""The run-folder format of the benchmark, written by the runner and read by the plots: defined here only.

A grid's output folder ``OUT`` holds one folder per run, ``OUT/<task>/<name>/seed_<s>/`` (``name``: the algorithm's, or
``<algo>-<variant>`` for a variant, :func:`~sppo_lab.spec.run_name`), with:

- ``curve.csv``: one row per finished training episode, the columns :data:`CURVE_COLUMNS`: ``timesteps`` (env steps
  at its end), ``episode``, ``return``, ``length``, ``cost``, ``violations``, ``cumulative_violations``, ``time``
  (from rl-zoo3's ``monitor.csv`` with the package's ``episode_cost``/``episode_violations`` columns);
- ``summary.json``: the run's figures (:func:`sppo_lab.summary.summarize`);
- ``hyperparams.yml`` (the exact config used, when one is passed), ``train.log`` (the run's output) and ``zoo/``
  (rl-zoo3's run folder: model, monitor.csv, args);
- ``DONE``: the marker of a finished run; ``FAILED`` (the log's tail) marks a run that failed.
"""

from __future__ import annotations

import json
import re
import shutil
import time
from pathlib import Path
from typing import Any

import pandas as pd

DONE_FILE = "DONE"
FAILED_FILE = "FAILED"
SUMMARY_FILE = "summary.json"
CURVE_FILE = "curve.csv"
LOG_FILE = "train.log"
CONFIG_FILE = "hyperparams.yml"
ZOO_DIR = "zoo"
#: columns of ``curve.csv``
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


def task_dirname(task: str) -> str:
    """Folder name of a task id (``dm_control/cheetah-run-v0`` -> ``dm_control_cheetah-run-v0``).

    :param task: gymnasium id.
    """
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", task)


def run_dir_for(out: Path, task: str, name: str, seed: int) -> Path:
    """``OUT/<task>/<name>/seed_<s>``.

    :param out: the grid's output folder.
    :param task: gymnasium id.
    :param name: the run's row name (the algorithm's, or ``<algo>-<variant>``).
    :param seed: seed.
    """
    return out / task_dirname(task) / name / f"seed_{seed}"


def is_finished(run_dir: Path) -> bool:
    """Whether the run in ``run_dir`` finished (its ``DONE`` marker and summary exist).

    :param run_dir: the run's folder.
    """
    return (run_dir / DONE_FILE).exists() and (run_dir / SUMMARY_FILE).exists()


def finished_run_dirs(out: Path) -> list[Path]:
    """The folders of the finished runs under a grid's output folder, in path order.

    :param out: the grid's output folder.
    """
    return [path.parent for path in sorted(out.glob(f"*/*/seed_*/{SUMMARY_FILE}")) if is_finished(path.parent)]


def read_summary(run_dir: Path) -> dict[str, Any]:
    """The run's ``summary.json``.

    :param run_dir: the run's folder.
    """
    return json.loads((run_dir / SUMMARY_FILE).read_text())


def read_curve(run_dir: Path) -> pd.DataFrame:
    """The run's ``curve.csv`` (an empty frame when there is none).

    :param run_dir: the run's folder.
    """
    path = run_dir / CURVE_FILE
    return pd.read_csv(path) if path.exists() else pd.DataFrame()


def mark_unfinished(run_dir: Path) -> None:
    """Remove the ``DONE`` marker and rl-zoo3's folder of an earlier attempt before the run starts again.

    :param run_dir: the run's folder.
    """
    (run_dir / DONE_FILE).unlink(missing_ok=True)  # --force: the run is unfinished until it finishes again
    shutil.rmtree(run_dir / ZOO_DIR, ignore_errors=True)  # an interrupted earlier attempt restarts from scratch


def write_finished(run_dir: Path, summary: dict[str, Any], curve_csv: str) -> None:
    """Write a finished run's curve and summary, then its ``DONE`` marker (removing an earlier ``FAILED``).

    :param run_dir: the run's folder.
    :param summary: the ``summary.json`` contents.
    :param curve_csv: the ``curve.csv`` contents.
    """
    (run_dir / CURVE_FILE).write_text(curve_csv)
    with open(run_dir / SUMMARY_FILE, "w") as file:
        json.dump(summary, file, indent=2)
    (run_dir / FAILED_FILE).unlink(missing_ok=True)
    (run_dir / DONE_FILE).write_text(time.strftime("%Y-%m-%dT%H:%M:%S") + "\n")


def write_failed(run_dir: Path, returncode: int | None, log_tail: str) -> None:
    """Write the ``FAILED`` marker of a run that failed: its exit status and the tail of its log.

    :param run_dir: the run's folder.
    :param returncode: the train command's exit status (``None``: the runner itself failed).
    :param log_tail: the end of the run's output.
    """
    (run_dir / FAILED_FILE).write_text(f"exit status {returncode}\n\n{log_tail}")
