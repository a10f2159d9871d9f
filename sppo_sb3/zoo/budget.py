"""The violation budget of hyperparameter search: its settings, the trial callback that enforces it, the objective.

See :mod:`sppo_sb3.zoo` for what the budget does. Imports nothing else of :mod:`sppo_sb3.zoo`;
:class:`~sppo_sb3.zoo.experiment.SafeExperimentManager` sets the budget on each trial and
:func:`~sppo_sb3.zoo.patches.install` makes rl-zoo3 use :class:`SafeTrialEvalCallback`.
"""

from __future__ import annotations

import os

from rl_zoo3.callbacks import TrialEvalCallback

from sppo_sb3.common.monitor import CostEvalCallback

BUDGET_ENV_VAR = "SPPO_VIOLATION_BUDGET"
PENALTY_ENV_VAR = "SPPO_VIOLATION_PENALTY"


def _env_float(name: str) -> float | None:
    value = os.environ.get(name, "").strip()
    return float(value) if value else None


def resolve_violation_budget(budget: float | None, penalty: float | None) -> tuple[float | None, float | None]:
    """The budget and penalty a study uses: the given ones, else the environment's; a penalty alone implies budget 0.

    :param budget: cumulative training violations allowed per trial (``None``: ``SPPO_VIOLATION_BUDGET``).
    :param penalty: objective penalty per violation above the budget (``None``: ``SPPO_VIOLATION_PENALTY``).
    :return: ``(budget, penalty)``, each ``None`` when unset.
    """
    budget = budget if budget is not None else _env_float(BUDGET_ENV_VAR)
    penalty = penalty if penalty is not None else _env_float(PENALTY_ENV_VAR)
    if penalty is not None and budget is None:
        budget = 0.0
    return budget, penalty


def penalised_objective(value: float, violations: float | None, budget: float | None, penalty: float | None) -> float:
    """A trial's objective: ``value - penalty * max(0, violations - budget)`` (``value`` when any of them is unset).

    :param value: rl-zoo3's objective (mean evaluation return).
    :param violations: the trial's cumulative training violations.
    :param budget: violations allowed.
    :param penalty: penalty per violation above ``budget``.
    :return: the penalised objective.
    """
    if penalty is not None and budget is not None and violations is not None:
        value -= penalty * max(0.0, float(violations) - budget)
    return value


class SafeTrialEvalCallback(CostEvalCallback, TrialEvalCallback):
    """rl-zoo3's ``TrialEvalCallback`` with evaluation cost and the violation budget of the study.

    Reads the budget from the trial's user attributes (``violation_budget``, ``violation_budget_mode``) and, in
    ``"prune"`` mode, stops the trial as soon as the model's cumulative training violations exceed it.
    """

    def _init_callback(self) -> None:
        super()._init_callback()
        attrs = self.trial.user_attrs
        self.violation_budget: float | None = attrs.get("violation_budget")
        self.prune_on_budget = attrs.get("violation_budget_mode") == "prune"

    def _violations(self) -> float | None:
        metrics = getattr(self.model, "safety_metrics", None)
        return float(metrics.violations) if metrics is not None else None

    def _on_step(self) -> bool:
        if not super()._on_step():
            return False
        violations = self._violations()
        budget = self.violation_budget
        if self.prune_on_budget and budget is not None and violations is not None and violations > budget:
            self.trial.set_user_attr("budget_exceeded_at", int(self.num_timesteps))
            self.is_pruned = True
            return False
        return True

    def _on_training_end(self) -> None:
        metrics = getattr(self.model, "safety_metrics", None)
        if metrics is not None:
            summary = metrics.summary()
            self.trial.set_user_attr("cumulative_violations", summary["cumulative_violations"])
            self.trial.set_user_attr("safety_rate", summary["safety_rate"])
            self.trial.set_user_attr("episodes", summary["episodes"])
        self.trial.set_user_attr("eval_mean_reward", float(self.last_mean_reward))
        self.trial.set_user_attr("eval_mean_cost", float(self.last_mean_cost))
