"""Where a run's figures came from: the code's commit, the hyperparameters as the model resolved them, the packages.

The README job's return moved from 57.4 to 43.9 with no change to the training code, and nothing recorded which
installed package moved it. Every benchmark run's ``summary.json`` now carries this record under ``provenance``.
"""

from __future__ import annotations

import dataclasses
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

from stable_baselines3.common.save_util import load_from_zip_file

#: the installed distributions whose versions a run records
PACKAGES = ("sppo_sb3", "stable-baselines3", "sb3-contrib", "rl-zoo3", "gymnasium", "mujoco", "torch", "numpy")
PACKAGE_DIR = Path(__file__).resolve().parents[1]


def package_versions() -> dict[str, str | None]:
    """The installed version of each of :data:`PACKAGES` (``None`` where one is not installed), and Python's."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def source_revision(directory: Path = PACKAGE_DIR) -> dict[str, Any]:
    """The git commit of the package's source and whether tracked files differ from it (``None`` outside a checkout).

    :param directory: a folder inside the checkout (default: the package's own).
    """

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", *args], cwd=directory, capture_output=True, text=True, check=True, timeout=10)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip()

    commit = git("rev-parse", "HEAD")
    changes = git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"commit": commit, "dirty": bool(changes) if commit else None}


def plain(value: Any) -> Any:
    """``value`` as JSON: numbers, strings, booleans, None and containers of them; dataclasses as dicts; else None."""
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {field.name: plain(getattr(value, field.name)) for field in dataclasses.fields(value)}
    if isinstance(value, dict):
        kept = {str(key): plain(item) for key, item in value.items()}
        return {key: item for key, item in kept.items() if item is not None}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    return None


def resolved_hyperparameters(model_path: Path) -> dict[str, Any]:
    """The saved model's own settings, as it resolved them (e.g. SPPO's ``gamma="auto"`` as a number): every attribute
    SB3 saved that is plain data or a dataclass (the planner's and TOPO's configs), private ones left out.

    :param model_path: a saved SB3 model (``.zip``).
    """
    data, _, _ = load_from_zip_file(model_path, device="cpu", print_system_info=False)
    assert data is not None
    resolved = {key: plain(value) for key, value in sorted(data.items()) if not key.startswith("_")}
    return {key: value for key, value in resolved.items() if value is not None}


def run_provenance(revision: dict[str, Any], model_path: Path | None) -> dict[str, Any]:
    """The commit, the installed packages and, where the run saved a model, its resolved hyperparameters.

    :param revision: :func:`source_revision` read when the run started: the checkout may move on while it trains.
    :param model_path: the run's final model (``None``: none was saved).
    """
    record: dict[str, Any] = {**revision, "packages": package_versions()}
    if model_path is not None:
        record["hyperparameters"] = resolved_hyperparameters(model_path)
    return record
