"""``sppo-enjoy`` / ``python -m sppo_sb3.enjoy``: rl-zoo3's enjoy command with the package's algorithms.

Every rl-zoo3 flag works unchanged (``--algo sppo --env SafePointCircle-v0 -f logs/ --no-render -n 1000``). Models
are loaded to be watched: SPPO and CSC allocate no replay buffer (they do so on their first ``learn`` only). Each
finished episode's cost and violations are printed after its reward, and the totals (mean cost, violations, safety
rate) at the end.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from stable_baselines3.common.vec_env import VecEnv


def _cost_reporting(create_test_env: Any) -> Any:
    """Wrap rl-zoo3's ``create_test_env`` so that the env it returns reports episode costs."""
    from sppo_sb3.common.monitor import VecCostReporter

    if getattr(create_test_env, "_sppo_cost_reporting", False):
        return create_test_env

    def create(*args: Any, **kwargs: Any) -> VecEnv:
        return VecCostReporter(create_test_env(*args, **kwargs))

    create._sppo_cost_reporting = True  # type: ignore[attr-defined]
    return create


def main(argv: Sequence[str] | None = None) -> None:
    """Run rl-zoo3's enjoy command with the package's algorithms registered (for watching, not training).

    :param argv: command-line arguments (default: ``sys.argv[1:]``).
    """
    from rl_zoo3 import enjoy as zoo_enjoy

    from sppo_sb3.zoo import register_algos

    register_algos()
    zoo_enjoy.create_test_env = _cost_reporting(zoo_enjoy.create_test_env)  # type: ignore[attr-defined]
    saved_argv = sys.argv
    sys.argv = [saved_argv[0] if saved_argv else "sppo-enjoy", *(sys.argv[1:] if argv is None else argv)]
    try:
        zoo_enjoy.enjoy()
    finally:
        sys.argv = saved_argv


if __name__ == "__main__":
    main()
