"""SAC behind ``ShieldWrapper`` on SafePointCircle-v0: ``on_intervention="continue"`` against ``"terminate"``.

For each mode and seed: SAC trains for ``--steps`` env steps behind the shield; reported are the training
violations and interventions, then the return, violations and interventions of the deterministic policy over
``--eval-episodes`` full episodes in the shielded env (``"continue"``: the real task, whatever the training mode).

    python scripts/bench_wrapper_modes.py --steps 5000 --seeds 0 1
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

import sppo_sb3  # noqa: F401  (registers the task)
from sppo_sb3.common.keys import COST_KEY
from sppo_sb3.shield import PointCircleShieldingRule, ShieldWrapper
from sppo_sb3.shield.intervention import OnIntervention

ENV_ID = "SafePointCircle-v0"


class Counts(BaseCallback):
    """Violations and interventions of the training steps."""

    def __init__(self) -> None:
        super().__init__()
        self.violations = 0
        self.interventions = 0

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            self.violations += int(info.get(COST_KEY, 0.0) > 0)
            self.interventions += int(info.get("shield_intervened", False))
        return True


def evaluate(model: SAC, episodes: int, seed: int) -> dict[str, float]:
    """Deterministic episodes in the shielded env: mean return, total violations and interventions."""
    env = ShieldWrapper(gym.make(ENV_ID), PointCircleShieldingRule())
    returns, violations, interventions = [], 0, 0
    for episode in range(episodes):
        obs, _ = env.reset(seed=10_000 + 100 * seed + episode)
        done, total = False, 0.0
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = env.step(action)
            total += float(reward)
            violations += int(info[COST_KEY] > 0)
            interventions += int(info["shield_intervened"])
            done = terminated or truncated
        returns.append(total)
    return {"eval_return": float(np.mean(returns)), "eval_violations": violations, "eval_interventions": interventions}


def run(mode: OnIntervention, seed: int, steps: int, eval_episodes: int) -> dict[str, float | int | str]:
    """Train SAC behind the shield in ``mode`` and evaluate it."""
    penalty = 1.0 if mode == "terminate" else 0.0  # eq. 7's R̃ = -1 for the absorbing step; the shielded env otherwise
    env = ShieldWrapper(gym.make(ENV_ID), PointCircleShieldingRule(), on_intervention=mode, penalty=penalty)
    model = SAC("MlpPolicy", env, learning_starts=1000, seed=seed, verbose=0)
    counts = Counts()
    model.learn(steps, callback=counts)
    return {
        "mode": mode,
        "seed": seed,
        "train_violations": counts.violations,
        "train_interventions": counts.interventions,
        **evaluate(model, eval_episodes, seed),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--eval-episodes", type=int, default=2)
    args = parser.parse_args()
    for mode in ("continue", "terminate"):
        for seed in args.seeds:
            print(json.dumps(run(mode, seed, args.steps, args.eval_episodes)), flush=True)


if __name__ == "__main__":
    main()
