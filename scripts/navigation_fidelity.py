"""The fidelity table of the navigation tasks: the package's envs against Safety-Gymnasium 1.0.0's recorded runs.

For each recording of ``tests/envs/data/navigation`` (``scripts/record_safety_gymnasium.py``): the layouts of its seeds
rebuilt, and every step replayed from its recorded state (:mod:`sppo_sb3.envs.navigation.replay`). Prints one markdown
row per task: steps compared, the largest layout gap, steps whose cost, cost terms, termination or goal event differ,
the median and largest observation gap (the accelerometer apart), the largest accelerometer and reward gaps, and the
share of steps within 1e-4 (observation) and 1e-5 (reward).

    python scripts/navigation_fidelity.py [--data tests/envs/data/navigation]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from sppo_sb3.envs.navigation.replay import Recording, compare_layouts, replay_steps

DATA = Path(__file__).resolve().parents[1] / "tests" / "envs" / "data" / "navigation"
COLUMNS = ("task", "steps", "layout gap", "discrete mismatches", "obs gap median", "obs gap max", "accelerometer max",
           "reward gap max", "steps within tolerance")  # fmt: skip


def row(recording: Recording) -> list[str]:
    """The table's row of one recording."""
    layouts, steps = compare_layouts(recording), replay_steps(recording)
    others = np.max([gap for key, gap in steps.obs.items() if key != "accelerometer"], axis=0)
    close = (others <= 1e-4) & (steps.reward <= 1e-5)
    return [
        recording.env_id.removesuffix("-v0"),
        str(recording.steps),
        f"{max(layouts.position, layouts.goal):.0e}",
        str(steps.discrete_mismatches),
        f"{np.median(others):.0e}",
        f"{others.max():.0e}",
        f"{steps.obs['accelerometer'].max():.0e}",
        f"{steps.reward.max():.0e}",
        f"{100 * close.mean():.0f}%",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DATA, help="the recordings' folder")
    args = parser.parse_args()
    recordings = sorted(args.data.glob("Safety*.npz"))
    if not recordings:
        raise SystemExit(f"no recordings (Safety*.npz) in {args.data}: run scripts/record_safety_gymnasium.py")
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for path in recordings:
        print("| " + " | ".join(row(Recording.load(path))) + " |")


if __name__ == "__main__":
    main()
