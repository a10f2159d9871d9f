"""The envs' retired ``default_shielding_rule()`` method: a warning that delegates to the shield registry.

The envs hold the physics only. Their shielding rules live in :mod:`sppo_sb3.shield`, whose registry builds each
task's rule from the env's own parameters (:func:`sppo_sb3.shield.default_shielding_rule`).
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym


def warn_default_shielding_rule(env: gym.Env, env_id: str) -> Any:
    """Warn that ``env.default_shielding_rule()`` is deprecated and return the registry's rule for ``env``.

    :param env: the env whose method was called.
    :param env_id: the task's gymnasium id.
    """
    warnings.warn(
        f"{type(env).__name__}.default_shielding_rule() is deprecated and will be removed: the shield registry builds the "
        f"task's rule from the env's parameters. Use sppo_sb3.shield.default_shielding_rule({env_id!r}, env), or "
        "shield='auto' in SPPO/SAILR.",
        DeprecationWarning,
        stacklevel=3,
    )
    from sppo_sb3.shield import default_shielding_rule  # only on this deprecated path: the envs import no shield code

    return default_shielding_rule(env_id, env)
