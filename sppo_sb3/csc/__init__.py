"""CSC: Conservative Safety Critics (Bharadhwaj et al., ICLR 2021)."""

from sppo_sb3.csc.csc import CSC
from sppo_sb3.csc.policies import CostCritic, CSCPolicy, RejectionSample, rejection_sample_actions

MlpPolicy = CSCPolicy

__all__ = ["CSC", "CSCPolicy", "CostCritic", "MlpPolicy", "RejectionSample", "rejection_sample_actions"]
