"""One run of the benchmark's grid, as plain data: what the grid builds, the runner runs and the summary records."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import yaml

#: between an algorithm's name and its variant's in row names and run folders (``cpo-shielded``)
VARIANT_SEPARATOR = "-"
VARIANT_PATTERN = re.compile(r"[A-Za-z0-9_]+")


def check_variant(variant: str) -> str:
    """``variant`` if it is ``""`` or letters, digits and ``_``.

    :param variant: a variant's name.
    :raises ValueError: any other name (it becomes part of a folder's name and is split off at the separator).
    """
    if variant and not VARIANT_PATTERN.fullmatch(variant):
        raise ValueError(f"variant {variant!r}: use letters, digits and '_' only (e.g. 'shielded')")
    return variant


def run_name(algo: str, variant: str = "") -> str:
    """A run's row name: ``algo``, or ``algo-variant`` for a variant (the row of the tables and the run's folder).

    :param algo: rl-zoo3 name of the algorithm.
    :param variant: the variant's name (``""``: none).
    """
    return f"{algo}{VARIANT_SEPARATOR}{variant}" if variant else algo


def split_run_name(name: str) -> tuple[str, str]:
    """``(algo, variant)`` of a row name (:func:`run_name`'s inverse; rl-zoo3's names have no ``-``).

    :param name: a row name.
    """
    algo, _, variant = name.partition(VARIANT_SEPARATOR)
    return algo, variant


@dataclass
class RunSpec:
    """One run of the grid.

    :param task: gymnasium id of the task.
    :param algo: rl-zoo3 name of the algorithm.
    :param seed: random seed.
    :param run_dir: the run's output folder (``OUT/<task>/<name>/seed_<s>``), as seen by the driver.
    :param steps: env steps; ``-n`` is as many agent steps (:attr:`agent_steps`: fewer where the yml holds each action
        for several env steps); ``None``: the hyperparameter file's ``n_timesteps`` (agent steps).
    :param config_text: the yml given to ``-conf`` (written into the run folder); ``None``: rl-zoo3's own.
    :param device: PyTorch device (``--device`` of the train command).
    :param zoo_args: extra arguments for the train command (after the runner's own, so they win).
    :param last_n: number of final episodes averaged into the reported return.
    :param variant: names runs of ``algo`` under other settings than its own (e.g. ``shielded``: behind
        :class:`~sppo_sb3.shield.ShieldWrapper`); their folders and table rows are ``<algo>-<variant>``. ``""``: none.
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
    variant: str = ""

    @property
    def action_repeat(self) -> int:
        """Env steps per agent step: the ``action_repeat`` of a ``ShieldWrapper`` or ``ActionRepeat`` in the task's
        ``env_wrapper`` (1 without one, or without the yml)."""
        return held_env_steps(self.config_text, self.task)

    @property
    def agent_steps(self) -> int | None:
        """``-n`` of the train command: :attr:`steps` (env steps) in agent steps, which hold each action
        :attr:`action_repeat` env steps."""
        return None if self.steps is None else math.ceil(self.steps / self.action_repeat)

    @property
    def name(self) -> str:
        """The run's row name: ``algo``, or ``algo-variant`` for a variant."""
        return run_name(self.algo, self.variant)

    @property
    def label(self) -> str:
        """``task / name / seed`` for progress lines."""
        return f"{self.task} / {self.name} / seed {self.seed}"


def held_env_steps(config_text: str | None, task: str) -> int:
    """How many env steps each agent step holds its action for in ``task``'s entry of a yml: the ``action_repeat`` of
    a ``ShieldWrapper`` (or ``repeat`` of an ``ActionRepeat``) among its ``env_wrapper``; 1 without one.

    :param config_text: the yml's text (``None``: rl-zoo3's own, which holds no action).
    :param task: the entry.
    """
    if config_text is None:
        return 1
    entry: Any = (yaml.safe_load(config_text) or {}).get(task) or {}
    wrappers = entry.get("env_wrapper") or []
    for wrapper in wrappers if isinstance(wrappers, list) else [wrappers]:
        if isinstance(wrapper, dict):
            for name, kwargs in wrapper.items():
                if name.endswith(("ShieldWrapper", "ActionRepeat")) and isinstance(kwargs, dict):
                    return int(kwargs.get("action_repeat", kwargs.get("repeat", 1)))
    return 1
