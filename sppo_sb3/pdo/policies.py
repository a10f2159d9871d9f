"""Policies of PDO: SB3's actor-critic with an extra cost value head."""

from sppo_sb3.common.cost_policy import CostActorCriticPolicy

MlpPolicy = CostActorCriticPolicy

__all__ = ["MlpPolicy"]
