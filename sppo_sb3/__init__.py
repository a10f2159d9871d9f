"""sppo_sb3: safe, data-efficient model-based RL (SPPO) and safe-RL baselines for Stable-Baselines3."""

import os

import sppo_sb3.envs  # noqa: F401  (registers the tasks with gymnasium)

with open(os.path.join(os.path.dirname(__file__), "version.txt")) as file_handler:
    __version__ = file_handler.read().strip()

__all__ = ["__version__"]
