"""Where a trained policy's episodes end, deployed with and without its shield: does an intervention precede a fall?

On tasks that end an episode when the robot falls (Hopper, Walker2d, Ant), a low return can come from the policy or
from the shield's backup, which minimises the constraint's cost and nothing else. This script deploys a saved model
(its own shield off, with :func:`~sppo_sb3.shield.evaluation.run_episode`) for ``--episodes`` deterministic
episodes, once as it is and once through :class:`~sppo_sb3.shield.ShieldWrapper` with the model's rule, and prints per
deployment the mean return, episode length, the episodes that ended by termination (a fall), the cost and the
interventions per episode; for the shielded one, how many steps before each fall the last intervention was. The
policy sees the env's raw observations, as SPPO's and SACLag's do (not a model trained under ``VecNormalize``).

    python scripts/deployment_falls.py results/velocity/sppo_sb3_SafetyHopperVelocity-v1/sppo/seed_1/zoo/sppo/\\
sppo_sb3-SafetyHopperVelocity-v1_1/sppo_sb3-SafetyHopperVelocity-v1.zip --env sppo_sb3/SafetyHopperVelocity-v1
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.algorithms import ALGORITHMS
from sppo_sb3.shield.evaluation import deployment_rule, run_episode
from sppo_sb3.shield.wrapper import ShieldWrapper

#: a fall "follows" an intervention when it comes within this many steps of it
NEAR_STEPS = 10


@dataclass
class Deployment:
    """Per episode: return, length, whether it ended by termination, violating steps, interventions, and the steps
    from the last intervention to the end of each terminated episode that had one."""

    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    falls: list[bool] = field(default_factory=list)
    costs: list[int] = field(default_factory=list)
    interventions: list[int] = field(default_factory=list)
    gaps: list[int] = field(default_factory=list)

    def report(self, name: str) -> str:
        """One line per deployment, and the falls' distance from the last intervention where there were any."""
        line = (
            f"{name}: return {np.mean(self.returns):.1f}, length {np.mean(self.lengths):.1f}, "
            f"fell in {sum(self.falls)} of {len(self.falls)} episodes, cost {np.mean(self.costs):.1f} and "
            f"{np.mean(self.interventions):.1f} interventions per episode"
        )
        if self.gaps:
            gaps = np.asarray(self.gaps)
            line += (
                f"\n  {len(gaps)} falls came after an intervention: {np.sum(gaps <= NEAR_STEPS)} within {NEAR_STEPS} "
                f"steps of it (median {np.median(gaps):.0f} steps)"
            )
        return line


def deploy(model: BaseAlgorithm, env: gym.Env, episodes: int, seed: int) -> Deployment:
    """Run ``model``'s deterministic actions in ``env`` for ``episodes`` episodes (seeds ``seed``, ``seed + 1``, ...)."""
    out = Deployment()
    for episode in (run_episode(model, env, seed + index) for index in range(episodes)):
        out.returns.append(episode.reward)
        out.lengths.append(episode.length)
        out.falls.append(episode.terminated)
        out.costs.append(episode.violations)
        out.interventions.append(len(episode.intervention_steps))
        if episode.terminated and episode.intervention_steps:
            out.gaps.append(episode.length - episode.intervention_steps[-1])
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="a saved model (.zip)")
    parser.add_argument("--env", required=True, help="the task's gymnasium id")
    parser.add_argument("--algo", default="sppo", choices=sorted(ALGORITHMS), help="the model's algorithm (default: sppo)")
    parser.add_argument("--episodes", type=int, default=20, help="episodes per deployment (default: 20)")
    parser.add_argument("--seed", type=int, default=1000, help="seed of the first episode (default: 1000)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    model = ALGORITHMS[args.algo].load_class().load(args.model, device="cpu")
    rule = deployment_rule(model)
    if rule is None:
        parser.error(f"{args.model} has no shield to compare with: it was trained without a shielding rule")
    print(deploy(model, gym.make(args.env), args.episodes, args.seed).report("without the shield"))
    print(deploy(model, ShieldWrapper(gym.make(args.env), rule), args.episodes, args.seed).report("with the shield"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
