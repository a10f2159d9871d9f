"""The discount from the task's time scale, so that ``γ`` looks as far ahead on an 8 ms robot as on a 0.1 s one.

With ``γ = 0.99`` the effective horizon ``1 / (1 - γ)`` is 100 steps: 10 s on the Point Robot (``dt = 0.1``), 0.8 s on
Hopper and Walker2d (8 ms steps), too short to see a fall coming. TD-MPC2 (Hansen et al. 2024) sets the discount from
the episode length ``L`` instead: ``γ = (L/5 - 1) / (L/5)``, clipped to ``[0.95, 0.995]``, which gives the paper's
0.99 on the Point Robot's 500-step episodes and 0.995 on 1000-step MuJoCo episodes.
"""

from __future__ import annotations

from stable_baselines3.common.vec_env import VecEnv

#: the paper's (and TD-MPC's) discount, used where the episode length is unknown
PAPER_GAMMA = 0.99


def episode_discount(episode_length: int | None, denominator: float = 5.0, low: float = 0.95, high: float = 0.995) -> float:
    """TD-MPC2's discount for episodes of ``episode_length`` steps: ``(L/d - 1) / (L/d)`` clipped to ``[low, high]``.

    :param episode_length: ``L``, the task's episode length (its time limit); ``None`` gives :data:`PAPER_GAMMA`.
    :param denominator: ``d``: the effective horizon ``1 / (1 - γ)`` is ``L / d`` steps.
    :param low: the smallest discount returned.
    :param high: the largest discount returned.
    """
    if episode_length is None:
        return PAPER_GAMMA
    if episode_length <= 0:
        raise ValueError(f"An episode length is a positive number of steps, got {episode_length}.")
    frac = episode_length / denominator
    return min(max((frac - 1.0) / frac, low), high)


def episode_length_of(env: VecEnv) -> int | None:
    """The time limit of a VecEnv's episodes (``env.spec.max_episode_steps``), or ``None`` where it declares none."""
    specs = env.get_attr("spec")
    lengths = {getattr(spec, "max_episode_steps", None) for spec in specs}
    return lengths.pop() if len(lengths) == 1 else None
