"""The benchmark on a local Ray instance: a run killed partway is recorded as failed, and a rerun resumes the grid.

``scripts/benchmark.py``'s Ray path (:func:`sppo_lab.benchmark.main` with ``--ray-address local``, on a
2-CPU instance started here), ``pdo`` × 2 seeds with tiny networks, each run's results sent back by its Ray task. The
test kills one run's ``sppo_sb3.train`` process (found among this process's descendants) once its first episode is
logged, then reruns the same command: the finished run is left alone, the killed one runs again and the grid is
complete. Needs Ray (``pip install "sppo_sb3[ray]"``) and Linux's ``/proc``.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from tiny_hyperparams import tiny_pdo_yml

from sppo_lab import benchmark, layout

ray = pytest.importorskip("ray")

TASK = "SafePointCircle-v0"
STEPS = 2048
KILLED_SEED = 1
PDO_YML = tiny_pdo_yml(TASK, STEPS)
#: how long the test waits for the run to kill to log its first episode
KILL_TIMEOUT_S = 300.0

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the run's process in /proc")


@pytest.fixture(scope="module")
def local_ray() -> Iterator[None]:
    """A fresh 2-CPU local Ray instance for the module (the benchmark's ``--ray-address local`` uses it), shut down after."""
    ray.init(num_cpus=2, include_dashboard=False)
    try:
        yield
    finally:
        ray.shutdown()


def _process_table() -> dict[int, tuple[int, list[str]]]:
    """Every process's parent pid and command line, from ``/proc``."""
    table = {}
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            stat = (proc / "stat").read_text()
            cmdline = (proc / "cmdline").read_bytes()
        except OSError:  # it ended meanwhile
            continue
        parent = int(stat.rsplit(")", 1)[1].split()[1])  # "pid (comm) state ppid ...", comm may hold spaces
        table[int(proc.name)] = (parent, [arg.decode(errors="replace") for arg in cmdline.split(b"\0") if arg])
    return table


def _descends_from(pid: int, ancestor: int, table: dict[int, tuple[int, list[str]]]) -> bool:
    while pid in table and pid > 1:
        pid = table[pid][0]
        if pid == ancestor:
            return True
    return False


def _train_process(seed: int) -> tuple[int, Path] | None:
    """This test's ``sppo_sb3.train`` process of ``seed`` (a descendant of this process: Ray's worker's child) and its
    rl-zoo3 folder (``-f``), if it runs."""
    table = _process_table()
    for pid, (_, args) in table.items():
        is_train = "sppo_sb3.train" in args and "--seed" in args and args[args.index("--seed") + 1] == str(seed)
        if is_train and _descends_from(pid, os.getpid(), table):
            return pid, Path(args[args.index("-f") + 1])
    return None


def _logged_episodes(zoo_dir: Path) -> int:
    """Episodes in rl-zoo3's monitor files (each starts with a JSON line and a CSV header)."""
    return sum(max(0, len(path.read_text().splitlines()) - 2) for path in zoo_dir.rglob("*monitor.csv"))


def _kill_after_first_episode(seed: int, done: threading.Event, killed: list[int]) -> None:
    """SIGKILL the run's train process once it has logged an episode (so partway through training)."""
    deadline = time.monotonic() + KILL_TIMEOUT_S
    while not done.is_set() and time.monotonic() < deadline:
        found = _train_process(seed)
        if found is not None and _logged_episodes(found[1]) >= 1:
            os.kill(found[0], signal.SIGKILL)
            killed.append(found[0])
            return
        time.sleep(0.05)


def _benchmark_args(out: Path, hyperparams: Path) -> list[str]:
    return [
        "--algos",
        "pdo",
        "--tasks",
        TASK,
        "--seeds",
        "2",
        "--steps",
        str(STEPS),
        "--hyperparams-dir",
        str(hyperparams),
        "--device",
        "cpu",
        "--ray-address",
        "local",
        "--out",
        str(out),
    ]


def test_killed_run_is_recorded_as_failed_and_the_rerun_resumes_the_grid(
    local_ray: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hyperparams = tmp_path / "hyperparams"
    hyperparams.mkdir()
    (hyperparams / "pdo.yml").write_text(PDO_YML)
    out = tmp_path / "results"
    args = _benchmark_args(out, hyperparams)
    finished, killed_run = (layout.run_dir_for(out, TASK, "pdo", seed) for seed in (1 - KILLED_SEED, KILLED_SEED))

    done, killed = threading.Event(), []
    killer = threading.Thread(target=_kill_after_first_episode, args=(KILLED_SEED, done, killed))
    killer.start()
    try:
        first_status = benchmark.main(args)
    finally:
        done.set()
        killer.join()
    assert killed, f"seed {KILLED_SEED}'s train process was not seen logging an episode"
    assert first_status == 1  # a run failed
    assert layout.is_finished(finished) and not (finished / layout.FAILED_FILE).exists()
    assert not layout.is_finished(killed_run) and not (killed_run / layout.SUMMARY_FILE).exists()
    assert (killed_run / layout.FAILED_FILE).read_text().startswith(f"exit status {-signal.SIGKILL}")
    assert (killed_run / layout.LOG_FILE).is_file()  # its log came back from the Ray task
    summary, stamps = (finished / layout.SUMMARY_FILE).read_text(), _mtimes(finished)
    capsys.readouterr()

    assert benchmark.main(args) == 0  # the same command again
    assert "1 already finished, 1 to run on Ray (local)" in capsys.readouterr().out
    assert (finished / layout.SUMMARY_FILE).read_text() == summary and _mtimes(finished) == stamps  # not rerun
    assert layout.is_finished(killed_run) and not (killed_run / layout.FAILED_FILE).exists()
    assert layout.read_summary(killed_run)["steps"] >= STEPS
    assert tuple(layout.read_curve(killed_run).columns) == layout.CURVE_COLUMNS
    assert layout.finished_run_dirs(out) == sorted([finished, killed_run])


def _mtimes(run_dir: Path) -> dict[str, int]:
    """Modification times of a run folder's files (``zoo/`` included)."""
    return {str(path.relative_to(run_dir)): path.stat().st_mtime_ns for path in sorted(run_dir.rglob("*"))}
