"""What SPPO reads from the task: the discount from its time scale, and whether its episodes end on their own.

The discount, so that ``γ`` looks as far ahead on an 8 ms robot as on a 0.1 s one.

With ``γ = 0.99`` the effective horizon ``1 / (1 - γ)`` is 100 steps: 10 s on the Point Robot (``dt = 0.1``), 0.8 s on
Hopper and Walker2d (8 ms steps), too short to see a fall coming. TD-MPC2 (Hansen et al. 2024) sets the discount from
the episode length ``L`` instead: ``γ = (L/5 - 1) / (L/5)``, clipped to ``[0.95, 0.995]``, which gives the paper's
0.99 on the Point Robot's 500-step episodes and 0.995 on 1000-step MuJoCo episodes.

Termination: a planner that sums reward and value past an imagined fall plans as if the robot could not fall. TD-MPC2
refuses such tasks unless its episodic head is on; SPPO turns its termination head on where the task ends episodes
on its own (:func:`task_terminates`).
"""

from __future__ import annotations

from typing import Literal

from stable_baselines3.common.vec_env import VecEnv

#: the paper's (and TD-MPC's) discount, used where the episode length is unknown
PAPER_GAMMA = 0.99


def resolve_gamma(gamma: float | Literal["auto"], env: VecEnv | None) -> float:
    """SPPO's discount, resolved once: the given number, or for ``"auto"`` TD-MPC2's discount for the task's episode
    length (:func:`episode_discount`; :data:`PAPER_GAMMA` without an env or where the length is unknown).

    :param gamma: a discount in ``(0, 1]`` or ``"auto"``.
    :param env: the training env (``None``: not known yet, e.g. while a saved model is loaded).
    :raises ValueError: neither a number nor ``"auto"``.
    """
    if gamma == "auto":
        return episode_discount(episode_length_of(env)) if env is not None else PAPER_GAMMA
    if isinstance(gamma, str):
        raise ValueError(f'gamma is a discount in (0, 1] or "auto" (from the episode length), got {gamma!r}.')
    return gamma


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


#: the attribute by which gymnasium's MuJoCo robots (Hopper, Walker2d, Ant, Humanoid, their velocity tasks) say that an
#: unhealthy state ends the episode
UNHEALTHY_TERMINATES = "_terminate_when_unhealthy"


def task_terminates(env: VecEnv) -> bool:
    """Whether the task ends an episode on its own (a fall), not only at its time limit.

    Read from gymnasium's MuJoCo convention, ``terminate_when_unhealthy`` (:data:`UNHEALTHY_TERMINATES`); every other
    task counts as one that does not terminate (``SPPO(termination_model=True)`` says otherwise).
    """
    return env.has_attr(UNHEALTHY_TERMINATES) and all(bool(flag) for flag in env.get_attr(UNHEALTHY_TERMINATES))
