"""Trace SPPO behind ``ShieldWrapper(action_repeat=k)``: train a lab probe config and print every shield decision of the
env steps around each costly one, so that a costly step behind the shield can be replayed and read.

Training is deterministic on one thread: the same config, task, seed and steps give the same run on the same package
versions. It builds the model directly (not through rl-zoo3), so its run is not the benchmark's run step for step, but
it is reproducible on its own::

    python scripts/trace_held_shield.py lab/hyperparams/navigation_probe/repeat5/sppo.yml \\
        --task sppo_sb3/SafetyPointGoal1-v0 --seed 101 --steps 1875 --before 30
"""

from __future__ import annotations

import argparse
from collections import deque
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from stable_baselines3.common.callbacks import BaseCallback

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3 import SPPO
from sppo_sb3.common.keys import COST_KEY, EXECUTED_ACTION_KEY
from sppo_sb3.shield import ShieldWrapper
from sppo_sb3.zoo import constructor_kwargs


class TracedShieldWrapper(ShieldWrapper):
    """``ShieldWrapper`` that keeps its last ``before`` env-step decisions and prints them, and every decision after,
    from the first costly env step on."""

    def __init__(self, env: gym.Env, action_repeat: int, before: int) -> None:
        super().__init__(env, "auto", action_repeat=action_repeat)
        self.recent: deque[str] = deque(maxlen=before)
        self.env_step, self.printing = 0, 0

    def _shielded_env_step(self, proposed: np.ndarray) -> Any:
        out = super()._shielded_env_step(proposed)
        _, _, _, _, info, decision = out
        self.env_step += 1
        line = (
            f"env step {self.env_step:6d}  proposed {np.round(proposed, 2)}  executed {np.round(info[EXECUTED_ACTION_KEY], 2)}"
            f"  intervened {bool(decision.intervened[0])!s:5}  Ā {float(decision.advantage[0]):9.3g}  cost {info[COST_KEY]}"
        )
        if info[COST_KEY] > 0:
            print(*self.recent, sep="\n")
            self.recent.clear()
            self.printing = self.recent.maxlen or 0
        if self.printing:
            print(line, flush=True)
            self.printing -= 1
        else:
            self.recent.append(line)
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", type=Path, help="a lab config whose entry holds ShieldWrapper(action_repeat=k)")
    parser.add_argument("--task", default="sppo_sb3/SafetyPointGoal1-v0")
    parser.add_argument("--seed", type=int, default=101)
    parser.add_argument("--steps", type=int, default=2000, help="agent steps to train")
    parser.add_argument("--before", type=int, default=30, help="env steps printed before (and after) a costly one")
    args = parser.parse_args()
    th.set_num_threads(1)
    kwargs = constructor_kwargs(args.config, args.task)
    kwargs.pop("policy")
    (wrapper,) = yaml.safe_load(args.config.read_text())[args.task]["env_wrapper"]  # rl-zoo3's key, not SPPO's
    repeat = int(next(iter(wrapper.values())).get("action_repeat", 1))
    env = TracedShieldWrapper(gym.make(args.task), repeat, args.before)
    model = SPPO("TOLDPolicy", env, seed=args.seed, **kwargs)

    class AgentSteps(BaseCallback):
        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if info.get(COST_KEY, 0.0) > 0:
                    print(f"agent step {self.num_timesteps}: {info.get('costly_steps')} costly env steps", flush=True)
            return True

    model.learn(args.steps, callback=AgentSteps())
    metrics = model.safety_metrics
    print(f"{args.steps} agent steps: {metrics.violations} costly env steps, {metrics.interventions} interventions")


if __name__ == "__main__":
    main()
