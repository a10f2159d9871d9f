"""Run the paper's comparison grid (algorithms × tasks × seeds) through the package's own training entry point.

A thin command line over :mod:`sppo_lab` (see ``--help``). Every run is ``python -m sppo_sb3.train
--algo ALGO --env TASK [-conf HYPERPARAMS/ALGO.yml] [-n STEPS] --seed S ...`` in a subprocess, so it is exactly what a
user gets from ``sppo-train``; its results go to ``OUT/<task>/<algo>/seed_<s>/`` (``curve.csv``, ``summary.json``,
``train.log``, ``hyperparams.yml``, ``zoo/`` and the ``DONE`` marker: :mod:`sppo_lab.layout`). Finished
runs are skipped (``--force`` reruns them); failed ones are retried.

Examples::

    python scripts/benchmark.py --quick --out results/quick
    python scripts/benchmark.py --tasks SafePointCircle-v0 --seeds 8 --out results/paper   # paper scale, Table I
    python scripts/benchmark.py --fig7 --seeds 3 --steps 100000 --out results/fig7
    python scripts/benchmark.py --ray-address auto --seeds 8 --out /shared/results         # on a Ray cluster
    python scripts/benchmark.py --plan --out results/quick --workers 64   # paper-scale core-hours, measured there
"""

from __future__ import annotations

import sys
from pathlib import Path

from sppo_lab.benchmark import main

if __name__ == "__main__":
    sys.exit(main(default_hyperparams_dir=Path(__file__).resolve().parents[1] / "hyperparams"))
