"""What a finished run reports: its learning curve from rl-zoo3's monitor files and its ``summary.json``.

:func:`summarize` is the one place that decides what ``summary.json`` holds. A new figure goes there; to show it as a
mean ± std over seeds, add its key to :data:`sppo_lab.stats.AGGREGATED_KEYS` (``aggregate.csv``), and to
:data:`~sppo_lab.stats.INTERVAL_KEYS` for its bootstrap confidence interval and IQM.
"""

from __future__ import annotations

import json
import shlex
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sppo_lab.layout import CURVE_COLUMNS
from sppo_lab.spec import RunSpec


def read_monitor_curve(zoo_dir: Path) -> pd.DataFrame:
    """The learning curve of a run from rl-zoo3's ``*.monitor.csv`` files (all training envs, in time order).

    :param zoo_dir: rl-zoo3's log folder of the run (searched recursively).
    :return: a frame with :data:`~sppo_lab.layout.CURVE_COLUMNS` (empty when no episode finished).
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


def monitor_interventions(zoo_dir: Path) -> int | None:
    """The shield interventions of a run from its ``*.monitor.csv`` files (``episode_interventions``), or ``None``
    where no env of it reported a shield (an unshielded run, or a monitor without the column).

    :param zoo_dir: rl-zoo3's log folder of the run (searched recursively).
    """
    counts = [
        pd.read_csv(path, skiprows=1).get("episode_interventions", pd.Series(dtype=float))
        for path in sorted(zoo_dir.rglob("*monitor.csv"))
    ]
    shielded = [count.dropna() for count in counts if count.notna().any()]
    return int(sum(count.sum() for count in shielded)) if shielded else None


def final_model_path(zoo_dir: Path) -> Path | None:
    """The final model that rl-zoo3 saved, ``<algo>/<env>_<id>/<env>.zip`` (not ``best_model.zip`` or checkpoints).

    :param zoo_dir: rl-zoo3's log folder of the run.
    """
    for path in sorted(zoo_dir.glob("*/*/*.zip")):
        if path.stem != "best_model" and "_steps" not in path.stem:
            return path
    return None


def model_timesteps(zoo_dir: Path) -> int | None:
    """``num_timesteps`` of the final model that rl-zoo3 saved (SB3 stores it in the zip's ``data``).

    :param zoo_dir: rl-zoo3's log folder of the run.
    """
    path = final_model_path(zoo_dir)
    if path is None:
        return None
    try:
        with zipfile.ZipFile(path) as archive:
            return int(json.loads(archive.read("data"))["num_timesteps"])
    except (KeyError, ValueError, OSError, zipfile.BadZipFile):
        return None


def model_safety_summary(zoo_dir: Path) -> dict[str, Any] | None:
    """The model's safety summary (``safety_summary.json``, written by ``sppo-train``), or ``None`` if it keeps none.

    :param zoo_dir: rl-zoo3's log folder of the run (searched recursively).
    """
    safety_files = sorted(zoo_dir.rglob("safety_summary.json"))
    return json.loads(safety_files[-1].read_text()) if safety_files else None


def summarize(
    spec: RunSpec,
    curve: pd.DataFrame,
    safety: dict[str, Any] | None,
    wall_s: float,
    cmd: Sequence[str],
    timesteps: int | None = None,
    provenance: dict[str, Any] | None = None,
    interventions: int | None = None,
) -> dict[str, Any]:
    """The ``summary.json`` of a run.

    Return: mean of the last ``spec.last_n`` episodes. Cumulative violations, safety rate, episodes and shield
    interventions come from the model's own safety summary (``safety_summary.json`` written by ``sppo-train``) when the
    algorithm keeps one, else from the monitor curve. Throughput: env steps per second over the whole command, start-up
    included (``steps_per_s``), and from the monitor's clock, env creation to the last finished episode
    (``train_steps_per_s``).

    :param spec: the run.
    :param curve: its learning curve (:func:`read_monitor_curve`).
    :param safety: the model's safety summary, or ``None``.
    :param wall_s: wall-clock seconds of the train command.
    :param cmd: the train command.
    :param timesteps: env steps of the run (the saved model's ``num_timesteps``); ``None``: the safety summary's, else
        the finished episodes' total length.
    :param provenance: where the run came from (:func:`~sppo_lab.provenance.run_provenance`: the
        commit, the resolved hyperparameters, the installed packages), stored under ``provenance``.
    :param interventions: the interventions of a shield around the env (:func:`monitor_interventions`; ``None``:
        none), used where the model keeps no safety summary of its own.
    """
    last = curve.tail(spec.last_n)
    episodes = len(curve)
    unsafe = int((curve["violations"] > 0).sum())
    if timesteps is None:
        timesteps = int(safety["num_timesteps"]) if safety and "num_timesteps" in safety else int(curve["length"].sum())
    summary: dict[str, Any] = {
        "task": spec.task,
        "algo": spec.algo,
        "variant": spec.variant,
        "seed": spec.seed,
        "steps": timesteps,
        "episodes": episodes,
        "return_last_n": float(last["return"].mean()) if episodes else float("nan"),
        "return_last_n_std": float(last["return"].std(ddof=0)) if episodes else float("nan"),
        "last_n": int(min(spec.last_n, episodes)),
        "cumulative_violations": int(curve["violations"].sum()),
        "safety_rate": 100.0 * (episodes - unsafe) / episodes if episodes else float("nan"),
        "cumulative_interventions": interventions,
        "safety_source": "monitor",
        "wall_clock_s": round(wall_s, 3),
        "steps_per_s": timesteps / wall_s if wall_s > 0 else float("nan"),
        "train_steps_per_s": float("nan"),
        "command": shlex.join(cmd),
    }
    if episodes and float(curve["time"].iloc[-1]) > 0:  # without start-up: env creation to the last episode's end
        summary["train_steps_per_s"] = float(curve["timesteps"].iloc[-1] / curve["time"].iloc[-1])
    if safety and "cumulative_violations" in safety:  # the model's own metrics (rl-zoo3's algorithms keep none)
        summary.update(
            episodes=int(safety.get("episodes", episodes)),
            cumulative_violations=int(safety.get("cumulative_violations", summary["cumulative_violations"])),
            safety_rate=float(safety.get("safety_rate", summary["safety_rate"])),
            cumulative_interventions=int(safety.get("cumulative_interventions", 0)),
            safety_source="safety_metrics",
        )
    if safety:
        if "eval_mean_reward" in safety:
            summary["eval_mean_reward"] = float(safety["eval_mean_reward"])
        summary.update(deployment_summary(safety.get("deployment", {})))
    if provenance is not None:
        summary["provenance"] = provenance
    return summary


def deployment_summary(deployment: dict[str, dict[str, float]]) -> dict[str, float]:
    """The learned policy deployed with and without the shield (``sppo-train``'s ``deployment``), as flat keys.

    ``eval_return``, ``eval_violations`` (per episode) and ``eval_safe_rate`` (% of episodes) for the shielded
    deployment; the same with ``eval_unshielded_`` for the policy alone.
    """
    flat = {}
    for name, metrics in deployment.items():
        flat[f"{name}_return"] = float(metrics["mean_reward"])
        flat[f"{name}_violations"] = float(metrics["mean_violations"])
        flat[f"{name}_safe_rate"] = float(metrics["safe_episode_rate"])
    return flat
