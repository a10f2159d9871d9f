"""SACLag: SAC-Lagrangian with a learned cost critic (OmniSafe's off-policy Lagrangian baseline)."""

from sppo_sb3.saclag.policies import MlpPolicy, SACLagPolicy
from sppo_sb3.saclag.saclag import SACLag

__all__ = ["MlpPolicy", "SACLag", "SACLagPolicy"]
