from sppo_sb3.cpo.cpo import CPO
from sppo_sb3.cpo.dual import CPOSolution, cpo_dual_solution
from sppo_sb3.cpo.policies import MlpPolicy

__all__ = ["CPO", "CPOSolution", "MlpPolicy", "cpo_dual_solution"]
