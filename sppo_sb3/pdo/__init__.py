from sppo_sb3.common.lagrange import lagrange_update
from sppo_sb3.pdo.pdo import PDO
from sppo_sb3.pdo.policies import MlpPolicy

__all__ = ["PDO", "MlpPolicy", "lagrange_update"]
