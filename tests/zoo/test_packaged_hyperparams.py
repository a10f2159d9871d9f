"""The package's own hyperparameters: ``sppo-train`` reads them without ``-conf``, from the checkout's ``hyperparams/``
(through the ``sppo_sb3/hyperparams`` symlink) or from an installed wheel's copy (``scripts/check_wheel.sh`` builds one).
"""

from __future__ import annotations

import argparse
import inspect
import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
import yaml
from rl_zoo3.exp_manager import ExperimentManager

import sppo_sb3  # registers the tasks with gymnasium
from sppo_lab import configs
from sppo_sb3.algorithms import ALGORITHMS, HYPERPARAMS_DIR
from sppo_sb3.zoo import FAMILY_FOLDERS, SafeExperimentManager, default_config

REPO_HYPERPARAMS = Path(__file__).resolve().parents[2] / "hyperparams"
#: the tasks the package registers with gymnasium
PACKAGE_TASKS = sorted(env_id for env_id, spec in gym.registry.items() if str(spec.entry_point).startswith("sppo_sb3"))


def test_the_package_folder_is_the_repository_one() -> None:
    """One source: in a checkout, the package's folder is the top-level ``hyperparams/`` (not a copy that can drift)."""
    assert REPO_HYPERPARAMS.resolve() == HYPERPARAMS_DIR
    assert (Path(sppo_sb3.__file__).parent / "hyperparams").resolve() == REPO_HYPERPARAMS.resolve()
    assert configs.REPO_HYPERPARAMS_DIR == HYPERPARAMS_DIR  # the benchmark's default --hyperparams-dir


@pytest.mark.parametrize("env_id", PACKAGE_TASKS)
def test_sppo_has_default_hyperparameters_on_every_task_of_the_package(env_id: str) -> None:
    path = default_config("sppo", env_id)
    assert path is not None and path.is_file() and path.is_relative_to(HYPERPARAMS_DIR)
    assert env_id in yaml.safe_load(path.read_text())


def test_the_default_is_the_first_packaged_file_with_the_task() -> None:
    """Top-level ``ALGO.yml`` first, then the family folders; rl-zoo3's own file (``None``) where the package has none."""
    assert len(PACKAGE_TASKS) >= 14 and {"SafePointCircle-v0", "DMC-cartpole-swingup-v0"} <= set(PACKAGE_TASKS)
    for algo in [*ALGORITHMS, "sac", "ppo", "ddpg"]:
        for env_id in PACKAGE_TASKS:
            candidates = [HYPERPARAMS_DIR / f"{algo}.yml", *(HYPERPARAMS_DIR / f / f"{algo}.yml" for f in FAMILY_FOLDERS)]
            having = [path for path in candidates if path.is_file() and env_id in yaml.safe_load(path.read_text())]
            if having:
                assert default_config(algo, env_id) == having[0], (algo, env_id)
            elif algo in ALGORITHMS:
                with pytest.raises(ValueError, match=rf"no {algo} hyperparameters for {re.escape(env_id)}.*pass -conf FILE"):
                    default_config(algo, env_id)
            else:
                assert default_config(algo, env_id) is None, (algo, env_id)
    assert default_config("sppo", "sppo_sb3/SafetyHopperVelocity-v1") == HYPERPARAMS_DIR / "sppo.yml"
    assert default_config("pdo", "sppo_sb3/SafetyHopperVelocity-v1") == HYPERPARAMS_DIR / "velocity" / "pdo.yml"
    assert default_config("ppo", "DMC-cartpole-swingup-v0") == HYPERPARAMS_DIR / "dmc" / "ppo.yml"
    assert default_config("ppo", "CartPole-v1") is None


def test_a_default_entry_and_a_missing_folder(tmp_path: Path) -> None:
    (tmp_path / "sppo.yml").write_text("default:\n  policy: TOLDPolicy\n")
    assert default_config("sppo", "CartPole-v1", tmp_path) == tmp_path / "sppo.yml"
    with pytest.raises(ValueError, match=r"looked in .*: no pdo\.yml at all"):
        default_config("pdo", "CartPole-v1", tmp_path)
    with pytest.raises(FileNotFoundError, match=r"hyperparameter folder is missing.*-conf FILE"):
        default_config("sppo", "CartPole-v1", tmp_path / "absent")


def _manager(tmp_path: Path, algo: str, env_id: str, *args: Any, **kwargs: Any) -> SafeExperimentManager:
    return SafeExperimentManager(argparse.Namespace(), algo, env_id, str(tmp_path), *args, **kwargs)


def test_train_reads_the_packaged_file_unless_conf_is_given(tmp_path: Path) -> None:
    manager = _manager(tmp_path, "sppo", "SafePointCircle-v0")
    assert manager.config == str(HYPERPARAMS_DIR / "sppo.yml")
    hyperparams, _ = manager.read_hyperparameters()
    assert hyperparams["policy"] == "TOLDPolicy" and hyperparams["shield"] == "auto"
    assert _manager(tmp_path, "cpo", "sppo_sb3/SafetyAntVelocity-v1").config == str(HYPERPARAMS_DIR / "velocity" / "cpo.yml")

    own = tmp_path / "mine.yml"
    own.write_text("SafePointCircle-v0:\n  policy: TOLDPolicy\n  n_timesteps: 7\n")
    assert _manager(tmp_path, "sppo", "SafePointCircle-v0", config=str(own)).config == str(own)  # -conf wins
    # given positionally, it wins too: every argument after log_folder at its default, up to config
    names = list(inspect.signature(ExperimentManager.__init__).parameters.values())[5:]
    defaults = [parameter.default for parameter in names[: [p.name for p in names].index("config")]]
    positional = _manager(tmp_path, "sppo", "SafePointCircle-v0", *defaults, str(own))
    assert positional.config == str(own)


def test_a_zoo_algorithm_without_packaged_hyperparameters_keeps_rl_zoo3s(tmp_path: Path) -> None:
    manager = _manager(tmp_path, "ppo", "CartPole-v1")
    assert Path(manager.config).parent.parent.name == "rl_zoo3" and Path(manager.config).name == "ppo.yml"
