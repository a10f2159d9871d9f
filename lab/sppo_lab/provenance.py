"""Where a run's figures came from: the code's commit, the hyperparameters as the model resolved them, the packages.

The README job's return moved from 57.4 to 43.9 with no change to the training code, and nothing recorded which
installed package moved it. Every benchmark run's ``summary.json`` now carries this record under ``provenance``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from stable_baselines3.common.save_util import load_from_zip_file

from sppo_sb3.common.provenance import package_versions, source_revision

__all__ = ["package_versions", "plain", "resolved_hyperparameters", "run_provenance", "source_revision"]


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
