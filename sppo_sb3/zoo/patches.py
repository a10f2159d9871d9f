"""Every monkeypatch of rl-zoo3's modules that training needs, applied by :func:`install` (the top of the package).

Each replacement is a superset of the original, so rl-zoo3's own code runs unchanged around it. The only other patch
of rl-zoo3 in the package is scoped: :meth:`SafeExperimentManager.hyperparameters_optimization
<sppo_sb3.zoo.experiment.SafeExperimentManager.hyperparameters_optimization>` wraps the algorithm's sampler for the
duration of a search (``sppo-enjoy`` also wraps rl-zoo3's ``create_test_env``, in :mod:`sppo_sb3.enjoy`).
"""

from __future__ import annotations

import rl_zoo3.exp_manager as zoo_exp_manager

from sppo_sb3.common.monitor import CostEvalCallback, cost_monitored_make_vec_env
from sppo_sb3.zoo.budget import SafeTrialEvalCallback
from sppo_sb3.zoo.experiment import DEFAULT_DEPLOYMENT_EPISODES, SafeExperimentManager
from sppo_sb3.zoo.registration import register_algos


def install(
    violation_budget: float | None = None,
    violation_penalty: float | None = None,
    deployment_episodes: int = DEFAULT_DEPLOYMENT_EPISODES,
) -> type[SafeExperimentManager]:
    """Register the algorithms and make rl-zoo3's train command cost-aware (idempotent).

    Replaces, in rl-zoo3's ``exp_manager`` module, ``make_vec_env`` by
    :func:`~sppo_sb3.common.monitor.cost_monitored_make_vec_env`, ``EvalCallback`` by
    :class:`~sppo_sb3.common.monitor.CostEvalCallback` and ``TrialEvalCallback`` by
    :class:`~sppo_sb3.zoo.budget.SafeTrialEvalCallback` (each a superset of the original), and rl-zoo3's train
    ``ExperimentManager`` by :class:`~sppo_sb3.zoo.experiment.SafeExperimentManager`.

    :param violation_budget: see :mod:`sppo_sb3.zoo` (``None``: the ``SPPO_VIOLATION_BUDGET`` variable).
    :param violation_penalty: see :mod:`sppo_sb3.zoo` (``None``: the ``SPPO_VIOLATION_PENALTY`` variable).
    :param deployment_episodes: episodes of each deployment (with and without the shield) evaluated after training
        (0: none).
    :return: the experiment manager class now used by ``rl_zoo3.train``.
    """
    import rl_zoo3.train as zoo_train

    register_algos()
    # patch exp_manager.make_vec_env: training and eval envs get EpisodeCostInfo inside their Monitor (cost columns)
    zoo_exp_manager.make_vec_env = cost_monitored_make_vec_env  # type: ignore[assignment]
    # patch exp_manager.EvalCallback: evaluations also log eval/mean_cost and save costs/violations in evaluations.npz
    zoo_exp_manager.EvalCallback = CostEvalCallback  # type: ignore[misc]
    # patch exp_manager.TrialEvalCallback: Optuna trials record safety attributes and honour the violation budget
    zoo_exp_manager.TrialEvalCallback = SafeTrialEvalCallback  # type: ignore[misc]
    SafeExperimentManager.violation_budget = violation_budget
    SafeExperimentManager.violation_penalty = violation_penalty
    SafeExperimentManager.deployment_episodes = deployment_episodes
    # patch train.ExperimentManager: rl-zoo3's train() builds ours (safety summary, *_kwargs strings, budget)
    zoo_train.ExperimentManager = SafeExperimentManager  # type: ignore[misc]
    return SafeExperimentManager
