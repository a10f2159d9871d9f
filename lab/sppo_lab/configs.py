"""Which hyperparameters a run of the benchmark trains with: the package's files, or rl-zoo3's own."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from typing import Any

import yaml

from sppo_sb3.algorithms import ALGORITHMS, HYPERPARAMS_DIR

#: the benchmark's default ``--hyperparams-dir``: the package's production yml files
#: (:data:`~sppo_sb3.algorithms.HYPERPARAMS_DIR`, the repository's ``hyperparams/``)
REPO_HYPERPARAMS_DIR = HYPERPARAMS_DIR
#: the lab's folder in the repository (``lab/``)
LAB_DIR = Path(__file__).resolve().parents[1]
#: the lab's probe and sweep configs, one folder per variant (``--hyperparams-dir lab/hyperparams/<suite>_probe/<variant>``)
LAB_HYPERPARAMS_DIR = LAB_DIR / "hyperparams"
#: the committed raw runs of the tables in ``docs/results.md``, one folder per grid
RUNS_DIR = LAB_DIR / "runs"


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
    ours = algo in ALGORITHMS
    own = hyperparams_dir / f"{algo}.yml"
    if ours or own.exists():
        if own.exists():
            entries = _load_yml(own)
            if task in entries or "default" in entries:
                return own.read_text()
            if ours:
                raise ValueError(f"{own} has no entry for {task} (it has: {', '.join(entries)}); add one")
        elif ours:
            raise ValueError(f"no hyperparameter file {own} for the package's algorithm {algo!r} (see --hyperparams-dir)")
    zoo_file = _zoo_hyperparams_path(algo)
    if not zoo_file.exists():
        raise ValueError(
            f"{algo!r} is neither one of the package's algorithms {tuple(ALGORITHMS)} nor one with rl-zoo3 hyperparameters"
        )
    entries = _load_yml(zoo_file)
    versions = _other_versions(task, entries)
    if task in entries or (not versions and "default" in entries):
        return None
    if not versions:
        raise ValueError(f"rl-zoo3's {zoo_file.name} has no entry for {task}; put one in {own}")
    header = f"# rl-zoo3's {algo} hyperparameters for {versions[0]} (its {zoo_file.name} has no {task} entry)\n"
    return header + yaml.safe_dump({task: entries[versions[0]]}, sort_keys=False)
