from sppo_sb3.sppo.planner import MPPIConfig
from sppo_sb3.sppo.policies import MlpPolicy, TOLDPolicy
from sppo_sb3.sppo.sppo import SPPO
from sppo_sb3.sppo.topo import TOPOConfig

__all__ = ["SPPO", "MPPIConfig", "MlpPolicy", "TOLDPolicy", "TOPOConfig"]
