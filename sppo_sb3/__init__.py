"""sppo_sb3: safe, data-efficient model-based RL (SPPO) and safe-RL baselines for Stable-Baselines3."""

import os

import sppo_sb3.envs  # noqa: F401  (registers the tasks with gymnasium)
from sppo_sb3.cpo import CPO
from sppo_sb3.csc import CSC
from sppo_sb3.pdo import PDO
from sppo_sb3.saclag import SACLag
from sppo_sb3.sailr import SAILR
from sppo_sb3.shield.persistence import ShieldRuleLoadError
from sppo_sb3.sppo import SPPO, TOLDPolicy

with open(os.path.join(os.path.dirname(__file__), "version.txt")) as file_handler:
    __version__ = file_handler.read().strip()

__all__ = ["CPO", "CSC", "PDO", "SAILR", "SPPO", "SACLag", "ShieldRuleLoadError", "TOLDPolicy", "__version__"]
