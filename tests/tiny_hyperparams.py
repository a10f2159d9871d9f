"""Tiny networks and budgets per algorithm, as rl-zoo3 ``--hyperparams`` overrides: for tests of the plumbing
(``sppo-train``, the benchmark), not of learning. One list per algorithm, shared by the test files that train through
the zoo."""

TINY_SPPO = [
    "learning_starts:60",
    "batch_size:16",
    "horizon:2",
    "policy_kwargs:dict(latent_dim=8, encoder_dim=16, hidden_dim=16)",
    "planner_kwargs:dict(num_samples=8, num_elites=2, iterations=1, horizon_warmup=10, min_std_decay=10)",
]
TINY_DDPG = ["learning_starts:60", "batch_size:16", "policy_kwargs:dict(net_arch=[8])"]
TINY_PPO = ["n_steps:64", "batch_size:32", "n_epochs:1", "policy_kwargs:dict(net_arch=[8])"]


def tiny_pdo_yml(task: str, steps: int) -> str:
    """A ``pdo.yml`` with one entry: ``task`` for ``steps`` env steps with 8-unit networks."""
    return f"""
{task}:
  n_timesteps: {steps}
  policy: 'MlpPolicy'
  n_steps: 256
  batch_size: 64
  n_epochs: 1
  cost_limit: 0.05
  policy_kwargs: "dict(net_arch=dict(pi=[8], vf=[8]), cost_net_arch=[8])"
"""
