"""The velocity shield on a recorded fall: violations and interventions per rule horizon, with and without the episode end.

Replays the proposals of the falling episode of Walker2d seed 0 (the velocity grid's first run of SPPO's new settings,
which paid 20 violating steps under the rule of the time: 15 steps, no episode end) through
:class:`~sppo_sb3.shield.MujocoShieldingRule` from the recorded state (``tests/shield/data/walker2d_fall.npz``), with
each horizon, once with the env's episode end (:class:`~sppo_sb3.shield.mujoco.model.EpisodeEnd`) and once without.

    python scripts/replay_fall.py
    python scripts/replay_fall.py --horizons 15 30 --fixture tests/shield/data/walker2d_fall.npz
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import gymnasium as gym
import numpy as np

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.shield import MujocoShieldingRule
from sppo_sb3.shield.analysis.replay import replay_proposals
from sppo_sb3.shield.registry import default_shielding_rule

ENV_ID = "sppo_sb3/SafetyWalker2dVelocity-v1"
FIXTURE = Path(__file__).resolve().parents[1] / "tests" / "shield" / "data" / "walker2d_fall.npz"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizons", type=int, nargs="+", default=[15, 25, 30, 45], help="rule horizons (env steps)")
    parser.add_argument("--fixture", type=Path, default=FIXTURE, help="the recorded fall (qpos, qvel, proposals)")
    args = parser.parse_args()
    recorded = np.load(args.fixture)
    registered = default_shielding_rule(ENV_ID, gym.make(ENV_ID))
    assert isinstance(registered, MujocoShieldingRule)  # the velocity tasks' registered rule
    print(f"registered rule: horizon {registered.horizon}; {len(recorded['proposals'])} recorded proposals\n")
    print("| horizon | episode end | violations | interventions | steps until the fall |")
    print("|---|---|---|---|---|")
    for horizon in args.horizons:
        for end in (True, False):
            layout = registered.layout if end else dataclasses.replace(registered.layout, episode_end=None)
            rule = MujocoShieldingRule(
                layout, registered.constraint, horizon=horizon, alpha=registered.alpha, eta=registered.eta
            )
            replay = replay_proposals(rule, ENV_ID, recorded["qpos"], recorded["qvel"], recorded["proposals"])
            fell = replay.steps if replay.terminated else f">{replay.steps}"
            print(f"| {horizon} | {'yes' if end else 'no'} | {replay.violations} | {replay.interventions} | {fell} |")


if __name__ == "__main__":
    main()
