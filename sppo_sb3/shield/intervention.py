"""What the learner is told when the shield intervenes: one vocabulary for SPPO, SAILR and :class:`ShieldWrapper`.

When the shield rejects a proposal ``a`` in state ``s`` (eq. 12), the env executes the backup action ``ζ(s)``. What the
*learner* then learns from is a separate choice, named by ``on_intervention``; a value means the same wherever it
applies:

- ``"continue"``: the learner's step is ``(s, a, r - penalty, s')``, the proposal with the executed step's reward
  less the penalty and the real next state; the episode goes on. SPPO, ``ShieldWrapper``.
- ``"terminate"``: the learner's step is eq. 7's absorbing transition ``(s, a, R̃ = -penalty, terminal)`` into ``s†``,
  and the learner sees nothing more of the episode: the paper's ``M̃``. SPPO, ``ShieldWrapper``.
- ``"restart"``: as ``"terminate"``, and the learner's next episode starts at the real next state ``s'``. SPPO.
- ``"takeover"``: as ``"terminate"``, and ``ζ`` executes the rest of the episode, whose steps are masked out of
  learning (SAILR's authors' code). SAILR, ``ShieldWrapper``.
- ``"none"``: the learner's step is the executed one, ``(s, ζ(s), r, s')``: nothing is relabelled. SPPO.

``ShieldWrapper`` sits between an env and any learner, so it can only say what the gym API can: under ``"terminate"`` it
ends the env's episode; under ``"takeover"`` it reports the executed steps as they are, the first intervention and the
backup's later steps flagged in ``info["shield_intervened"]``, and leaves the relabel and the masking to the learner
(SAILR does); ``"restart"`` and ``"none"`` need a learner that keeps its own relabel (SPPO's replay buffer).

**The penalty** is one non-negative amount everywhere: what an intervention costs the learner. SPPO and
``ShieldWrapper`` subtract it from the step's reward (``R̃ = -penalty`` under ``"terminate"`` and ``"restart"``,
``r - penalty`` under ``"continue"``); SAILR gives its absorbing step reward 0 and weights its intervention cost by it
(``κ``, in ``(A_R - κ·A_C) / (1 + κ)``).
"""

from __future__ import annotations

from typing import Literal

OnIntervention = Literal["continue", "terminate", "restart", "takeover", "none"]
ON_INTERVENTION: tuple[OnIntervention, ...] = ("continue", "terminate", "restart", "takeover", "none")
"""Every value of ``on_intervention``, in the order of the module's table."""

#: the values that end the learner's episode at the intervention: the intervened step is an absorbing terminal
ABSORBING: frozenset[OnIntervention] = frozenset({"terminate", "restart", "takeover"})


def check_on_intervention(value: str, supported: tuple[OnIntervention, ...], owner: str) -> None:
    """Reject an ``on_intervention`` that ``owner`` does not support, with the values it does.

    :param value: the given value.
    :param supported: the values ``owner`` implements.
    :param owner: who takes it (``"SPPO"``, ``"SAILR"``, ``"ShieldWrapper"``), for the message.
    :raises ValueError: an unknown value, or one ``owner`` cannot implement.
    """
    if value in supported:
        return
    allowed = ", ".join(map(repr, supported))
    if value not in ON_INTERVENTION:
        raise ValueError(f"on_intervention={value!r} is not a value of sppo_sb3.shield.intervention; {owner} takes {allowed}.")
    raise ValueError(
        f"{owner} cannot implement on_intervention={value!r} (see sppo_sb3.shield.intervention for what each value "
        f"means and who implements it); it takes {allowed}."
    )


#: what a penalty means to SPPO and ShieldWrapper, in the message of :func:`check_penalty`
REWARD_PENALTY_HINT = "The absorbing step's reward is R̃ = -penalty (eq. 7): for R̃ = -1 pass penalty=1.0."


def check_penalty(penalty: float, owner: str, hint: str = REWARD_PENALTY_HINT) -> None:
    """Reject a negative penalty: the penalty is the non-negative amount an intervention costs the learner.

    :param penalty: the given penalty.
    :param owner: who takes it, for the message.
    :param hint: what the penalty means to ``owner``, appended to the message (default: the reward ``R̃ = -penalty``).
    :raises ValueError: ``penalty < 0`` (or NaN).
    """
    if not penalty >= 0.0:
        raise ValueError(
            f"{owner}'s penalty is what an intervention costs the learner, a number >= 0 (see "
            f"sppo_sb3.shield.intervention), got {penalty}. {hint}"
        )
