"""How well a learned rule knows where the danger is on the Point Robot: ``scripts/learned_shield.py``.

Two learned rules with the Point rule's backup, scored against the model rule (:mod:`sppo_sb3.shield.analysis.quality`) on a
held-out walk whose random actions are each held for 20 steps (so that the robot meets the wall), beside ``Q̄ ≡ 0``
and a predictor from the distance alone:

- a :class:`~sppo_sb3.shield.LearnedDynamicsRule` (the constraint known, the dynamics learned) and a
  :class:`~sppo_sb3.shield.LearnedCostCriticRule` (``Q̄`` fitted on the costs), both on what a warm-up holds:
  ``--warmup-steps`` uniform steps, a quarter of them the backup's;
- the critic again on a walk that meets the wall often (``--steps`` steps of actions held for ``--hold`` steps), and
  its decisions at several ``η``;
- with ``--latent``, a :class:`~sppo_sb3.shield.LatentModelRule` fitted on the same walk, on the TOLD of a saved SPPO
  model (``--latent PATH``) or an untrained one of the Point settings' size (``--latent untrained``).

Under each table, the mean ``Ā`` of every rule on the pairs the model rule shields, beside the model rule's own: a
shield compares ``a`` with ``ζ(s)`` in one state, so a rule that ranks states well but cannot separate the two
decides badly.

With ``--training-steps N`` they are also scored on the pairs of a real training run: the states a shielded SPPO
(``hyperparams/sppo.yml``'s Point settings, the model rule) visited in ``N`` env steps and the actions it proposed
there, from a seed of its own. Each table has ``max |error|``, an estimate of Proposition 2.3's ``δ``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch as th

from sppo_lab.configs import REPO_HYPERPARAMS_DIR
from sppo_lab.recording import RecordingRule
from sppo_sb3.common.keys import COST_KEY, SHAPED_COST_KEY
from sppo_sb3.envs.point_circle import PointParams, point_distance_to_unsafe, point_is_unsafe
from sppo_sb3.shield import (
    LatentModelRule,
    LearnedCostCriticRule,
    LearnedDynamicsRule,
    PointCircleShieldingRule,
    ShieldingRule,
)
from sppo_sb3.shield.analysis import quality
from sppo_sb3.shield.learned.base import CostTransitions
from sppo_sb3.shield.learned.critic import definition2_step_costs
from sppo_sb3.shield.registry import latent_point_rule
from sppo_sb3.sppo import SPPO
from sppo_sb3.zoo import constructor_kwargs

TASK = "SafePointCircle-v0"
#: decision thresholds on Definition 2's scale at which the learned rule's decisions are compared
ETAS: tuple[float, ...] = (0.0, 0.003, 0.01, 0.03, 0.1)


@dataclass
class Walk:
    """A walk's transitions, as :meth:`LearnedCostCriticRule.update` takes them, and its violations."""

    obs: np.ndarray
    actions: np.ndarray
    step_costs: np.ndarray
    next_obs: np.ndarray
    dones: np.ndarray
    violations: int
    shaped_costs: np.ndarray
    costs: np.ndarray

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """The walk's observations and actions."""
        return self.obs, self.actions

    def cost_transitions(self) -> CostTransitions:
        """The walk as a replay buffer's transitions, as :meth:`RefinableRule.refine` takes them."""
        return CostTransitions(self.obs, self.actions, self.shaped_costs, self.costs, self.next_obs, self.dones)


def held_action_walk(steps: int, seed: int, hold: int, backup_fraction: float, rule: PointCircleShieldingRule) -> Walk:
    """A walk on the Point Robot: a uniform action held for ``hold`` steps, or on a ``backup_fraction`` of the steps ζ.

    :param steps: env steps.
    :param seed: seed of the env and the actions.
    :param hold: steps each uniform action is held.
    :param backup_fraction: share of the steps that execute the rule's backup instead.
    :param rule: the rule whose backup the walk uses and whose ``γ`` the step costs take.
    """
    env, rng = gym.make(TASK), np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    rows: dict[str, list] = {key: [] for key in ("obs", "actions", "shaped", "violations", "next_obs", "dones")}
    held = rng.uniform(-1.0, 1.0, 2)
    for t in range(steps):
        if t % hold == 0:
            held = rng.uniform(-1.0, 1.0, 2)
        backup = rng.random() < backup_fraction
        action = rule.backup_action(obs[None].astype(np.float64))[0] if backup else held
        next_obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
        for key, value in zip(rows, (obs, action, info[SHAPED_COST_KEY], info[COST_KEY], next_obs, terminated)):
            rows[key].append(value)
        obs = next_obs if not (terminated or truncated) else env.reset()[0]
    violations, shaped = np.array(rows["violations"]) > 0, np.array(rows["shaped"], dtype=np.float64)
    return Walk(
        obs=np.array(rows["obs"], dtype=np.float64),
        actions=np.array(rows["actions"], dtype=np.float64),
        step_costs=definition2_step_costs(shaped, violations, rule.gamma),
        next_obs=np.array(rows["next_obs"], dtype=np.float64),
        dones=np.array(rows["dones"]) | violations,
        violations=int(violations.sum()),
        shaped_costs=shaped,
        costs=violations.astype(np.float64),
    )


def training_run_pairs(steps: int, seed: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` pairs ``(s, a)`` drawn from a shielded SPPO training run on the Point Robot: states it visited and the
    actions it proposed there (``hyperparams/sppo.yml``'s settings, the model rule; one thread, as the benchmark).

    :param steps: env steps of the run.
    :param seed: seed of the run and of the draw.
    :param count: pairs drawn (without replacement).
    """
    recording = RecordingRule(PointCircleShieldingRule())
    kwargs = constructor_kwargs(REPO_HYPERPARAMS_DIR / "sppo.yml", TASK)
    kwargs.pop("shield")
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        SPPO(kwargs.pop("policy"), TASK, shield=recording, seed=seed, **kwargs).learn(steps)
    finally:
        th.set_num_threads(threads)
    obs, actions = recording.pairs()
    pick = np.sort(np.random.default_rng(seed).choice(len(obs), size=min(count, len(obs)), replace=False))
    return obs[pick], actions[pick]


def fit_critic(walk: Walk, rule: PointCircleShieldingRule, seed: int, gradient_steps: int) -> LearnedCostCriticRule:
    """A learned rule with ``rule``'s backup, fitted on ``walk`` for ``gradient_steps`` minibatches of 256."""
    space = gym.make(TASK)
    critic = LearnedCostCriticRule(space.observation_space, space.action_space, rule.backup_action, seed=seed)
    for _ in range(max(gradient_steps // 100, 1)):
        critic.update(walk.obs, walk.actions, walk.step_costs, walk.next_obs, walk.dones, 100, 256)
    return critic


def fit_dynamics(walk: Walk, rule: PointCircleShieldingRule, seed: int, gradient_steps: int) -> LearnedDynamicsRule:
    """A learned-model rule with ``rule``'s backup, constraint and band, fitted on ``walk``'s transitions."""
    space, params = gym.make(TASK), PointParams()
    learned = LearnedDynamicsRule(
        space.observation_space,
        space.action_space,
        rule.backup_action,
        lambda obs: point_is_unsafe(obs, params),
        lambda obs: point_distance_to_unsafe(obs, params),
        alpha=rule.alpha,
        horizon=rule.horizon + 10,
        seed=seed,
    )
    for _ in range(max(gradient_steps // 100, 1)):
        learned.update(walk.obs, walk.actions, walk.next_obs, 100, 256)
    return learned


def score_table(
    learned: dict[str, ShieldingRule], reference: PointCircleShieldingRule, obs: np.ndarray, actions: np.ndarray, fitting: Walk
) -> dict[str, quality.ShieldScores]:
    """The learned rules', ``Q̄ ≡ 0``'s and the distance predictor's scores on the pairs ``(obs, actions)``."""
    reference_q, shielded = reference.definition2_value(obs, actions), quality.shielded_pairs(reference, obs, actions)
    violates = quality.violation_labels(reference.band_free(), obs, actions)
    params = PointParams()
    scores = {name: quality.rule_scores(rule, obs, actions, reference_q, shielded, violates) for name, rule in learned.items()}
    return {
        **scores,
        "Q̄ ≡ 0": quality.zero_scores(reference_q, shielded, violates),
        "distance alone": quality.distance_scores(
            point_distance_to_unsafe(obs, params),
            reference_q,
            shielded,
            violates,
            point_distance_to_unsafe(fitting.obs, params),
            reference.definition2_value(fitting.obs, fitting.actions),
        ),
    }


def eta_rows(critic: LearnedCostCriticRule, reference: PointCircleShieldingRule, evaluation: Walk) -> list[str]:
    """Markdown rows: the learned rule's decisions against the reference's at each of :data:`ETAS`."""
    shielded = quality.shielded_pairs(reference, evaluation.obs, evaluation.actions)
    rows, eta = [], critic.eta
    for critic.eta in ETAS:
        mine = quality.shielded_pairs(critic, evaluation.obs, evaluation.actions)
        rows.append(
            f"| {critic.eta} | {(mine == shielded).mean():.3f} | {mine[shielded].mean():.3f} | {mine[~shielded].mean():.3f} |"
        )
    critic.eta = eta
    return rows


def fit_latent(walk: Walk, source: str, seed: int, gradient_steps: int) -> LatentModelRule:
    """The Point rule's :class:`LatentModelRule`, bound to the TOLD of the SPPO model saved at ``source`` (or an
    untrained one of ``hyperparams/sppo.yml``'s Point size for ``"untrained"``), its heads fitted on ``walk``."""
    if source == "untrained":
        kwargs = constructor_kwargs(REPO_HYPERPARAMS_DIR / "sppo.yml", TASK)
        model = SPPO(kwargs["policy"], TASK, policy_kwargs=kwargs["policy_kwargs"], compile=False, seed=seed)
    else:
        model = SPPO.load(source, device="cpu")
    rule = latent_point_rule(seed=seed)
    rule.bind(model.policy.model)
    transitions = walk.cost_transitions()
    for _ in range(gradient_steps):
        rule.refine(transitions, 256)
    return rule


def separation_rows(
    learned: dict[str, ShieldingRule], reference: PointCircleShieldingRule, obs: np.ndarray, actions: np.ndarray
) -> list[str]:
    """Markdown rows: each rule's mean ``Ā`` (Definition 2's scale) on the pairs the model rule shields."""
    shielded = quality.shielded_pairs(reference, obs, actions)
    obs, actions = obs[shielded], actions[shielded]
    rows = []
    for name, rule in {"model rule": reference, **learned}.items():
        advantage = rule.definition2_value(obs, actions) - rule.definition2_value(obs, rule.backup_action(obs))
        share = quality.shielded_pairs(rule, obs, actions).mean()
        rows.append(f"| {name} | {len(obs)} | {advantage.mean():.3f} | {share:.3f} |")
    return rows


def print_separation(rows: list[str]) -> None:
    """The rows of :func:`separation_rows` under their header."""
    print("Mean Ā on the pairs the model rule shields:\n")
    print("| rule | pairs | mean Ā (Definition 2) | share shielded |\n|---|---|---|---|")
    print("\n".join(rows) + "\n")


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options (see ``--help``)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--warmup-steps", type=int, default=3000, help="env steps of the warm-up (default: 3000)")
    parser.add_argument("--steps", type=int, default=10_000, help="env steps of the held-action walk (default: 10000)")
    parser.add_argument("--hold", type=int, default=20, help="steps each random action is held (default: 20)")
    parser.add_argument("--backup-fraction", type=float, default=0.25, help="share of backup steps (default: 0.25)")
    parser.add_argument("--gradient-steps", type=int, default=2000, help="minibatches of 256 (default: 2000)")
    parser.add_argument("--model-steps", type=int, default=1000, help="the model's minibatches of 256 (default: 1000)")
    parser.add_argument("--seeds", type=int, default=2, help="seeds 0..N-1 (default: 2)")
    parser.add_argument(
        "--latent", default="", help="also fit a LatentModelRule on the TOLD of this saved SPPO model, or 'untrained'"
    )
    parser.add_argument(
        "--training-steps", type=int, default=0, help="also score on a shielded SPPO run of this many steps (default: 0, none)"
    )
    return parser.parse_args(argv)


def print_scores(title: str, table: dict[str, quality.ShieldScores]) -> None:
    """A markdown table of :func:`score_table`'s scores, under ``title``."""
    print(f"Scored on {title}:\n")
    print("| predictor | MAE | max abs error (δ) | agreement | recall | false shields | AUC |\n|---|---|---|---|---|---|---|")
    for name, scores in table.items():
        print(f"| {name} | " + " | ".join(f"{value:.3f}" for value in scores.as_dict().values()) + " |")
    print()


def main(argv: Sequence[str] | None = None) -> int:
    """Print, per seed, the scores table and the decisions at each ``η``."""
    args = parse_args(argv)
    reference = PointCircleShieldingRule()
    for seed in range(args.seeds):
        warmup = held_action_walk(args.warmup_steps, seed, 1, args.backup_fraction, reference)
        walk = held_action_walk(args.steps, seed, args.hold, args.backup_fraction, reference)
        evaluation = held_action_walk(3000, 1000 + seed, 20, 0.0, reference)
        critic = fit_critic(walk, reference, seed, args.gradient_steps)
        learned: dict[str, ShieldingRule] = {
            "learned model, warm-up data": fit_dynamics(warmup, reference, seed, args.model_steps),
            "critic, warm-up data": fit_critic(warmup, reference, seed, args.gradient_steps),
            "critic, held-action walk": critic,
        }
        if args.latent:
            learned["latent model, held-action walk"] = fit_latent(walk, args.latent, seed, args.gradient_steps)
        print(
            f"\n### Seed {seed}: warm-up {args.warmup_steps} steps ({warmup.violations} violations), held-action walk "
            f"{args.steps} steps ({walk.violations} violations)\n"
        )
        print_scores("3000 held-out pairs of a held-action walk", score_table(learned, reference, *evaluation.pairs(), walk))
        print_separation(separation_rows(learned, reference, *evaluation.pairs()))
        if args.training_steps:
            obs, actions = training_run_pairs(args.training_steps, 2000 + seed, 3000)
            title = f"{len(obs)} pairs of a shielded SPPO run of {args.training_steps} steps (seed {2000 + seed})"
            print_scores(title, score_table(learned, reference, obs, actions, walk))
            print_separation(separation_rows(learned, reference, obs, actions))
        print("\nThe critic of the held-action walk at other η:\n")
        print("| η (Definition 2) | agreement | recall | false shields |\n|---|---|---|---|")
        print("\n".join(eta_rows(critic, reference, evaluation)))
    return 0
