"""``sppo-train`` / ``python -m sppo_sb3.train``: rl-zoo3's train command with the package's algorithms.

Every rl-zoo3 flag works unchanged (``--algo sppo --env SafePointCircle-v0 -conf hyperparams/sppo.yml``,
``-optimize``, ``--storage``, ...); without ``-conf``, the package's own hyperparameters are read (shipped in the wheel,
:func:`sppo_sb3.zoo.hyperparams.default_config`). On top of the zoo (see :mod:`sppo_sb3.zoo`): ``monitor.csv`` has the
columns ``episode_cost``, ``episode_violations`` and ``episode_interventions``, evaluations log ``eval/mean_cost``,
the safety summary is printed at the end with a line of legend (:data:`EXTRA_HELP` explains its terms,
``docs/guide/cli.md`` every field of ``safety_summary.json``), and two extra flags set the violation budget of
hyperparameter search:

``--violation-budget B``  prune trials whose cumulative training violations exceed ``B`` (env: SPPO_VIOLATION_BUDGET)
``--violation-penalty P``  instead of pruning, objective = return - P * max(0, violations - B) (env: SPPO_VIOLATION_PENALTY)

and one sets the deployment check at the end of training:

``--deployment-episodes N``  evaluate the learned policy for N deterministic episodes with and without the shield
(default 5; 0: skip), printed side by side and saved under ``deployment`` in ``safety_summary.json``
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

EXTRA_HELP = """
sppo_sb3 options (besides rl-zoo3's):
  --violation-budget B   hyperparameter search: prune a trial as soon as its cumulative training violations exceed B
                         (default: $SPPO_VIOLATION_BUDGET, else no budget)
  --violation-penalty P  hyperparameter search: train over-budget trials to the end and return
                         mean eval return - P * max(0, violations - B) instead (default: $SPPO_VIOLATION_PENALTY)
  --deployment-episodes N
                         after training, evaluate the learned policy for N deterministic episodes with and without
                         the shield (deployment safety; default 5, 0: skip)
  -conf FILE             as in rl-zoo3; without it, the package's own hyperparams/ALGO.yml (velocity/ALGO.yml or
                         dmc/ALGO.yml for those task families), shipped with the package

safety outputs (the summary printed at the end of training, also saved to <run folder>/safety_summary.json; every
field of that file is described in the package's docs, docs/guide/cli.md):
  violations             env steps whose info["cost"] is positive, i.e. steps in the task's unsafe set;
                         "cumulative violations": over all of training; elsewhere: per episode
  safety rate            % of the finished training episodes without a single violation (100 before one ends)
  interventions          env steps at which the shield replaced the policy's action with its backup action
                         ("shield interventions": over all of training; 0 where nothing shields the algorithm)
  cost                   sum of info["cost"] over an episode (the package's tasks give 1 per unsafe step, so
                         cost = violations there); "eval/mean_cost": the periodic evaluations of --eval-freq
  eval/                  the final policy deployed WITH its shield for --deployment-episodes deterministic episodes:
                         mean_reward (return), mean_violations and mean_interventions (per episode),
                         safe_episode_rate (% of the episodes without a violation)
  eval_unshielded/       the same policy deployed WITHOUT the shield (the same four figures): how safe the learned
                         policy is on its own, as Corollary 1 of the paper bounds it
"""


def _split_args(argv: Sequence[str]) -> tuple[argparse.Namespace, list[str]]:
    """Take the package's own flags out of ``argv``; the rest goes to rl-zoo3.

    :param argv: the command-line arguments (without the program name).
    """
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--violation-budget", type=float, default=None)
    parser.add_argument("--violation-penalty", type=float, default=None)
    parser.add_argument("--deployment-episodes", type=int, default=None)
    return parser.parse_known_args(list(argv))


def main(argv: Sequence[str] | None = None) -> None:
    """Run rl-zoo3's train command with the package's algorithms registered and its safety outputs.

    :param argv: command-line arguments (default: ``sys.argv[1:]``).
    """
    from rl_zoo3 import train as zoo_train

    from sppo_sb3.zoo import install

    own, rest = _split_args(sys.argv[1:] if argv is None else argv)
    deployment = {} if own.deployment_episodes is None else {"deployment_episodes": own.deployment_episodes}
    install(violation_budget=own.violation_budget, violation_penalty=own.violation_penalty, **deployment)
    if "-h" in rest or "--help" in rest:
        print(EXTRA_HELP)
    saved_argv = sys.argv
    sys.argv = [saved_argv[0] if saved_argv else "sppo-train", *rest]
    try:
        zoo_train.train()
    finally:
        sys.argv = saved_argv


if __name__ == "__main__":
    main()
