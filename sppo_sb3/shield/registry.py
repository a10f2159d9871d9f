"""The shielding rule of each task: what ``shield="auto"`` finds, built from the env's own parameters.

Every algorithm that shields (SPPO, SAILR) resolves its ``shield`` argument here (:func:`resolve_shielding_rule`); a
user's task joins with :func:`register_shielding_rule`.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
from stable_baselines3.common.vec_env import VecEnv

from sppo_sb3.envs.navigation import NAVIGATION_TASKS
from sppo_sb3.envs.point_circle import SafePointCircleEnv, point_distance_to_unsafe, point_is_unsafe
from sppo_sb3.envs.velocity import VELOCITY_TASKS
from sppo_sb3.shield.base import ShieldingRule
from sppo_sb3.shield.learned.dynamics import LearnedDynamicsRule
from sppo_sb3.shield.learned.latent import LatentModelRule
from sppo_sb3.shield.tasks.cheetah import HalfCheetahHeightShieldingRule
from sppo_sb3.shield.tasks.navigation import navigation_shielding_rule
from sppo_sb3.shield.tasks.point import PointCircleShieldingRule, paper_point_rule
from sppo_sb3.shield.tasks.velocity import velocity_shielding_rule

#: a variant of a task's rule, named ``"<env id>:<variant>"``: pass the name as ``shield`` to train with it
PAPER_POINT_RULE = "SafePointCircle-v0:paper"
#: the Point Robot's rule without its model: the dynamics learned, for the learned-shield measurements (SPPO refines it)
LEARNED_POINT_RULE = "SafePointCircle-v0:learned"
#: the Point Robot's rule on SPPO's own TOLD: cost and backup heads learned on its latents (SPPO only)
LATENT_POINT_RULE = "SafePointCircle-v0:latent"


def learned_point_rule(**kwargs: Any) -> LearnedDynamicsRule:
    """The Point rule's backup, constraint and band on a learned model of the dynamics; ``kwargs`` override.

    What a user without the Point Robot's equations would build: a :class:`LearnedDynamicsRule` that ``SPPO`` fits on
    its buffer (``refine_shield="auto"``), rolled for long enough to stop from full speed.
    """
    env, model_rule = SafePointCircleEnv(), PointCircleShieldingRule()
    settings = {"alpha": model_rule.alpha, "horizon": model_rule.horizon + 10, **kwargs}
    return LearnedDynamicsRule(
        env.observation_space,
        env.action_space,
        model_rule.backup_action,
        lambda obs: point_is_unsafe(obs, env.params),
        lambda obs: point_distance_to_unsafe(obs, env.params),
        **settings,
    )


def latent_point_rule(**kwargs: Any) -> LatentModelRule:
    """The Point rule's backup on SPPO's TOLD (:class:`LatentModelRule`), rolled for long enough to stop from full
    speed; ``kwargs`` override. The constraint is learned too, from the env's ``info["shaped_cost"]`` and ``info["cost"]``."""
    env, model_rule = SafePointCircleEnv(), PointCircleShieldingRule()
    settings = {"horizon": model_rule.horizon + 10, **kwargs}
    return LatentModelRule(env.observation_space, env.action_space, model_rule.backup_action, **settings)


#: the rule of each task (``shield="auto"``), by gymnasium id, and named variants: a class or factory, called for
#: every model
SHIELDING_RULES: dict[str, Callable[..., ShieldingRule]] = {
    "SafePointCircle-v0": PointCircleShieldingRule,
    PAPER_POINT_RULE: paper_point_rule,  # the paper's and SAILR's: brake both axes, band 0.5 (Table I's first rows)
    LEARNED_POINT_RULE: learned_point_rule,  # no model: the dynamics learned from B (SPPO refines it)
    LATENT_POINT_RULE: latent_point_rule,  # no model: Q̄ rolled on SPPO's own TOLD (SPPO only)
    "SafeHalfCheetahHeight-v1": HalfCheetahHeightShieldingRule,
    **{task.env_id: functools.partial(velocity_shielding_rule, task) for task in VELOCITY_TASKS},
    **{
        task.env_id: functools.partial(navigation_shielding_rule, task.robot, task.task, task.level)
        for task in NAVIGATION_TASKS
        if task.level > 0  # level 0 constrains nothing
    },
}
#: the env's own parameters each task's rule is built from: attributes of the env passed to the factory as keyword
#: arguments of the same name (so the rule agrees with the env made, e.g. its shaped-cost band ``alpha`` of eq. 18)
RULE_ENV_PARAMETERS: dict[str, tuple[str, ...]] = {
    "SafePointCircle-v0": ("params", "alpha"),
    "SafeHalfCheetahHeight-v1": ("alpha",),
    **{task.env_id: ("alpha",) for task in VELOCITY_TASKS},
    **{task.env_id: ("alpha",) for task in NAVIGATION_TASKS if task.level > 0},
}


def register_shielding_rule(env_id: str, factory: Callable[..., ShieldingRule], env_parameters: Sequence[str] = ()) -> None:
    """Make ``factory()`` the default rule (``shield="auto"``) of every algorithm on ``env_id``.

    :param env_id: the gymnasium id of the task.
    :param factory: the rule's class, or a function that builds one (``lambda: MyRule(eta=0.1)``): every model gets
        its own rule, so a rule instance is rejected.
    :param env_parameters: names of the env's attributes that the rule is built from, passed to ``factory`` as keyword
        arguments of the same name when the env is known (``("alpha",)``: ``factory(alpha=env.alpha)``); empty: the
        factory is called without arguments.
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
    if isinstance(env_parameters, str):
        raise TypeError(f"env_parameters must be a sequence of attribute names, e.g. ({env_parameters!r},), not a string.")
    SHIELDING_RULES[env_id] = factory
    RULE_ENV_PARAMETERS[env_id] = tuple(env_parameters)


def _env_attribute(env: gym.Env | VecEnv, name: str) -> Any:
    """Attribute ``name`` of the (first) env, looked up through its wrappers."""
    return env.get_attr(name, indices=[0])[0] if isinstance(env, VecEnv) else env.get_wrapper_attr(name)


def rule_parameters_of(env_id: str, env: gym.Env | VecEnv | None) -> dict[str, Any]:
    """The keyword arguments that the rule registered for ``env_id`` takes from ``env`` (:data:`RULE_ENV_PARAMETERS`).

    :param env_id: the gymnasium id of the task.
    :param env: an env of that task, or ``None`` (the rule's own defaults: no arguments).
    :raises ValueError: the env lacks one of the attributes.
    """
    names = RULE_ENV_PARAMETERS.get(env_id, ())
    if env is None or not names:
        return {}
    parameters = {}
    for name in names:
        try:
            parameters[name] = _env_attribute(env, name)
        except AttributeError:
            raise ValueError(
                f"The shielding rule registered for {env_id!r} is built from the env's attribute {name!r}, which this "
                f"env lacks. Fix: give the env that attribute, or register the rule with the parameters the env has: "
                f"register_shielding_rule({env_id!r}, factory, env_parameters=(...))."
            ) from None
    return parameters


def default_shielding_rule(env_id: str | None, env: gym.Env | VecEnv | None = None) -> ShieldingRule | None:
    """The registered rule for ``env_id``, or ``None`` when the task has none.

    :param env_id: the gymnasium id of the task.
    :param env: an env of that task (a gymnasium env or a VecEnv): the rule is built from its parameters
        (:data:`RULE_ENV_PARAMETERS`: e.g. ``gym.make("SafePointCircle-v0", alpha=0.3)`` gives a rule with ``alpha``
        0.3); ``None``: the rule's defaults, which are the task's defaults.
    """
    factory = SHIELDING_RULES.get(env_id) if env_id else None
    if factory is None or env_id is None:
        return None
    rule = factory(**rule_parameters_of(env_id, env))
    if not isinstance(rule, ShieldingRule):
        raise TypeError(f"The factory registered for {env_id!r} built {rule!r}, not a sppo_sb3.shield.ShieldingRule.")
    return rule


def _env_id(env: gym.Env | VecEnv) -> str | None:
    """The gymnasium id the (first) env was made with, or ``None`` (not made with ``gymnasium.make``)."""
    spec = env.get_attr("spec", indices=[0])[0] if isinstance(env, VecEnv) else env.spec
    return spec.id if spec is not None else None


def resolve_shielding_rule(
    shield: ShieldingRule | str | None, env: gym.Env | VecEnv | None, required: bool
) -> ShieldingRule | None:
    """The rule an algorithm's ``shield`` argument names.

    :param shield: a rule (used as is), ``None`` (no shield), ``"auto"`` (the rule registered for the env's id) or
        another registered name: an env id or a variant's ``"<env id>:<variant>"`` (e.g. :data:`PAPER_POINT_RULE`),
        whose rule is built with its own defaults.
    :param env: the training env (a VecEnv or a gymnasium env), whose id ``"auto"`` looks up (``None``: not known yet,
        no rule). A rule registered for the env's own id is built from the env's parameters
        (:func:`default_shielding_rule`).
    :param required: raise when no rule is found (SAILR cannot work without one); else ``"auto"`` without a rule
        warns that the algorithm runs unshielded (pass ``shield=None`` to say so and silence it).
    """
    if shield is None or isinstance(shield, ShieldingRule):
        return shield
    if not isinstance(shield, str):
        raise TypeError(f"shield must be a ShieldingRule, 'auto', an env id or None, got {shield!r}.")
    if shield == "auto" and env is None:
        return None
    own_id = _env_id(env) if env is not None else None
    env_id = own_id if shield == "auto" else shield
    rule = default_shielding_rule(env_id, env if env_id == own_id else None)
    if rule is not None:
        return rule
    what = (
        "The env has no spec (it was not made with gymnasium.make), so shield='auto' cannot look its id up"
        if env_id is None
        else f"No shielding rule is registered for env id {env_id!r}"
    )
    fix = (
        "pass your rule (a sppo_sb3.shield.ShieldingRule: shield=YourRule() to an algorithm, "
        "ShieldWrapper(env, YourRule()) to a wrapper) or register one with "
        "sppo_sb3.shield.register_shielding_rule(env_id, YourRule)"
    )
    if required or shield != "auto":
        raise ValueError(f"{what}. Fix: {fix}.")
    warnings.warn(
        f"shield='auto' found no rule, so nothing is shielded. {what}. Fix: {fix}; or pass shield=None.", stacklevel=4
    )
    return None
