"""rl-zoo3 integration: the package's algorithms, samplers and safety outputs, registered with the zoo.

:func:`register_algos` (:mod:`~sppo_sb3.zoo.registration`) adds the package's algorithms
(:data:`sppo_sb3.algorithms.ALGORITHMS`: ``sppo``, ``pdo``, ``cpo``, ``sailr``, ``csc``, ``saclag``) to rl-zoo3's
``ALGOS`` (an algorithm whose module does not import is skipped with a warning and listed in :data:`UNAVAILABLE`) and
their Optuna samplers (:mod:`~sppo_sb3.zoo.samplers`) to ``HYPERPARAMS_SAMPLER``/``HYPERPARAMS_CONVERTER``.
:func:`install` (:mod:`~sppo_sb3.zoo.patches`, where every monkeypatch of rl-zoo3 lives) does that and makes rl-zoo3's
train command cost-aware (used by ``sppo-train``):

- every env that rl-zoo3 creates gets :class:`~sppo_sb3.common.monitor.EpisodeCostInfo` inside its ``Monitor``,
  whose ``monitor.csv`` gains the columns ``episode_cost``, ``episode_violations`` and ``episode_interventions``;
- the evaluation callback is :class:`~sppo_sb3.common.monitor.CostEvalCallback` (``eval/mean_cost`` beside
  ``eval/mean_reward``, ``costs``/``violations`` in ``evaluations.npz``);
- :class:`SafeExperimentManager` (:mod:`~sppo_sb3.zoo.experiment`) reads the package's own hyperparameters when no
  ``-conf`` is given (:func:`~sppo_sb3.zoo.hyperparams.default_config`: ``hyperparams/ALGO.yml``, or the task family's
  ``velocity/`` or ``dmc/`` file, shipped in the wheel), prints the model's safety summary at the end of
  training (and writes it to ``safety_summary.json`` in the run folder), evaluates ``*_kwargs`` strings of the yml
  (``planner_kwargs: "dict(...)"``, :mod:`~sppo_sb3.zoo.hyperparams`) as the zoo does for ``policy_kwargs``, and gives
  hyperparameter search a violation budget (:mod:`~sppo_sb3.zoo.budget`).

**Violation budget** (``--violation-budget B`` of ``sppo-train``, or ``SPPO_VIOLATION_BUDGET``): a trial whose
*training* cumulative violations (``model.safety_metrics``) exceed ``B`` is stopped and pruned at once. With
``--violation-penalty P`` (or ``SPPO_VIOLATION_PENALTY``) it is trained to the end instead and its objective becomes
``mean eval return - P * max(0, violations - B)`` (``B`` defaults to 0). Every trial records
``cumulative_violations``, ``safety_rate``, ``eval_mean_cost`` and ``eval_mean_reward`` as Optuna user attributes.

The modules import each other downward only: :mod:`~sppo_sb3.zoo.hyperparams`, :mod:`~sppo_sb3.zoo.samplers` and
:mod:`~sppo_sb3.zoo.budget` import none of the others; :mod:`~sppo_sb3.zoo.registration` imports the samplers,
:mod:`~sppo_sb3.zoo.experiment` the hyperparams and the budget, and :mod:`~sppo_sb3.zoo.patches` sits on top.
"""

from sppo_sb3.zoo.budget import BUDGET_ENV_VAR, PENALTY_ENV_VAR, SafeTrialEvalCallback
from sppo_sb3.zoo.experiment import DEFAULT_DEPLOYMENT_EPISODES, SafeExperimentManager
from sppo_sb3.zoo.hyperparams import (
    FAMILY_FOLDERS,
    constructor_kwargs,
    default_config,
    eval_kwargs_strings,
    eval_yml_string,
    merge_kwargs,
)
from sppo_sb3.zoo.patches import install
from sppo_sb3.zoo.registration import UNAVAILABLE, algo_classes, register_algos, register_samplers
from sppo_sb3.zoo.samplers import TOLD_SIZES, convert_sppo_params, sample_sppo_params

__all__ = [
    "BUDGET_ENV_VAR",
    "DEFAULT_DEPLOYMENT_EPISODES",
    "FAMILY_FOLDERS",
    "PENALTY_ENV_VAR",
    "TOLD_SIZES",
    "UNAVAILABLE",
    "SafeExperimentManager",
    "SafeTrialEvalCallback",
    "algo_classes",
    "constructor_kwargs",
    "convert_sppo_params",
    "default_config",
    "eval_kwargs_strings",
    "eval_yml_string",
    "install",
    "merge_kwargs",
    "register_algos",
    "register_samplers",
    "sample_sppo_params",
]
