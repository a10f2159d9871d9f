"""Does SPPO's value see the fall coming? ``min Q(z, π(z))`` against the real discounted return-to-go, near the end.

On tasks that end an episode when the robot falls (Hopper, Walker2d), a planner whose value does not drop before a
fall plans into it. This script deploys a saved SPPO model as it is deployed (``predict``: MPPI, then its shield,
deterministic) for ``--episodes`` episodes, and at every step records the value TOLD gives the state,
``min Q(h(s), π(h(s)))``, beside the discounted return-to-go that followed, ``G_t = Σ_k γ^(k-t) r_k`` with the
model's ``γ`` (a time-limit truncation bootstraps ``G`` with the last state's value). It prints, for the episodes that
ended in a fall, both means by how many steps before the fall the state was: a ``Q`` far above ``G`` just before a
fall is a value that did not see it coming.

    python scripts/value_diagnostic.py results/velocity_probe/.../sppo_sb3-SafetyHopperVelocity-v1.zip \\
        --env sppo_sb3/SafetyHopperVelocity-v1 --episodes 5
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import gymnasium as gym
import numpy as np
import torch as th

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3 import SPPO

#: the bins of "steps before the fall" the table reports (inclusive lower edge, exclusive upper edge)
BINS = ((1, 11), (11, 26), (26, 51), (51, 101), (101, 1_000_001))


def discounted_return_to_go(rewards: np.ndarray, gamma: float, bootstrap: float) -> np.ndarray:
    """``G_t = r_t + γ G_(t+1)``, with ``G_T = bootstrap`` after the last step."""
    returns = np.empty(len(rewards))
    running = bootstrap
    for t in range(len(rewards) - 1, -1, -1):
        running = rewards[t] + gamma * running
        returns[t] = running
    return returns


@th.no_grad()
def state_value(model: SPPO, obs: np.ndarray) -> float:
    """``min Q(h(s), π(h(s)))`` of one raw observation (TOLD's value of the state under its policy prior)."""
    told = model.policy.model
    z = told.encode(th.as_tensor(obs, dtype=th.float32, device=model.device)[None])
    return float(told.min_q(z, told.policy(z)).squeeze())


def deployed_episode(model: SPPO, env: gym.Env, seed: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """One deterministic, shielded episode: per-step values and rewards, and whether it ended in a fall."""
    obs, _ = env.reset(seed=seed)
    values, rewards, state, start = [], [], None, np.array([True])
    terminated = truncated = False
    while not (terminated or truncated):
        values.append(state_value(model, obs))
        action, state = model.predict(obs, state=state, episode_start=start, deterministic=True)
        obs, reward, terminated, truncated, _ = env.step(action)
        rewards.append(float(reward))
        start = np.array([False])
    if truncated and not terminated:
        values.append(state_value(model, obs))  # the bootstrap of G after the time limit
    return np.asarray(values), np.asarray(rewards), bool(terminated)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="a saved SPPO model (.zip)")
    parser.add_argument("--env", required=True, help="the task's id")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode's reset")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    model = SPPO.load(args.model, device="cpu")
    env = gym.make(args.env)
    by_bin: dict[tuple[int, int], list[tuple[float, float]]] = {b: [] for b in BINS}
    lengths, falls = [], 0
    for episode in range(args.episodes):
        values, rewards, fell = deployed_episode(model, env, args.seed + episode)
        bootstrap = 0.0 if fell else values[-1]
        returns = discounted_return_to_go(rewards, model.gamma, bootstrap)
        lengths.append(len(rewards))
        if not fell:
            continue
        falls += 1
        before = len(rewards) - np.arange(len(rewards))  # steps from each state to the fall
        for low, high in BINS:
            at = (before >= low) & (before < high)
            by_bin[(low, high)] += list(zip(values[: len(rewards)][at], returns[at]))
    print(f"{args.episodes} episodes, mean length {np.mean(lengths):.0f}, {falls} ended in a fall; γ = {model.gamma}")
    print("| steps before the fall | states | mean min Q(z, π(z)) | mean return-to-go G | Q - G |")
    print("|---|---|---|---|---|")
    for (low, high), pairs in by_bin.items():
        if pairs:
            q, g = np.asarray(pairs).T
            label = f"{low}–{high - 1}" if high < 1_000_000 else f"≥ {low}"
            print(f"| {label} | {len(pairs)} | {q.mean():.1f} | {g.mean():.1f} | {q.mean() - g.mean():+.1f} |")


if __name__ == "__main__":
    main()
