"""How algorithms and tasks appear in the figures and tables: names, colours and order (from the one algorithm list)."""

from __future__ import annotations

import re

from sppo_lab.spec import split_run_name
from sppo_sb3.algorithms import ALGORITHMS, DISPLAY_ORDER, ZOO_BASELINES
from sppo_sb3.envs.dmc import action_repeat
from sppo_sb3.envs.velocity import VELOCITY_TASKS

#: the paper's names of its constrained tasks
TASK_NAMES: dict[str, str] = {"SafePointCircle-v0": "Point Robot", "SafeHalfCheetahHeight-v1": "Half-Cheetah"}
#: Safety-Gymnasium's velocity tasks by their robot
VELOCITY_TASK_NAMES: dict[str, str] = {task.env_id: f"{task.robot} velocity" for task in VELOCITY_TASKS}


def display_name(name: str) -> str:
    """``SPPO (ours)``, ``PDO``, ... for the listed algorithms, the name itself otherwise; a variant's after its
    algorithm's (``cpo-shielded``: ``CPO (shielded)``; ``sppo-previous``: ``SPPO (ours, previous)``).

    :param name: rl-zoo3 name of the algorithm, or a row name ``<algo>-<variant>``.
    """
    algo, variant = split_run_name(name)
    known = ALGORITHMS.get(algo) or ZOO_BASELINES.get(algo)
    base = known.display_name if known else algo
    if not variant:
        return base
    return f"{base[:-1]}, {variant})" if base.endswith(")") else f"{base} ({variant})"


def algo_color(name: str) -> str | None:
    """The algorithm's matplotlib colour; ``None`` (matplotlib's next one) for the others and for variants, so that a
    variant's line is told from its algorithm's.

    :param name: rl-zoo3 name of the algorithm, or a row name ``<algo>-<variant>``.
    """
    known = ALGORITHMS.get(name) or ZOO_BASELINES.get(name)
    return known.color if known else None


def algo_sort_key(name: str) -> tuple[int, str, str]:
    """Paper order first (:data:`~sppo_sb3.algorithms.DISPLAY_ORDER`), unknown algorithms after, alphabetically; a
    variant right after its algorithm.

    :param name: algorithm name, or a row name ``<algo>-<variant>``.
    """
    algo, variant = split_run_name(name)
    return (DISPLAY_ORDER.index(algo) if algo in DISPLAY_ORDER else len(DISPLAY_ORDER), algo, variant)


def task_title(task: str) -> str:
    """``Point Robot (SafePointCircle-v0)`` for the paper's tasks, ``Hopper velocity (sppo_sb3/...)`` for the velocity
    tasks, the id otherwise.

    :param task: gymnasium id.
    """
    name = TASK_NAMES.get(task) or VELOCITY_TASK_NAMES.get(task)
    return f"{name} ({task})" if name else task


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
