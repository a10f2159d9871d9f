"""The tiny settings of every algorithm the tests build: small networks and budgets, for tests of the plumbing, not of
learning. This module is their one home:

* constructor settings (``SPPO("TOLDPolicy", env, **TINY_SPPO)``), shared by the test files that build models directly;
* rl-zoo3 ``--hyperparams`` overrides (:data:`TINY_ZOO`), shared by the test files that train through the zoo
  (``sppo-train``, the benchmark), and a one-entry ``pdo.yml`` (:func:`tiny_pdo_yml`).

A test that needs a variant derives it (``{**TINY_SPPO, "learning_starts": 10}``) instead of writing a new dict; nobody
mutates these dicts in place.
"""

from __future__ import annotations

from typing import Any

# ---------------------------------------------------------------------------- SPPO: TOLD sizes, planner, algorithm
TINY_TOLD: dict[str, Any] = dict(latent_dim=8, encoder_dim=16, hidden_dim=16)
"""TOLD sizes (``TOLD(...)``, ``TOLDPolicy(...)``, SPPO's ``policy_kwargs``)."""
SMALL_TOLD: dict[str, Any] = {**TINY_TOLD, "hidden_dim": 32}
"""Wider hidden layers, for tests that train the model a little."""
TINIEST_TOLD: dict[str, Any] = dict(latent_dim=4, encoder_dim=8, hidden_dim=8)
"""The smallest TOLD, for tests that only build, save or warm up."""

TINY_MPPI: dict[str, Any] = dict(num_samples=16, num_elites=4, iterations=2)
"""The planner's sample counts (fields of ``MPPIConfig``)."""
TINIEST_MPPI: dict[str, Any] = dict(num_samples=8, num_elites=2, iterations=1)

TINY_SPPO: dict[str, Any] = dict(
    learning_starts=60,
    batch_size=16,
    horizon=3,
    buffer_size=5_000,
    policy_kwargs=TINY_TOLD,
    planner_kwargs={**TINY_MPPI, "horizon_warmup": 0},
)
"""SPPO's constructor settings: plans from the first step after a 60-step warm-up."""

# ---------------------------------------------------------------------------- on-policy baselines: PDO, CPO, SAILR, CSC
TINY_NET: dict[str, Any] = dict(net_arch=[16])
"""``policy_kwargs`` of PDO, CPO and SAILR."""
TINY_ROLLOUT: dict[str, Any] = dict(n_steps=64, batch_size=32)
"""A short rollout and its minibatch (with the default networks)."""
TINY_ON_POLICY: dict[str, Any] = {**TINY_ROLLOUT, "policy_kwargs": TINY_NET}
"""The on-policy constructor settings every baseline shares (each algorithm's own update budget at its default)."""
TINY_PDO: dict[str, Any] = {**TINY_ON_POLICY, "n_epochs": 2}
TINY_SAILR: dict[str, Any] = {**TINY_ON_POLICY, "n_epochs": 2}
TINY_CPO: dict[str, Any] = {**TINY_ON_POLICY, "n_critic_updates": 2}
TINY_CSC: dict[str, Any] = {
    **TINY_ON_POLICY,
    "n_epochs": 2,
    "cost_batch_size": 32,
    "cost_gradient_steps": 4,
    "n_action_samples": 20,
    "policy_kwargs": {**TINY_NET, "cost_net_arch": [16]},
}
QUICK_CSC: dict[str, Any] = {**TINY_CSC, "n_epochs": 1, "cost_batch_size": 16, "cost_gradient_steps": 2, "n_action_samples": 4}
"""CSC with one epoch and few samples, for the tests that run every algorithm."""

# ---------------------------------------------------------------------------- off-policy baseline: SACLag
TINY_SACLAG: dict[str, Any] = dict(
    learning_starts=24,
    batch_size=16,
    buffer_size=2_000,
    policy_kwargs=dict(net_arch=[16], cost_net_arch=[16]),
)
"""SACLag's constructor settings: 16-unit networks, one gradient step per env step after a 24-step warm-up."""


# ---------------------------------------------------------------------------- rl-zoo3 --hyperparams overrides
def _literal(settings: dict[str, Any]) -> str:
    """``settings`` as the ``dict(...)`` expression rl-zoo3 evaluates."""
    return "dict(" + ", ".join(f"{key}={value!r}" for key, value in settings.items()) + ")"


_ZOO_ON_POLICY = ["n_steps:64", "batch_size:32"]
_ZOO_COST_NETS = "policy_kwargs:dict(net_arch=[8], cost_net_arch=[8])"
TINY_ZOO: dict[str, list[str]] = {
    "sppo": [
        "learning_starts:60",
        "batch_size:16",
        "horizon:2",
        f"policy_kwargs:{_literal(TINY_TOLD)}",
        f"planner_kwargs:{_literal({**TINIEST_MPPI, 'horizon_warmup': 10, 'min_std_decay': 10})}",
    ],
    "pdo": [*_ZOO_ON_POLICY, "n_epochs:1", _ZOO_COST_NETS],
    "sailr": [*_ZOO_ON_POLICY, "n_epochs:1", "policy_kwargs:dict(net_arch=[8])"],
    "cpo": [*_ZOO_ON_POLICY, "n_critic_updates:1", "cg_max_steps:3", _ZOO_COST_NETS],
    "csc": [
        *_ZOO_ON_POLICY,
        "n_epochs:1",
        "n_action_samples:4",
        "cost_buffer_size:1000",
        "cost_batch_size:16",
        "cost_gradient_steps:2",
        "n_cost_baseline_samples:2",
        _ZOO_COST_NETS,
    ],
    "saclag": ["learning_starts:60", "batch_size:16", "buffer_size:1000", _ZOO_COST_NETS],
    "ddpg": ["learning_starts:60", "batch_size:16", "policy_kwargs:dict(net_arch=[8])"],
    "ppo": [*_ZOO_ON_POLICY, "n_epochs:1", "policy_kwargs:dict(net_arch=[8])"],
}
"""rl-zoo3 ``--hyperparams`` overrides per algorithm: 8-unit networks, short rollouts."""


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
