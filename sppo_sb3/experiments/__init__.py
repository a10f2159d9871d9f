"""The paper's comparison as a library: run a grid of trainings, resume it, summarise and plot its runs.

``scripts/benchmark.py`` and ``scripts/plot_results.py`` are thin command lines over it:

- :mod:`~sppo_sb3.experiments.layout`: the run-folder format (``OUT/<task>/<algo>/seed_<s>/``), written and read here;
- :mod:`~sppo_sb3.experiments.configs`: which hyperparameters a run trains with;
- :mod:`~sppo_sb3.experiments.grid`: the grid (algorithms × tasks × seeds), its presets, what is left to do;
- :mod:`~sppo_sb3.experiments.runner`: one run (a ``python -m sppo_sb3.train`` subprocess), many in parallel or on Ray;
- :mod:`~sppo_sb3.experiments.summary`: a run's curve and ``summary.json``;
- :mod:`~sppo_sb3.experiments.stats`, :mod:`~sppo_sb3.experiments.tables`, :mod:`~sppo_sb3.experiments.figures`:
  aggregates over seeds (mean, 95% bootstrap CI, IQM), Tables I–II, Figs. 5–7;
- :mod:`~sppo_sb3.experiments.plan`: the paper-scale grid's core-hours from measured throughput (``--plan``);
- :mod:`~sppo_sb3.experiments.benchmark`, :mod:`~sppo_sb3.experiments.plot`: the two command lines.

The algorithms come from the package's one list, :data:`sppo_sb3.algorithms.ALGORITHMS`.
"""
