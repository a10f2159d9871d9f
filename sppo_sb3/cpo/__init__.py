from sppo_sb3.cpo.cpo import CPO, CPOSolution, cpo_dual_solution
from sppo_sb3.cpo.policies import MlpPolicy

__all__ = ["CPO", "CPOSolution", "MlpPolicy", "cpo_dual_solution"]
