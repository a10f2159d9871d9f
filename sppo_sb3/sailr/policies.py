"""Policies of SAILR: SB3's actor-critic with a cost value head (the intervention cost's critic ``V_C``)."""

from sppo_sb3.common.cost_policy import CostActorCriticPolicy

MlpPolicy = CostActorCriticPolicy

__all__ = ["MlpPolicy"]
