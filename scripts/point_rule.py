"""The Point Robot's shielding rules measured: the return ceiling each leaves, ``β`` and Theorem 1's bound.

For each rule (the default, the paper's and the band widths between), a scripted lap
(:func:`~sppo_sb3.envs.point_circle.scripted_lap_action`) aimed at each ``|x|`` of ``LAP_TARGETS`` runs one
500-step episode under the shield; the ceiling is the best safe lap's return, against the best unshielded one. (The
rules' cost per env step: ``scripts/bench_shield.py``.)
``β`` of Definition 2 is measured on random transitions of the true dynamics (:func:`~sppo_sb3.shield.analysis.bounds.
adoptability_gap`), and the bound of Theorem 1 at the task's start state.

    python scripts/point_rule.py                  # the table of docs/results.md
    python scripts/point_rule.py --transitions 2000
"""

from __future__ import annotations

import argparse

import numpy as np

from sppo_lab.point_lap import LAP_TARGETS, lap_ceiling
from sppo_sb3.envs.point_circle import PointParams, point_is_unsafe, point_step
from sppo_sb3.shield.analysis.bounds import adoptability_gap, theorem1_bound
from sppo_sb3.shield.tasks.point import PointCircleShieldingRule, paper_point_rule

RULES = {
    "paper (SAILR): brake both, band 0.5": paper_point_rule,
    "wall backup, band 0.5": lambda: PointCircleShieldingRule(alpha=0.5),
    "wall backup, band 0.25": lambda: PointCircleShieldingRule(alpha=0.25),
    "wall backup, band 0.1": lambda: PointCircleShieldingRule(alpha=0.1),
    "default: wall backup, band 0.05": PointCircleShieldingRule,
    "wall backup, no band": lambda: PointCircleShieldingRule(alpha=0.0),
}


def random_transitions(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Safe states over the strip and ``|y| <= 6`` at any speed, random actions, and the true next states."""
    params, rng = PointParams(), np.random.default_rng(seed)
    speed, angle = rng.uniform(0.0, params.max_speed, n), rng.uniform(0.0, 2.0 * np.pi, n)
    obs = np.stack(
        [
            rng.uniform(-params.x_limit, params.x_limit, n),
            rng.uniform(-6.0, 6.0, n),
            speed * np.cos(angle),
            speed * np.sin(angle),
        ],
        axis=1,
    )
    actions = rng.uniform(-1.0, 1.0, (n, 2))
    return obs, actions, point_step(obs, actions, params)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--transitions", type=int, default=20_000, help="random transitions for beta (default: 20000)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    unshielded = lap_ceiling(None)
    obs, actions, next_obs = random_transitions(args.transitions, args.seed)
    start = np.zeros((1, 4))  # the task starts at rest within 0.1 of the origin
    print(f"unshielded ceiling: return {unshielded.episode_return:.1f} (lap at |x| = {unshielded.x_target})\n")
    print("| rule | ceiling | of unshielded | lap's |x| target | max |x| | interventions | β | Theorem 1 bound |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, make in RULES.items():
        rule = make()
        best = lap_ceiling(rule)
        beta = adoptability_gap(rule, obs, actions, next_obs, point_is_unsafe(next_obs, PointParams()))
        backup_value = float(rule.definition2_value(start, rule.backup_action(start))[0])
        bound = theorem1_bound(backup_value, beta, rule.definition2_eta, rule.gamma)
        print(
            f"| {name} | {best.episode_return:.1f} | {best.episode_return / unshielded.episode_return:.0%} | "
            f"{best.x_target} | {best.max_abs_x:.3f} | {best.interventions} | {beta:.1e} | {bound:.1e} |"
        )
    print(f"\nlap targets |x|: {', '.join(map(str, LAP_TARGETS))}; beta on {args.transitions} random transitions")


if __name__ == "__main__":
    main()
