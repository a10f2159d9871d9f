"""Advantage-based shielding (Section III-B): rules, the built-in rules of the paper's tasks, and a wrapper."""

from __future__ import annotations

from collections.abc import Callable

from sppo_sb3.shield.base import ShieldDecision, ShieldingRule, in_shielding_set
from sppo_sb3.shield.cheetah import HalfCheetahHeightShieldingRule
from sppo_sb3.shield.learned import LearnedCostCriticRule
from sppo_sb3.shield.point import PointCircleShieldingRule
from sppo_sb3.shield.wrapper import ShieldWrapper

SHIELDING_RULES: dict[str, Callable[[], ShieldingRule]] = {
    "SafePointCircle-v0": PointCircleShieldingRule,
    "SafeHalfCheetahHeight-v0": HalfCheetahHeightShieldingRule,
}


def register_shielding_rule(env_id: str, factory: Callable[[], ShieldingRule]) -> None:
    """Make ``factory()`` the default rule (``shield="auto"``) of every algorithm on ``env_id``."""
    SHIELDING_RULES[env_id] = factory


def default_shielding_rule(env_id: str | None) -> ShieldingRule | None:
    """The registered rule for ``env_id``, or ``None`` when the task has none."""
    factory = SHIELDING_RULES.get(env_id) if env_id else None
    return factory() if factory is not None else None


__all__ = [
    "SHIELDING_RULES",
    "HalfCheetahHeightShieldingRule",
    "LearnedCostCriticRule",
    "PointCircleShieldingRule",
    "ShieldDecision",
    "ShieldWrapper",
    "ShieldingRule",
    "default_shielding_rule",
    "in_shielding_set",
    "register_shielding_rule",
]
