from sppo_sb3.sppo.policies import MlpPolicy, TOLDPolicy
from sppo_sb3.sppo.sppo import SPPO

__all__ = ["SPPO", "MlpPolicy", "TOLDPolicy"]
