from sppo_sb3.pdo.pdo import PDO, lagrange_update
from sppo_sb3.pdo.policies import MlpPolicy

__all__ = ["PDO", "MlpPolicy", "lagrange_update"]
