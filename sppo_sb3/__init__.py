"""sppo_sb3: safe, data-efficient model-based RL (SPPO) and safe-RL baselines for Stable-Baselines3."""

import os

import sppo_sb3.envs  # noqa: F401  (registers the tasks with gymnasium)
from sppo_sb3.sppo import SPPO, TOLDPolicy

with open(os.path.join(os.path.dirname(__file__), "version.txt")) as file_handler:
    __version__ = file_handler.read().strip()

__all__ = ["SPPO", "TOLDPolicy", "__version__"]
