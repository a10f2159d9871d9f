"""One vocabulary for what the learner is told of an intervention: SPPO, SAILR and ShieldWrapper take the same name,
``on_intervention``, accept the values they implement and refuse the others with the same message."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import pytest
from tiny_hyperparams import TINY_SAILR, TINY_SPPO

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3 import SAILR, SPPO
from sppo_sb3.shield import ShieldWrapper
from sppo_sb3.shield.intervention import ABSORBING, ON_INTERVENTION

POINT = "SafePointCircle-v0"

#: each owner, built with a value of on_intervention (the wrapper with penalty 0, which every mode accepts)
OWNERS: dict[str, Callable[[str], Any]] = {
    "SPPO": lambda value: SPPO("TOLDPolicy", POINT, on_intervention=value, **TINY_SPPO),
    "SAILR": lambda value: SAILR("MlpPolicy", POINT, on_intervention=value, **TINY_SAILR),
    "ShieldWrapper": lambda value: ShieldWrapper(gym.make(POINT), "auto", on_intervention=value),
}
#: what each owner implements, as its documentation says
IMPLEMENTS = {
    "SPPO": {"continue", "terminate", "restart", "none"},
    "SAILR": {"takeover"},
    "ShieldWrapper": {"continue", "terminate", "takeover"},
}


@pytest.mark.parametrize("owner", sorted(OWNERS))
@pytest.mark.parametrize("value", ON_INTERVENTION)
def test_every_owner_takes_the_same_name_and_refuses_what_it_cannot_implement(owner: str, value: str) -> None:
    if value in IMPLEMENTS[owner]:
        assert OWNERS[owner](value).on_intervention == value
    else:
        with pytest.raises(ValueError, match=rf"{owner} cannot implement on_intervention='{value}'"):
            OWNERS[owner](value)


def test_every_value_has_an_owner_and_the_absorbing_ones_end_the_learners_episode() -> None:
    assert set().union(*IMPLEMENTS.values()) == set(ON_INTERVENTION)
    assert {"terminate", "restart", "takeover"} == ABSORBING


@pytest.mark.parametrize("owner", sorted(OWNERS))
def test_a_value_outside_the_vocabulary_is_refused_by_every_owner(owner: str) -> None:
    for old_name in ("execute", "absorb"):  # ShieldWrapper's former names, now "continue" and "terminate"
        with pytest.raises(ValueError, match=rf"on_intervention='{old_name}' is not a value of sppo_sb3.shield.intervention"):
            OWNERS[owner](old_name)


@pytest.mark.parametrize(
    "build",
    [
        lambda: SPPO("TOLDPolicy", POINT, penalty=-1.0, **TINY_SPPO),
        lambda: SAILR("MlpPolicy", POINT, penalty=-1.0, **TINY_SAILR),
        lambda: ShieldWrapper(gym.make(POINT), "auto", on_intervention="terminate", penalty=-1.0),
    ],
)
def test_one_sign_convention_a_penalty_is_never_negative(build: Callable[[], Any]) -> None:
    with pytest.raises(ValueError, match="penalty is what an intervention costs the learner, a number >= 0"):
        build()
