"""Advantage-based shielding (Section III-B): rules, the built-in rules of the paper's tasks, and a wrapper."""

from __future__ import annotations

import warnings
from collections.abc import Callable

from stable_baselines3.common.vec_env import VecEnv

from sppo_sb3.shield.base import ShieldDecision, ShieldFailure, ShieldingRule, in_shielding_set
from sppo_sb3.shield.cheetah import HalfCheetahHeightShieldingRule
from sppo_sb3.shield.learned import LearnedCostCriticRule
from sppo_sb3.shield.persistence import ShieldRuleLoadError
from sppo_sb3.shield.point import PointCircleShieldingRule
from sppo_sb3.shield.wrapper import ShieldWrapper

SHIELDING_RULES: dict[str, Callable[[], ShieldingRule]] = {
    "SafePointCircle-v0": PointCircleShieldingRule,
    "SafeHalfCheetahHeight-v1": HalfCheetahHeightShieldingRule,
}


def register_shielding_rule(env_id: str, factory: Callable[[], ShieldingRule]) -> None:
    """Make ``factory()`` the default rule (``shield="auto"``) of every algorithm on ``env_id``.

    :param env_id: the gymnasium id of the task.
    :param factory: the rule's class, or a function without arguments that builds one (``lambda: MyRule(eta=0.1)``):
        every model gets its own rule, so a rule instance is rejected.
    """
    if isinstance(factory, ShieldingRule):
        name = type(factory).__name__
        raise TypeError(
            f"register_shielding_rule({env_id!r}, ...) got a {name} instance; pass the class or a factory instead: "
            f"register_shielding_rule({env_id!r}, {name}) or register_shielding_rule({env_id!r}, lambda: {name}(...)). "
            "To use one rule object, pass it as the algorithm's shield= argument."
        )
    if not callable(factory):
        raise TypeError(f"register_shielding_rule needs a ShieldingRule class or factory, got {factory!r}.")
    SHIELDING_RULES[env_id] = factory


def default_shielding_rule(env_id: str | None) -> ShieldingRule | None:
    """The registered rule for ``env_id``, or ``None`` when the task has none."""
    factory = SHIELDING_RULES.get(env_id) if env_id else None
    if factory is None:
        return None
    rule = factory()
    if not isinstance(rule, ShieldingRule):
        raise TypeError(f"The factory registered for {env_id!r} built {rule!r}, not a sppo_sb3.shield.ShieldingRule.")
    return rule


def resolve_shielding_rule(shield: ShieldingRule | str | None, env: VecEnv | None, required: bool) -> ShieldingRule | None:
    """The rule an algorithm's ``shield`` argument names.

    :param shield: a rule (used as is), ``None`` (no shield), ``"auto"`` (the rule registered for the env's id) or
        another env id (the rule registered for it).
    :param env: the training env, whose id ``"auto"`` looks up (``None``: not known yet, no rule).
    :param required: raise when no rule is found (SAILR cannot work without one); else ``"auto"`` without a rule
        warns that the algorithm runs unshielded (pass ``shield=None`` to say so and silence it).
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
    if rule is not None:
        return rule
    what = (
        "The env has no spec (it was not made with gymnasium.make), so shield='auto' cannot look its id up"
        if env_id is None
        else f"No shielding rule is registered for env id {env_id!r}"
    )
    fix = (
        "pass shield=YourRule() (a sppo_sb3.shield.ShieldingRule) or register one with "
        "sppo_sb3.shield.register_shielding_rule(env_id, YourRule)"
    )
    if required or shield != "auto":
        raise ValueError(f"{what}. Fix: {fix}.")
    warnings.warn(
        f"shield='auto' found no rule, so nothing is shielded. {what}. Fix: {fix}; or pass shield=None.", stacklevel=4
    )
    return None


__all__ = [
    "SHIELDING_RULES",
    "HalfCheetahHeightShieldingRule",
    "LearnedCostCriticRule",
    "PointCircleShieldingRule",
    "ShieldDecision",
    "ShieldFailure",
    "ShieldRuleLoadError",
    "ShieldWrapper",
    "ShieldingRule",
    "default_shielding_rule",
    "in_shielding_set",
    "register_shielding_rule",
    "resolve_shielding_rule",
]
