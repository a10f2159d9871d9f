"""Fingerprints of short trainings, to show that a refactoring leaves training bit for bit unchanged.

Each configuration trains a few hundred steps with the tests' tiny settings (``tests/tiny_hyperparams.py``), one
thread, eager, seeded; its fingerprint is the SHA-256 of the policy's parameters and of the learned shielding rule's,
and the safety summary. Run it on two commits and compare::

    git worktree add /tmp/before <commit>
    PYTHONPATH=/tmp/before python scripts/training_fingerprints.py --out before.json   # run from outside the checkout
    python scripts/training_fingerprints.py --out after.json
    python scripts/training_fingerprints.py --compare before.json after.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ["TORCH_COMPILE_DISABLE"] = "1"  # before torch is imported: the eager reference

import torch as th
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import gymnasium as gym
from stable_baselines3 import SAC
from tiny_hyperparams import TINY_CPO, TINY_CSC, TINY_PDO, TINY_SACLAG, TINY_SAILR, TINY_SPPO

from sppo_sb3 import CPO, CSC, PDO, SAILR, SPPO, SACLag
from sppo_sb3.shield import LatentModelRule, LearnedCostCriticRule, LearnedDynamicsRule, ShieldWrapper

POINT, CHEETAH, HOPPER = "SafePointCircle-v0", "SafeHalfCheetahHeight-v1", "sppo_sb3/SafetyHopperVelocity-v1"

CONFIGS: dict[str, tuple[Callable[[], Any], int]] = {
    "sppo_point": (lambda: SPPO("TOLDPolicy", POINT, seed=0, **TINY_SPPO), 300),
    "sppo_point_unshielded": (lambda: SPPO("TOLDPolicy", POINT, seed=1, shield=None, **TINY_SPPO), 300),
    "sppo_point_learned_rule": (lambda: SPPO("TOLDPolicy", POINT, seed=2, shield=f"{POINT}:learned", **TINY_SPPO), 300),
    "sppo_point_latent_rule": (lambda: SPPO("TOLDPolicy", POINT, seed=3, shield=f"{POINT}:latent", **TINY_SPPO), 300),
    "sppo_cheetah_height": (lambda: SPPO("TOLDPolicy", CHEETAH, seed=0, **{**TINY_SPPO, "learning_starts": 30}), 80),
    "sppo_hopper_velocity": (lambda: SPPO("TOLDPolicy", HOPPER, seed=0, **{**TINY_SPPO, "learning_starts": 30}), 80),
    "sppo_point_terminate": (lambda: SPPO("TOLDPolicy", POINT, seed=4, on_intervention="terminate", **TINY_SPPO), 300),
    "sppo_point_continue": (
        lambda: SPPO("TOLDPolicy", POINT, seed=5, on_intervention="continue", penalty=0.5, **TINY_SPPO),
        300,
    ),
    "sppo_point_none": (lambda: SPPO("TOLDPolicy", POINT, seed=6, on_intervention="none", **TINY_SPPO), 300),
    "sppo_hopper_auto_gamma": (
        lambda: SPPO("TOLDPolicy", HOPPER, seed=1, gamma="auto", **{**TINY_SPPO, "learning_starts": 30}),
        80,
    ),
    "sac_point_wrapper_continue": (lambda: shielded_sac("continue", seed=0), 300),
    "sac_point_wrapper_terminate": (lambda: shielded_sac("terminate", seed=1, penalty=1.0), 300),
    "sac_point_wrapper_takeover": (lambda: shielded_sac("takeover", seed=2), 300),
    "sailr_point": (lambda: SAILR("MlpPolicy", POINT, seed=0, **TINY_SAILR), 300),
    "pdo_point": (lambda: PDO("MlpPolicy", POINT, seed=0, **TINY_PDO), 300),
    "cpo_point": (lambda: CPO("MlpPolicy", POINT, seed=0, **TINY_CPO), 300),
    "csc_point": (lambda: CSC("MlpPolicy", POINT, seed=0, **TINY_CSC), 300),
    "saclag_point": (lambda: SACLag("MlpPolicy", POINT, seed=0, **TINY_SACLAG), 300),
}


def shielded_sac(mode: str, seed: int, penalty: float = 0.0) -> SAC:
    """SAC behind ``ShieldWrapper`` on the Point task, in one of the wrapper's intervention modes."""
    env = ShieldWrapper(gym.make(POINT), "auto", on_intervention=mode, penalty=penalty)
    return SAC("MlpPolicy", env, seed=seed, learning_starts=50, batch_size=16, policy_kwargs=dict(net_arch=[16]))


def parameters_digest(modules: list[nn.Module]) -> str:
    """SHA-256 (first 16 hex digits) of every parameter and buffer of ``modules``, in name order."""
    digest = hashlib.sha256()
    for module in modules:
        for name, value in sorted(module.state_dict().items()):
            digest.update(name.encode())
            digest.update(value.detach().cpu().numpy().tobytes())
    return digest.hexdigest()[:16]


def learned_rule_modules(model: Any) -> list[nn.Module]:
    """The networks of a learned shielding rule in use (none for a model rule)."""
    rule = getattr(model, "shield_rule", None)
    if not isinstance(rule, (LatentModelRule, LearnedCostCriticRule, LearnedDynamicsRule)):
        return []
    told = getattr(rule, "model", None)  # the latent rule's TOLD is the policy's, fingerprinted with it
    return [value for value in vars(rule).values() if isinstance(value, nn.Module) and value is not told]


def fingerprint(make: Callable[[], Any], steps: int) -> dict[str, Any]:
    """Train ``steps`` env steps and fingerprint the result."""
    model = make()
    model.learn(steps)
    return {
        "parameters": parameters_digest([model.policy, *learned_rule_modules(model)]),
        "safety": safety_summary(model),
    }


def safety_summary(model: Any) -> dict[str, float]:
    """The safety summary of a shielded algorithm; for a learner behind ``ShieldWrapper``, its episode returns."""
    if hasattr(model, "safety_metrics"):
        return {key: round(float(value), 10) for key, value in model.safety_metrics.summary().items()}
    return {"episode_returns": round(float(sum(info["r"] for info in model.ep_info_buffer)), 10)}


def compare(before: Path, after: Path) -> int:
    """Print each configuration as SAME or DIFFERENT; exit status 1 if any differs or is missing."""
    a, b = json.loads(before.read_text()), json.loads(after.read_text())
    differ = 0
    for name in sorted(set(a) | set(b)):
        same = a.get(name) == b.get(name)
        differ += not same
        print(f"{name:26s} {'SAME' if same else 'DIFFERENT'}")
    return int(differ > 0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, help="write the fingerprints to this JSON file")
    parser.add_argument("--compare", type=Path, nargs=2, metavar=("BEFORE", "AFTER"), help="compare two JSON files")
    args = parser.parse_args()
    if args.compare:
        return compare(*args.compare)
    th.set_num_threads(1)
    results = {}
    for name, (make, steps) in CONFIGS.items():
        results[name] = fingerprint(make, steps)
        print(name, results[name]["parameters"], flush=True)
    if args.out:
        args.out.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
