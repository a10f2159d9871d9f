"""The paper's comparison as a library: run a grid of trainings, resume it, summarise and plot its runs.

``scripts/benchmark.py`` and ``scripts/plot_results.py`` are thin command lines over it:

- :mod:`~sppo_lab.layout`: the run-folder format (``OUT/<task>/<algo>/seed_<s>/``), written and read here;
- :mod:`~sppo_lab.configs`: which hyperparameters a run trains with;
- :mod:`~sppo_lab.grid`: the grid (algorithms × tasks × seeds), its presets, what is left to do;
- :mod:`~sppo_lab.runner`: one run (a ``python -m sppo_sb3.train`` subprocess), many in parallel or on Ray;
- :mod:`~sppo_lab.summary`: a run's curve and ``summary.json``;
- :mod:`~sppo_lab.stats`, :mod:`~sppo_lab.tables`, :mod:`~sppo_lab.figures`:
  aggregates over seeds (mean, 95% bootstrap CI, IQM), Tables I–II, Figs. 5–7;
- :mod:`~sppo_lab.plan`: the paper-scale grid's core-hours from measured throughput (``--plan``);
- :mod:`~sppo_lab.benchmark`, :mod:`~sppo_lab.plot`: the two command lines.

The algorithms come from the package's one list, :data:`sppo_sb3.algorithms.ALGORITHMS`.
"""
