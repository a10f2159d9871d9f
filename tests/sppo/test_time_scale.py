"""What SPPO reads from the task: the discount from its time scale (``gamma="auto"``, TD-MPC2's rule from the episode
length) and whether it terminates (``termination_model="auto"``)."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest
from tiny_hyperparams import TINY_SPPO

from sppo_sb3 import SPPO
from sppo_sb3.sppo.time_scale import PAPER_GAMMA, episode_discount


@pytest.mark.parametrize(
    ("length", "gamma"),
    [(500, 0.99), (1000, 0.995), (10_000, 0.995), (100, 0.95), (50, 0.95), (250, 0.98), (None, PAPER_GAMMA)],
)
def test_episode_discount_follows_the_episode_length(length: int | None, gamma: float) -> None:
    assert episode_discount(length) == pytest.approx(gamma)


def test_episode_discount_rejects_a_non_positive_length() -> None:
    with pytest.raises(ValueError, match="positive number of steps"):
        episode_discount(0)


@pytest.mark.parametrize(("env_id", "gamma"), [("SafePointCircle-v0", 0.99), ("sppo_sb3/SafetyHopperVelocity-v1", 0.995)])
def test_auto_gamma_reaches_the_planner_and_the_update(env_id: str, gamma: float) -> None:
    model = SPPO("TOLDPolicy", env_id, gamma="auto", **TINY_SPPO)
    assert model.gamma == pytest.approx(gamma)
    assert model.planner.gamma == model.gamma  # the planner reads the one resolved discount; the update is given it
    assert not hasattr(model.planner_config, "gamma") and not hasattr(model.topo_config, "gamma")


@pytest.mark.parametrize("kwargs", ["planner_kwargs", "topo_kwargs"])
def test_a_discount_in_the_planner_or_update_settings_names_sppos_gamma(kwargs: str) -> None:
    """One source: SPPO's gamma; a second one in the planner's or the update's settings is refused, not merged."""
    with pytest.raises(ValueError, match=rf"remove 'gamma' from {kwargs} and pass SPPO\(\.\.\., gamma=0\.9\)"):
        SPPO("TOLDPolicy", "SafePointCircle-v0", **{**TINY_SPPO, kwargs: {**TINY_SPPO.get(kwargs, {}), "gamma": 0.9}})


def test_auto_gamma_without_a_time_limit_is_the_papers() -> None:
    env = gym.make("SafePointCircle-v0").unwrapped  # no spec's time limit left
    env.spec = None
    assert SPPO("TOLDPolicy", env, gamma="auto", shield=None, **TINY_SPPO).gamma == PAPER_GAMMA


def test_a_number_is_the_discount_as_given() -> None:
    model = SPPO("TOLDPolicy", "sppo_sb3/SafetyHopperVelocity-v1", gamma=0.99, **TINY_SPPO)
    assert model.gamma == model.planner.gamma == 0.99


def test_the_resolved_discount_is_saved(tmp_path: Path) -> None:
    model = SPPO("TOLDPolicy", "sppo_sb3/SafetyHopperVelocity-v1", gamma="auto", **TINY_SPPO)
    model.save(tmp_path / "model")
    loaded = SPPO.load(tmp_path / "model")
    assert loaded.gamma == loaded.planner.gamma == pytest.approx(0.995)


@pytest.mark.parametrize(
    ("env_id", "kwargs", "terminates"),
    [
        ("sppo_sb3/SafetyHopperVelocity-v1", {}, True),
        ("sppo_sb3/SafetyAntVelocity-v1", {}, True),
        ("sppo_sb3/SafetyHopperVelocity-v1", {"terminate_when_unhealthy": False}, False),
        ("sppo_sb3/SafetyHalfCheetahVelocity-v1", {}, False),
        ("SafePointCircle-v0", {}, False),
    ],
)
def test_termination_model_by_default_where_the_task_falls(env_id: str, kwargs: dict, terminates: bool) -> None:
    """The planner stops summing at an imagined fall on the robots that fall, and stays the paper's elsewhere."""
    model = SPPO("TOLDPolicy", gym.make(env_id, **kwargs), shield=None, **TINY_SPPO)
    assert model.termination_model is terminates
    assert (model.policy.model.termination is not None) is terminates


@pytest.mark.parametrize("given", [True, False])
def test_termination_model_as_given(given: bool) -> None:
    model = SPPO("TOLDPolicy", "sppo_sb3/SafetyHopperVelocity-v1", termination_model=given, shield=None, **TINY_SPPO)
    assert model.termination_model is given and (model.policy.model.termination is not None) is given


def test_termination_model_rejects_other_values() -> None:
    with pytest.raises(ValueError, match="termination_model is True, False or"):
        SPPO("TOLDPolicy", "SafePointCircle-v0", termination_model="yes", **TINY_SPPO)  # type: ignore[arg-type]


def test_the_resolved_termination_model_is_saved(tmp_path: Path) -> None:
    SPPO("TOLDPolicy", "sppo_sb3/SafetyHopperVelocity-v1", shield=None, **TINY_SPPO).save(tmp_path / "model")
    standing = gym.make("sppo_sb3/SafetyHopperVelocity-v1", terminate_when_unhealthy=False)  # "auto" would say False
    loaded = SPPO.load(tmp_path / "model", env=standing, custom_objects={"shield": None})
    assert loaded.termination_model is True and loaded.policy.model.termination is not None
