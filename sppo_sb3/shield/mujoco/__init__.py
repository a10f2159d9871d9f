"""The MuJoCo shield engine: any constraint on a gymnasium MuJoCo env's state, certified by rollouts of "``a``, then
the MPPI backup" on the env's own model (:class:`~sppo_sb3.shield.mujoco.rule.MujocoShieldingRule`)."""
