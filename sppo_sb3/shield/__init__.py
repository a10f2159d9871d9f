"""Advantage-based shielding (Section III-B).

The contract lives at this package's top: :class:`ShieldingRule` (``base``), :class:`ShieldWrapper` (``wrapper``), the
registry behind ``shield="auto"`` (``registry``), what the learner is told of an intervention (``intervention``, the
``on_intervention`` and ``penalty`` that SPPO, SAILR and the wrapper share), saving and loading a shielded model's rule
(``persistence``) and deployment with and without the shield (``evaluation``). Beneath it, by role:

- ``tasks``: the built-in tasks' rules (Point Robot, Half-Cheetah height, velocity);
- ``mujoco``: the MuJoCo engine, a certified rule for any constraint on a MuJoCo env's state;
- ``learned``: rules that learn where no model exists (Alg. 1 line 12);
- ``analysis``: Theorem 1's bound and the comparison of a rule's decisions with a reference's.
"""

from sppo_sb3.shield.base import ShieldDecision, ShieldFailure, ShieldingRule, in_shielding_set
from sppo_sb3.shield.intervention import ON_INTERVENTION, OnIntervention
from sppo_sb3.shield.learned.base import RefinableRule
from sppo_sb3.shield.learned.critic import LearnedCostCriticRule
from sppo_sb3.shield.learned.dynamics import LearnedDynamicsRule
from sppo_sb3.shield.learned.latent import LatentModelRule
from sppo_sb3.shield.mujoco.model import ConstraintCosts, ConstraintSteps, MujocoLayout, StateConstraint
from sppo_sb3.shield.mujoco.rule import MujocoShieldingRule
from sppo_sb3.shield.registry import (
    RULE_ENV_PARAMETERS,
    SHIELDING_RULES,
    default_shielding_rule,
    register_shielding_rule,
    resolve_shielding_rule,
    rule_parameters_of,
)
from sppo_sb3.shield.tasks.cheetah import HalfCheetahHeightShieldingRule
from sppo_sb3.shield.tasks.point import PointCircleShieldingRule
from sppo_sb3.shield.tasks.velocity import VelocityConstraint
from sppo_sb3.shield.wrapper import ShieldWrapper

__all__ = [
    "ON_INTERVENTION",
    "RULE_ENV_PARAMETERS",
    "SHIELDING_RULES",
    "ConstraintCosts",
    "ConstraintSteps",
    "HalfCheetahHeightShieldingRule",
    "LatentModelRule",
    "LearnedCostCriticRule",
    "LearnedDynamicsRule",
    "MujocoLayout",
    "MujocoShieldingRule",
    "OnIntervention",
    "PointCircleShieldingRule",
    "RefinableRule",
    "ShieldDecision",
    "ShieldFailure",
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
