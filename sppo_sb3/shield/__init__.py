"""Advantage-based shielding (Section III-B): rules, the built-in rules of the paper's tasks, and a wrapper."""

from __future__ import annotations

from collections.abc import Callable

from stable_baselines3.common.vec_env import VecEnv

from sppo_sb3.shield.base import ShieldDecision, ShieldingRule, in_shielding_set
from sppo_sb3.shield.cheetah import HalfCheetahHeightShieldingRule
from sppo_sb3.shield.learned import LearnedCostCriticRule
from sppo_sb3.shield.point import PointCircleShieldingRule
from sppo_sb3.shield.wrapper import ShieldWrapper

SHIELDING_RULES: dict[str, Callable[[], ShieldingRule]] = {
    "SafePointCircle-v0": PointCircleShieldingRule,
    "SafeHalfCheetahHeight-v1": HalfCheetahHeightShieldingRule,
}


def register_shielding_rule(env_id: str, factory: Callable[[], ShieldingRule]) -> None:
    """Make ``factory()`` the default rule (``shield="auto"``) of every algorithm on ``env_id``."""
    SHIELDING_RULES[env_id] = factory


def default_shielding_rule(env_id: str | None) -> ShieldingRule | None:
    """The registered rule for ``env_id``, or ``None`` when the task has none."""
    factory = SHIELDING_RULES.get(env_id) if env_id else None
    return factory() if factory is not None else None


def resolve_shielding_rule(shield: ShieldingRule | str | None, env: VecEnv | None, required: bool) -> ShieldingRule | None:
    """The rule an algorithm's ``shield`` argument names.

    :param shield: a rule (used as is), ``None`` (no shield), ``"auto"`` (the rule registered for the env's id) or
        another env id (the rule registered for it).
    :param env: the training env, whose id ``"auto"`` looks up (``None``: not known yet, no rule).
    :param required: raise when no rule is found (SAILR cannot work without one; SPPO then runs unshielded).
    """
    if shield is None or isinstance(shield, ShieldingRule):
        return shield
    if not isinstance(shield, str):
        raise TypeError(f"shield must be a ShieldingRule, 'auto', an env id or None, got {shield!r}.")
    env_id: str | None = shield
    if shield == "auto":
        if env is None:
            return None
        spec = env.get_attr("spec", indices=[0])[0]
        env_id = spec.id if spec is not None else None
    rule = default_shielding_rule(env_id)
    if rule is None and (required or shield != "auto"):
        raise ValueError(
            f"No shielding rule is registered for env id {env_id!r}: pass shield=YourRule() (a "
            "sppo_sb3.shield.ShieldingRule), register one with sppo_sb3.shield.register_shielding_rule, or pass "
            "shield=None."
        )
    return rule


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
    "resolve_shielding_rule",
]
