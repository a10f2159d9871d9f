from sppo_sb3.sailr.sailr import SAILR, shield_vec_env

__all__ = ["SAILR", "shield_vec_env"]
