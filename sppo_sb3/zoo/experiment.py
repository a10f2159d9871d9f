""":class:`SafeExperimentManager`: rl-zoo3's ``ExperimentManager`` with the package's safety outputs.

Above :mod:`~sppo_sb3.zoo.hyperparams` (the yml's ``*_kwargs`` strings) and :mod:`~sppo_sb3.zoo.budget` (the violation
budget) in the package; :func:`~sppo_sb3.zoo.patches.install` makes rl-zoo3's train command use it.
"""

from __future__ import annotations

import inspect
import json
import os
from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import optuna
import yaml
from rl_zoo3 import hyperparams_opt as zoo_opt
from rl_zoo3.exp_manager import ExperimentManager
from stable_baselines3.common.base_class import BaseAlgorithm

import sppo_sb3  # noqa: F401  (registers the tasks with gymnasium)
from sppo_sb3.common.keys import DEPLOYMENT_SHIELDED, DEPLOYMENT_UNSHIELDED
from sppo_sb3.common.monitor import CostEvalCallback
from sppo_sb3.shield.evaluation import evaluate_deployment
from sppo_sb3.zoo.budget import penalised_objective, resolve_violation_budget
from sppo_sb3.zoo.hyperparams import default_config, eval_kwargs_strings, merge_kwargs

DEFAULT_DEPLOYMENT_EPISODES = 5
#: the line of legend under the safety summary at the end of training (``sppo-train -h`` says more)
SAFETY_LEGEND = (
    "legend: violations = env steps with a positive cost (unsafe steps); safety rate = % of training episodes without "
    "a violation; interventions = steps where the shield replaced the action; eval/ = the final policy deployed with "
    "the shield, eval_unshielded/ = without it (safe_episode_rate: % of its episodes without a violation); "
    "sppo-train -h explains more, and safety_summary.json in the run folder keeps these figures"
)


def _given_config(args: tuple[Any, ...], kwargs: dict[str, Any]) -> str | None:
    """The ``config`` (``-conf``) that ``ExperimentManager(*args, **kwargs)`` was given (``None``: none).

    :param args: the constructor's positional arguments.
    :param kwargs: its keyword arguments.
    """
    bound = inspect.signature(ExperimentManager.__init__).bind_partial(None, *args, **kwargs)
    return bound.arguments.get("config")


class SafeExperimentManager(ExperimentManager):
    """rl-zoo3's ``ExperimentManager`` with the safety outputs and violation budget described in :mod:`sppo_sb3.zoo`.

    :cvar violation_budget: cumulative training violations allowed per trial (``None``: ``SPPO_VIOLATION_BUDGET``).
    :cvar violation_penalty: objective penalty per violation above the budget (``None``:
        ``SPPO_VIOLATION_PENALTY``; unset: over-budget trials are pruned).
    :cvar deployment_episodes: episodes of each deployment evaluated after training (0: none).
    """

    violation_budget: ClassVar[float | None] = None
    violation_penalty: ClassVar[float | None] = None
    deployment_episodes: ClassVar[int] = DEFAULT_DEPLOYMENT_EPISODES

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if _given_config(args, kwargs) is None:  # no -conf: the package's own file (rl-zoo3 has none for its algorithms)
            packaged = default_config(self.algo, self.env_name.gym_id)
            if packaged is not None:
                self.config = str(packaged)
        self.budget, self.penalty = resolve_violation_budget(self.violation_budget, self.violation_penalty)
        self.safety_summary: dict[str, float] | None = None

    # ---- hyperparameters
    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]) -> Any:
        return super()._preprocess_hyperparams(eval_kwargs_strings(hyperparams))

    def _yml_entry(self) -> dict[str, Any]:
        with open(self.config) as file:
            entries = yaml.safe_load(file)
        gym_id = self.env_name.gym_id
        return dict(entries.get(gym_id, entries.get("default", {})))

    def load_trial(self, storage: str, study_name: str, trial_id: int | None = None, convert: bool = True) -> Any:
        params = super().load_trial(storage, study_name, trial_id, convert)
        if not convert or not str(self.config).endswith((".yml", ".yaml")):
            return params
        base = self._yml_entry()
        return {key: value for key, value in merge_kwargs(base, params).items() if key in params}

    def hyperparameters_optimization(self) -> None:
        opt = zoo_opt
        sampler = opt.HYPERPARAMS_SAMPLER[self.algo]
        base = dict(self._hyperparams)

        def merged_sampler(trial: optuna.Trial, *args: Any) -> dict[str, Any]:
            sampled = sampler(trial, *args)
            return {key: value for key, value in merge_kwargs(base, sampled).items() if key in sampled}

        # patch (for this search only): rl-zoo3's sampler of the algorithm, so that trials keep the yml's unsearched *_kwargs
        opt.HYPERPARAMS_SAMPLER[self.algo] = merged_sampler  # type: ignore[assignment]
        try:
            super().hyperparameters_optimization()
        finally:
            opt.HYPERPARAMS_SAMPLER[self.algo] = sampler

    # ---- optimisation objective
    def objective(self, trial: optuna.Trial) -> float:
        if self.budget is not None:
            trial.set_user_attr("violation_budget", self.budget)
            trial.set_user_attr("violation_budget_mode", "prune" if self.penalty is None else "penalty")
        value = float(super().objective(trial))
        return penalised_objective(value, trial.user_attrs.get("cumulative_violations"), self.budget, self.penalty)

    # ---- training
    def learn(self, model: BaseAlgorithm) -> None:
        super().learn(model)
        self.report_safety(model)

    def report_safety(self, model: BaseAlgorithm) -> None:
        """Print the model's safety summary and write it to ``safety_summary.json`` in the run folder.

        The summary holds the paper's training-safety metrics (Section V-B-2: cumulative constraint violations,
        safety rate) with the episodes' return and the shield's interventions, and the final policy's deployments with
        and without the shield, then a line of legend (:data:`SAFETY_LEGEND`). A model that keeps no safety metrics
        (rl-zoo3's own algorithms, whose training costs are in ``monitor.csv``) gets the deployments only.
        ``docs/guide/cli.md`` describes every field of the file.

        :param model: the trained model.
        """
        metrics = getattr(model, "safety_metrics", None)
        print(f"========== Safety summary: {self.algo} on {self.env_name.gym_id} ==========")
        summary: dict[str, Any] = {}
        if metrics is None:
            print(f"{type(model).__name__} keeps no safety metrics (see the episode_cost columns of monitor.csv)")
        else:
            self.safety_summary = metrics.summary()
            summary.update(self.safety_summary)
            print(metrics.format_summary())
        deployment = self.evaluate_deployments(model)
        if deployment:
            summary["deployment"] = deployment
        for callback in self.callbacks:
            if isinstance(callback, CostEvalCallback) and callback.evaluations_timesteps:
                print(
                    f"last evaluation: mean return={callback.last_mean_reward:.2f}  "
                    f"mean cost={callback.last_mean_cost:.2f}  mean violations={callback.last_mean_violations:.2f}"
                )
                summary = {**summary, "eval_mean_reward": callback.last_mean_reward}
                summary["eval_mean_cost"] = callback.last_mean_cost
        self.save_costly_episodes(model)
        print(SAFETY_LEGEND)
        Path(self.save_path).mkdir(parents=True, exist_ok=True)
        with open(os.path.join(self.save_path, "safety_summary.json"), "w") as file:
            json.dump({"num_timesteps": int(model.num_timesteps), **summary}, file, indent=2)

    def save_costly_episodes(self, model: BaseAlgorithm) -> None:
        """Write the replayable record of every training episode that paid cost behind a ``ShieldWrapper``
        (:mod:`sppo_sb3.shield.records`) to ``costly_episodes/`` in the run folder, and say how to replay them."""
        env = model.get_env()
        if env is None or not env.has_attr("costly_episodes"):
            return
        folder = Path(self.save_path) / "costly_episodes"
        saved = [
            record.save(folder / f"env_{index}_episode_{record.episode}.json")
            for index, records in enumerate(env.get_attr("costly_episodes"))
            for record in records
        ]
        if saved:
            print(f"{len(saved)} costly episodes recorded for replay in {folder}: python scripts/replay_costly.py {saved[0]}")

    def evaluate_deployments(self, model: BaseAlgorithm) -> dict[str, dict[str, float]]:
        """Deployment safety (Corollary 1): the learned policy with and without the shield, printed side by side.

        Runs :attr:`deployment_episodes` deterministic episodes of each deployment on a fresh env of the task (none when
        0). A model trained under ``VecNormalize`` sees the observations normalised with its final statistics. Also
        logged (TensorBoard) under ``deployment_eval/`` and ``deployment_eval_unshielded/`` at the final step.

        :param model: the trained model.
        :return: the metrics of each deployment, by name (``eval``, ``eval_unshielded``); empty when none is run.
        """
        episodes = self.deployment_episodes
        if episodes <= 0:
            return {}
        gym_id, env_kwargs = self.env_name.gym_id, dict(self.env_kwargs)
        vec_normalize = model.get_vec_normalize_env()

        def make_env() -> gym.Env:
            return gym.make(gym_id, **env_kwargs)

        results = {
            name: evaluate_deployment(model, make_env, episodes, shielded, seed=self.seed, vec_normalize=vec_normalize)
            for name, shielded in ((DEPLOYMENT_SHIELDED, True), (DEPLOYMENT_UNSHIELDED, False))
        }
        print(f"deployment, {episodes} deterministic episodes each (the learned policy with / without the shield):")
        for name, metrics in results.items():
            print(f"  {name + '/':17s}" + "  ".join(f"{key}={value:.2f}" for key, value in metrics.items()))
            for key, value in metrics.items():  # TensorBoard: deployment_eval/ and deployment_eval_unshielded/
                model.logger.record(f"deployment_{name}/{key}", value)
        model.logger.dump(model.num_timesteps)
        return results
