"""How algorithms and tasks appear in the figures and tables: names, colours and order (from the one algorithm list)."""

from __future__ import annotations

import re

from sppo_sb3.algorithms import ALGORITHMS, DISPLAY_ORDER, ZOO_BASELINES
from sppo_sb3.envs.dmc import action_repeat

#: the paper's names of its constrained tasks
TASK_NAMES: dict[str, str] = {"SafePointCircle-v0": "Point Robot", "SafeHalfCheetahHeight-v1": "Half-Cheetah"}


def display_name(algo: str) -> str:
    """``SPPO (ours)``, ``PDO``, ... for the listed algorithms, the name itself otherwise.

    :param algo: rl-zoo3 name of the algorithm.
    """
    known = ALGORITHMS.get(algo) or ZOO_BASELINES.get(algo)
    return known.display_name if known else algo


def algo_color(algo: str) -> str | None:
    """The algorithm's matplotlib colour (``None``: matplotlib's next one).

    :param algo: rl-zoo3 name of the algorithm.
    """
    known = ALGORITHMS.get(algo) or ZOO_BASELINES.get(algo)
    return known.color if known else None


def algo_sort_key(algo: str) -> tuple[int, str]:
    """Paper order first (:data:`~sppo_sb3.algorithms.DISPLAY_ORDER`), unknown algorithms after, alphabetically.

    :param algo: algorithm name.
    """
    return (DISPLAY_ORDER.index(algo) if algo in DISPLAY_ORDER else len(DISPLAY_ORDER), algo)


def task_title(task: str) -> str:
    """``Point Robot (SafePointCircle-v0)`` for the paper's tasks, the id otherwise.

    :param task: gymnasium id.
    """
    return f"{TASK_NAMES[task]} ({task})" if task in TASK_NAMES else task


def task_sort_key(task: str) -> tuple[bool, str]:
    """The paper's tasks first, then the others, each alphabetically.

    :param task: gymnasium id.
    """
    return (task not in TASK_NAMES, task)


def env_steps_per_step(task: str) -> int:
    """Env steps in one step of ``task``: TD-MPC's action repeat for the dm_control ids ``DMC-<domain>-<task>-v0``
    (whose budgets and x-axes the paper and TD-MPC count in dm_control steps), 1 for every other task.

    :param task: gymnasium id.
    """
    match = re.fullmatch(r"DMC-(.+)-v\d+", task)
    return action_repeat(match.group(1)) if match else 1
