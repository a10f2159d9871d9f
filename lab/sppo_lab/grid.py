"""The benchmark's grid: algorithms × tasks × seeds, its presets, and which of its runs are still to do."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from sppo_lab import layout
from sppo_lab.configs import resolve_config
from sppo_lab.spec import RunSpec, check_variant, run_name
from sppo_sb3.algorithms import PAPER_ALGORITHMS
from sppo_sb3.envs.dmc import FIG7_DMC_TASKS, dmc_id
from sppo_sb3.envs.velocity import ANT, HALF_CHEETAH, HOPPER, WALKER2D

#: the paper's comparison: the package's algorithms the paper compares (configured by ``--hyperparams-dir/ALGO.yml``;
#: the others, e.g. ``saclag``, run when named with ``--algos``)
OUR_ALGOS: tuple[str, ...] = PAPER_ALGORITHMS
#: the paper's constrained tasks (Tables I and II)
SAFE_TASKS: tuple[str, ...] = ("SafePointCircle-v0", "SafeHalfCheetahHeight-v1")
#: Fig. 7: SPPO's planning-guided exploration against SB3's DDPG and PPO on gymnasium MuJoCo tasks
FIG7_ALGOS: tuple[str, ...] = ("sppo", "ddpg", "ppo")
FIG7_TASKS: tuple[str, ...] = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5")
#: ``--fig7 dmc``: the paper's own six dm_control tasks (``pip install "sppo_sb3[dmc]"``), configured by ``hyperparams/dmc``
FIG7_DMC: tuple[str, ...] = tuple(dmc_id(task) for task in FIG7_DMC_TASKS)
#: the task sets of ``--fig7 [SET]`` and the hyperparameter subfolder each one reads ("": the folder itself)
FIG7_SETS: dict[str, tuple[tuple[str, ...], str]] = {"mujoco": (FIG7_TASKS, ""), "dmc": (FIG7_DMC, "dmc")}


@dataclass(frozen=True)
class Suite:
    """A benchmark preset (``--velocity``, ``--navigation``): Safety-Gymnasium's tasks against OmniSafe's tables.

    :param name: the option's name.
    :param algos: SPPO, the constrained baselines (OmniSafe's strongest off-policy one, SACLag, and PDO and CPO) and
        SB3's SAC as the unconstrained reference.
    :param tasks: the suite's tasks.
    :param hyperparams: its hyperparameter subfolder.
    :param steps: the budget of its runs (their ``n_timesteps``).
    :param deployment_episodes: the episodes of each final deployment, as OmniSafe evaluates.
    """

    name: str
    algos: tuple[str, ...]
    tasks: tuple[str, ...]
    hyperparams: str
    steps: int = 100_000
    deployment_episodes: int = 10


#: ``--velocity``: Safety-Gymnasium's velocity tasks
VELOCITY = Suite(
    "velocity",
    ("sppo", "saclag", "pdo", "cpo", "sac"),
    tuple(task.env_id for task in (HALF_CHEETAH, HOPPER, WALKER2D, ANT)),
    "velocity",
)
#: ``--navigation``: Safety-Gymnasium's navigation tasks, those of OmniSafe's model-based and off-policy tables
NAVIGATION = Suite(
    "navigation",
    ("sppo", "saclag", "pdo", "cpo", "sac"),
    ("sppo_sb3/SafetyPointGoal1-v0", "sppo_sb3/SafetyCarGoal1-v0", "sppo_sb3/SafetyPointButton1-v0"),
    "navigation",
)
SUITES: dict[str, Suite] = {suite.name: suite for suite in (VELOCITY, NAVIGATION)}
#: ``--quick``: a few minutes on a laptop (on-policy algorithms still collect one full rollout of ``n_steps``)
QUICK_STEPS: dict[str, int] = {"SafePointCircle-v0": 2048, "SafeHalfCheetahHeight-v1": 256}
QUICK_DEFAULT_STEPS = 2048
QUICK_SEEDS = 2
DEFAULT_SEEDS = 3
#: what ``--quick`` runs when no ``--tasks`` are given (the Cheetah's MPC shield is slow on a CPU)
QUICK_TASKS: tuple[str, ...] = ("SafePointCircle-v0",)


def parse_steps(values: Iterable[str]) -> tuple[int | None, dict[str, int]]:
    """``--steps`` values: ``N`` (every task) and/or ``TASK=N`` (one task).

    :param values: the strings given.
    :return: the default for all tasks (``None``: the yml's) and the per-task overrides.
    """
    default: int | None = None
    per_task: dict[str, int] = {}
    for value in values:
        task, sep, number = value.rpartition("=")
        try:
            steps = int(float(number))
        except ValueError:
            raise ValueError(f"--steps {value!r}: expected N or TASK=N with an integer N") from None
        if steps <= 0:
            raise ValueError(f"--steps {value!r}: N must be positive")
        if sep:
            per_task[task] = steps
        else:
            default = steps
    return default, per_task


def quick_steps(tasks: Sequence[str], steps_default: int | None, steps_per_task: dict[str, int]) -> dict[str, int]:
    """Per-task budgets of ``--quick``: the preset's, under an explicit ``--steps N``, under explicit ``--steps TASK=N``.

    :param tasks: the grid's tasks.
    :param steps_default: ``--steps N`` (``None``: not given).
    :param steps_per_task: the ``--steps TASK=N`` values.
    """
    quick = {t: QUICK_STEPS.get(t, QUICK_DEFAULT_STEPS) if steps_default is None else steps_default for t in tasks}
    return {**quick, **steps_per_task}


def build_grid(
    algos: Sequence[str],
    tasks: Sequence[str],
    seeds: Sequence[int],
    out: Path,
    hyperparams_dir: Path,
    steps_default: int | None = None,
    steps_per_task: dict[str, int] | None = None,
    device: str = "auto",
    zoo_args: Sequence[str] = (),
    last_n: int = 10,
    variant: str = "",
) -> list[RunSpec]:
    """All runs of the grid, tasks outermost (configs are checked for every pair before anything runs).

    :param algos: algorithm names.
    :param tasks: gymnasium ids.
    :param seeds: seeds.
    :param out: the grid's output folder.
    :param hyperparams_dir: folder of the package's hyperparameter files.
    :param steps_default: env steps of every run (``None``: the yml's ``n_timesteps``).
    :param steps_per_task: per-task overrides of ``steps_default``.
    :param device: PyTorch device.
    :param zoo_args: extra train-command arguments.
    :param last_n: final episodes averaged into the reported return.
    :param variant: the runs' variant name (:attr:`~sppo_lab.spec.RunSpec.variant`; ``""``: none).
    :raises ValueError: a pair without hyperparameters, or a bad variant name.
    """
    per_task = steps_per_task or {}
    check_variant(variant)
    specs = []
    for task in tasks:
        for algo in algos:
            config_text = resolve_config(algo, task, hyperparams_dir)
            for seed in seeds:
                specs.append(
                    RunSpec(
                        task=task,
                        algo=algo,
                        seed=seed,
                        run_dir=str(layout.run_dir_for(out, task, run_name(algo, variant), seed)),
                        steps=per_task.get(task, steps_default),
                        config_text=config_text,
                        device=device,
                        zoo_args=list(zoo_args),
                        last_n=last_n,
                        variant=variant,
                    )
                )
    return specs


def is_done(spec: RunSpec) -> bool:
    """Whether the run finished in an earlier invocation (see :func:`sppo_lab.layout.is_finished`).

    :param spec: the run.
    """
    return layout.is_finished(Path(spec.run_dir))
