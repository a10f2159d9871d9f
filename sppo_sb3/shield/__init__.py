"""Advantage-based shielding (Section III-B): rules, the built-in rules of the paper's tasks, their registry, and a
wrapper."""

from sppo_sb3.shield.base import ShieldDecision, ShieldFailure, ShieldingRule, in_shielding_set
from sppo_sb3.shield.cheetah import HalfCheetahHeightShieldingRule
from sppo_sb3.shield.latent import LatentModelRule
from sppo_sb3.shield.learned import LearnedCostCriticRule, RefinableRule
from sppo_sb3.shield.learned_model import LearnedDynamicsRule
from sppo_sb3.shield.mjmodel import ConstraintSteps, MujocoLayout, StateConstraint
from sppo_sb3.shield.mujoco import MujocoShieldingRule
from sppo_sb3.shield.persistence import ShieldRuleLoadError
from sppo_sb3.shield.point import PointCircleShieldingRule
from sppo_sb3.shield.registry import (
    RULE_ENV_PARAMETERS,
    SHIELDING_RULES,
    default_shielding_rule,
    register_shielding_rule,
    resolve_shielding_rule,
    rule_parameters_of,
)
from sppo_sb3.shield.velocity import VelocityConstraint
from sppo_sb3.shield.wrapper import ShieldWrapper

__all__ = [
    "RULE_ENV_PARAMETERS",
    "SHIELDING_RULES",
    "ConstraintSteps",
    "HalfCheetahHeightShieldingRule",
    "LatentModelRule",
    "LearnedCostCriticRule",
    "LearnedDynamicsRule",
    "MujocoLayout",
    "MujocoShieldingRule",
    "PointCircleShieldingRule",
    "RefinableRule",
    "ShieldDecision",
    "ShieldFailure",
    "ShieldRuleLoadError",
    "ShieldWrapper",
    "ShieldingRule",
    "StateConstraint",
    "VelocityConstraint",
    "default_shielding_rule",
    "in_shielding_set",
    "register_shielding_rule",
    "resolve_shielding_rule",
    "rule_parameters_of",
]
