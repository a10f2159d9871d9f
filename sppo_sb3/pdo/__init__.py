from sppo_sb3.pdo.pdo import PDO
from sppo_sb3.pdo.policies import MlpPolicy

__all__ = ["PDO", "MlpPolicy"]
