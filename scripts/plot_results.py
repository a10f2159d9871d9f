"""Figures and tables of the paper's comparison from a ``scripts/benchmark.py`` output folder.

A thin command line over :mod:`sppo_lab` (see ``--help``). Writes to ``--out``:

- ``learning_curves.png``: episode return vs env steps, mean over seeds with its 95% bootstrap CI, one panel per task
  (Figs. 5–6 left);
- ``violations.png``: cumulative constraint violations at the end of training per algorithm, mean over seeds with its
  95% bootstrap CI and each seed as a dot, one panel per task (Figs. 5–6 right);
- ``cumulative_violations.png``: cumulative violations vs env steps (mean, 95% bootstrap CI), one panel per task;
- ``tables.md``: Tables I–II: order of magnitude of the cumulative violations and safety rate (mean [95% CI] over
  seeds, and the IQM from 4 seeds) beside the paper's numbers, with return, episodes, env steps and throughput;
- ``aggregate.csv``: the per-(task, algorithm) aggregates behind them.

``--fig7`` instead writes ``fig7_curves.png`` (return curves of SPPO, DDPG and PPO per task, as Fig. 7) and
``fig7_table.md`` (final returns). The intervals are percentile bootstraps over seeds (scipy). Needs matplotlib and
scipy (``pip install "sppo_sb3[plots]"``).

Example::

    python scripts/plot_results.py results/quick --out results/quick/figures
"""

from __future__ import annotations

import sys

from sppo_lab.plot import main

if __name__ == "__main__":
    sys.exit(main())
