"""One run of the benchmark's grid, as plain data: what the grid builds, the runner runs and the summary records."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class RunSpec:
    """One run of the grid.

    :param task: gymnasium id of the task.
    :param algo: rl-zoo3 name of the algorithm.
    :param seed: random seed.
    :param run_dir: the run's output folder (``OUT/<task>/<algo>/seed_<s>``), as seen by the driver.
    :param steps: env steps (``-n``); ``None``: the hyperparameter file's ``n_timesteps``.
    :param config_text: the yml given to ``-conf`` (written into the run folder); ``None``: rl-zoo3's own.
    :param device: PyTorch device (``--device`` of the train command).
    :param zoo_args: extra arguments for the train command (after the runner's own, so they win).
    :param last_n: number of final episodes averaged into the reported return.
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

    @property
    def label(self) -> str:
        """``task / algo / seed`` for progress lines."""
        return f"{self.task} / {self.algo} / seed {self.seed}"
