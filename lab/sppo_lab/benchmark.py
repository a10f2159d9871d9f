"""The command line of ``scripts/benchmark.py``: run the comparison grid, skipping the runs that already finished.

Runs go to parallel local processes (``--workers``, default: the number of cores) or, with ``--ray-address``, to Ray
tasks on an existing cluster. A run with a ``DONE`` marker is skipped (``--force`` reruns it); a run that failed
leaves ``FAILED`` and is retried by the next invocation. The algorithms are the package's (configured by
``--hyperparams-dir``) and any of rl-zoo3's built-in ones (:func:`~sppo_lab.configs.resolve_config`).
``--plan`` prints the paper-scale grid's (or with ``--velocity`` or ``--navigation`` that grid's) core-hours and what is
left of it, from the throughput of the runs in ``--out`` (:mod:`~sppo_lab.plan`).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sppo_lab import grid, layout, plan
from sppo_lab.configs import REPO_HYPERPARAMS_DIR
from sppo_lab.runner import dry_run_command, finalize, import_ray, progress_line, run_local, run_ray
from sppo_lab.spec import RunSpec

DESCRIPTION = "Run the paper's comparison grid (algorithms × tasks × seeds) through the package's own training entry point."


def parse_args(argv: Sequence[str] | None = None, default_hyperparams_dir: Path = REPO_HYPERPARAMS_DIR) -> argparse.Namespace:
    """Command-line options (see ``--help``).

    :param argv: the arguments (default: ``sys.argv[1:]``).
    :param default_hyperparams_dir: ``--hyperparams-dir`` when not given.
    """
    parser = argparse.ArgumentParser(description=DESCRIPTION, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("results"), help="output folder (default: results)")
    parser.add_argument("--algos", nargs="+", default=None, help=f"algorithms (default: {' '.join(grid.OUR_ALGOS)})")
    parser.add_argument("--tasks", nargs="+", default=None, help=f"tasks (default: {' '.join(grid.SAFE_TASKS)})")
    parser.add_argument("--seeds", type=int, default=None, help="number of seeds 0..N-1 (default: 3; --quick: 2)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed (default: 0)")
    parser.add_argument(
        "--steps",
        action="append",
        default=[],
        metavar="[TASK=]N",
        help="env steps per run: N for every task, TASK=N for one (repeatable; default: the yml's n_timesteps)",
    )
    parser.add_argument(
        "--hyperparams-dir",
        type=Path,
        default=None,
        help=f"folder of ALGO.yml files (default: {default_hyperparams_dir}; --fig7 dmc: its dmc/ subfolder)",
    )
    parser.add_argument(
        "--variant",
        default="",
        help="name these runs as a variant of their algorithms, run under other settings (e.g. --hyperparams-dir\n"
        "lab/hyperparams/point_shielded --variant shielded): folders OUT/<task>/<algo>-<variant>, rows 'CPO (shielded)'",
    )
    parser.add_argument("--quick", action="store_true", help="tiny preset: 2 seeds, 2048 steps (Half-Cheetah: 256)")
    fig7 = (
        f"Fig. 7 grid: {' '.join(grid.FIG7_ALGOS)} on {' '.join(grid.FIG7_TASKS)};\n"
        f'--fig7 dmc: on the paper\'s dm_control tasks {" ".join(grid.FIG7_DMC)} (pip install "sppo_sb3[dmc]")'
    )
    parser.add_argument("--fig7", nargs="?", const="mujoco", default=None, choices=tuple(grid.FIG7_SETS), help=fig7)
    for suite in grid.SUITES.values():
        parser.add_argument(
            f"--{suite.name}",
            action="store_true",
            help=f"Safety-Gymnasium's {suite.name} tasks: {' '.join(suite.algos)} on {' '.join(suite.tasks)},\n"
            f"hyperparams/{suite.hyperparams}/ ({suite.steps:.0e} env steps), each final policy deployed for "
            f"{suite.deployment_episodes} episodes",
        )
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="parallel local runs (default: cores)")
    parser.add_argument("--ray-address", default=None, help="run as Ray tasks on this cluster (auto, ray://host:port)")
    parser.add_argument("--ray-cpus-per-run", type=float, default=1.0, help="CPUs Ray reserves per run (default: 1)")
    parser.add_argument("--ray-shared-fs", action="store_true", help="--out is on a filesystem shared by all Ray nodes")
    parser.add_argument("--device", default="auto", help="PyTorch device of every run (default: auto)")
    parser.add_argument("--last-n", type=int, default=10, help="episodes averaged into the final return (default: 10)")
    parser.add_argument(
        "--zoo-args", default="", help='extra train arguments, one string (e.g. "--eval-freq 10000 --n-eval-envs 2")'
    )
    parser.add_argument("--force", action="store_true", help="rerun finished runs too")
    parser.add_argument("--dry-run", action="store_true", help="print the runs' commands and exit")
    parser.add_argument(
        "--plan",
        action="store_true",
        help="print the paper-scale grid's core-hours (with --velocity or --navigation: that grid's), measured on the\n"
        "finished runs in --out, and the wall clock of the runs left on --workers cores; then exit",
    )
    args = parser.parse_args(argv)
    suites = [grid.SUITES[name] for name in grid.SUITES if getattr(args, name)]
    if len(suites) + bool(args.fig7) > 1:
        parser.error(f"--{', --'.join(grid.SUITES)} and --fig7 are separate grids: give one")
    args.suite = suites[0] if suites else None
    if args.hyperparams_dir is None:
        subfolder = args.suite.hyperparams if args.suite else grid.FIG7_SETS[args.fig7 or "mujoco"][1]
        args.hyperparams_dir = default_hyperparams_dir / subfolder
    if args.suite:  # before the user's own --zoo-args, which win
        args.zoo_args = f"--deployment-episodes {args.suite.deployment_episodes} {args.zoo_args}".strip()
    return args


def grid_axes(args: argparse.Namespace) -> tuple[list[str], list[str], list[int]]:
    """The algorithms, tasks and seeds the options ask for (``--quick``, ``--fig7`` and the suites' presets applied).

    :param args: :func:`parse_args`'s result.
    :raises SystemExit: an option out of range.
    """
    if args.suite:
        default_algos, default_tasks = args.suite.algos, args.suite.tasks
    elif args.fig7:
        default_algos, default_tasks = grid.FIG7_ALGOS, grid.FIG7_SETS[args.fig7][0]
    else:
        default_algos, default_tasks = grid.OUR_ALGOS, grid.QUICK_TASKS if args.quick else grid.SAFE_TASKS
    algos, tasks = args.algos or list(default_algos), args.tasks or list(default_tasks)
    n_seeds = args.seeds if args.seeds is not None else (grid.QUICK_SEEDS if args.quick else grid.DEFAULT_SEEDS)
    if n_seeds < 1 or args.workers < 1 or args.last_n < 1:
        raise SystemExit("--seeds, --workers and --last-n must be at least 1")
    return algos, tasks, list(range(args.first_seed, args.first_seed + n_seeds))


def grid_steps(args: argparse.Namespace, tasks: Sequence[str]) -> tuple[int | None, dict[str, int]]:
    """Env steps of every run (``None``: the yml's) and per task, from ``--steps`` and ``--quick``.

    :param args: :func:`parse_args`'s result.
    :param tasks: the grid's tasks.
    :raises SystemExit: a malformed ``--steps``.
    """
    try:
        steps_default, steps_per_task = grid.parse_steps(args.steps)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    if args.quick:
        steps_per_task = grid.quick_steps(tasks, steps_default, steps_per_task)
    return steps_default, steps_per_task


def run_grid(todo: Sequence[RunSpec], args: argparse.Namespace) -> list[RunSpec]:
    """Run ``todo`` with a progress bar, writing each run's folder as it finishes.

    :param todo: the runs.
    :param args: :func:`parse_args`'s result (where and how to run).
    :return: the runs that failed.
    """
    from tqdm import tqdm

    failed: list[RunSpec] = []
    with tqdm(total=len(todo), unit="run", dynamic_ncols=True, file=sys.stderr) as bar:

        def report(spec: RunSpec, result: dict[str, Any]) -> None:
            finalize(spec, result)
            if not result["ok"]:
                failed.append(spec)
            bar.update(1)
            bar.write(progress_line(bar.n, len(todo), spec, result))

        if args.ray_address is not None:
            run_ray(todo, args.ray_address, report, args.ray_cpus_per_run, args.ray_shared_fs)
        else:
            run_local(todo, args.workers, report)
    return failed


def print_plan(args: argparse.Namespace) -> int:
    """Print the plan (:func:`~sppo_lab.plan.plan_markdown`) of the paper-scale grid, or with
    ``--velocity`` / ``--navigation`` of the suite's grid the options name (its algorithms, tasks, seeds; ``--steps``
    or its budget), with the runs left in ``--out``; returns the exit status.

    :param args: :func:`parse_args`'s result: ``--out``, whose finished runs measure the throughput, and ``--workers``,
        the cores of the wall clock.
    """
    algos, tasks, seeds = grid_axes(args)
    summaries = plan.load_summaries(args.out)
    if summaries.empty:
        print(f"benchmark --plan: no finished runs under {args.out} to measure the throughput on", file=sys.stderr)
        return 1
    throughput = plan.measured_throughput(summaries)
    if args.suite:
        steps = grid_steps(args, tasks)[0] or args.suite.steps
        grid_plan = plan.grid_plan(throughput, dict.fromkeys(tasks, seeds), algos, steps, finished=summaries)
    else:
        steps = plan.PAPER_STEPS
        grid_plan = plan.grid_plan(throughput, finished=summaries)
    print(plan.plan_markdown(grid_plan, args.workers, steps), end="")
    return 0


def main(argv: Sequence[str] | None = None, default_hyperparams_dir: Path = REPO_HYPERPARAMS_DIR) -> int:
    """Run the grid; returns the exit status (1 when a run failed).

    :param argv: command-line arguments (default: ``sys.argv[1:]``).
    :param default_hyperparams_dir: ``--hyperparams-dir`` when not given.
    """
    args = parse_args(argv, default_hyperparams_dir)
    if args.plan:
        return print_plan(args)
    algos, tasks, seeds = grid_axes(args)
    steps_default, steps_per_task = grid_steps(args, tasks)
    if args.ray_address is not None:
        import_ray()  # fail before anything runs
    try:
        specs = grid.build_grid(
            algos,
            tasks,
            seeds,
            args.out,
            args.hyperparams_dir,
            steps_default,
            steps_per_task,
            args.device,
            shlex.split(args.zoo_args),
            args.last_n,
            args.variant,
        )
    except ValueError as exc:
        raise SystemExit(f"benchmark: {exc}") from None
    todo = [spec for spec in specs if args.force or not grid.is_done(spec)]
    where = f"on Ray ({args.ray_address})" if args.ray_address else f"with {min(args.workers, max(len(todo), 1))} workers"
    print(
        f"{len(specs)} runs ({len(algos)} algorithms x {len(tasks)} tasks x {len(seeds)} seeds) -> {args.out}; "
        f"{len(specs) - len(todo)} already finished, {len(todo)} to run {where}",
        flush=True,
    )
    if args.dry_run:
        for spec in todo:
            print(shlex.join(dry_run_command(spec)))
        return 0
    if not todo:
        return 0
    start = time.perf_counter()
    failed = run_grid(todo, args)
    print(f"{len(todo) - len(failed)}/{len(todo)} runs finished in {time.perf_counter() - start:.0f} s -> {args.out}")
    for spec in failed:
        print(f"FAILED: {spec.label}: {Path(spec.run_dir) / layout.FAILED_FILE}", file=sys.stderr)
    return 1 if failed else 0
