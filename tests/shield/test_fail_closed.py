"""The shield fails closed, speaks up, checks the rules it is given, and tells off-policy learners the truth.

Each test names the failure it covers: non-finite values execute the backup, a rule that cannot be checked raises,
and an off-policy learner behind the wrapper sees what was executed.
"""

from __future__ import annotations

import sys
import textwrap
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.pendulum import PendulumEnv
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from tiny_hyperparams import TINY_SAILR, TINY_SPPO

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3 import SPPO
from sppo_sb3.common.keys import ABSORBED_KEY, ENV_REWARD_KEY, EXECUTED_ACTION_KEY, PROPOSED_ACTION_KEY
from sppo_sb3.sailr import SAILR
from sppo_sb3.shield import (
    SHIELDING_RULES,
    PointCircleShieldingRule,
    ShieldDecision,
    ShieldFailure,
    ShieldingRule,
    ShieldWrapper,
    in_shielding_set,
    register_shielding_rule,
)
from sppo_sb3.shield.persistence import ShieldRuleLoadError

SPPO_TINY = {**TINY_SPPO, "seed": 0}
BRAKE = PointCircleShieldingRule()
INTERVENED = "shield_intervened"


class NaNValueRule(PointCircleShieldingRule):
    """The Point rule whose ``Q̄`` is NaN wherever ``x > nan_beyond``: a broken model of part of the state space."""

    def __init__(self, nan_beyond: float = -np.inf) -> None:
        super().__init__()
        self.nan_beyond = nan_beyond

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        q = super().cost_value(obs, actions)
        return np.where(obs[:, 0] > self.nan_beyond, np.nan, q)


class NaNOffBackupRule(PointCircleShieldingRule):
    """The Point rule whose ``Q̄`` is NaN for every action but the backup's (finite where the rule is probed)."""

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        at_backup = np.all(actions == self.backup_action(obs), axis=1)
        return np.where(at_backup, super().cost_value(obs, actions), np.nan)


class ConstantBackupRule(PointCircleShieldingRule):
    """Backup: a fixed action (finite even where the observation is not)."""

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 2))


class OptimisticOverride(PointCircleShieldingRule):
    """A rule that overrides ``shield`` and lets a NaN advantage through (``NaN > η`` is False)."""

    def shield(self, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        adv = self.advantage(obs, actions)
        intervened = adv > self.eta
        return ShieldDecision(np.where(intervened[:, None], self.backup_action(obs), actions), intervened, adv)


class NaNOverride(OptimisticOverride, NaNValueRule):
    pass


# ------------------------------------------------------------------------- 1. fail closed: the rule
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_in_shielding_set_counts_non_finite_advantages_as_unsafe(bad: float) -> None:
    np.testing.assert_array_equal(in_shielding_set(np.array([bad, 0.0, 1.0]), 0.0), [True, False, True])


def test_nan_cost_value_executes_the_backup() -> None:
    obs = np.array([[-1.0, 0.0, 0.5, 0.0], [1.0, 0.0, 0.5, 0.0]])  # Q̄ is NaN for the second state only
    actions = np.array([[0.5, 0.0], [0.5, 0.0]])
    decision = NaNValueRule(nan_beyond=0.0).shield(obs, actions)
    np.testing.assert_array_equal(decision.intervened, [False, True])
    np.testing.assert_array_equal(decision.actions[0], actions[0])
    np.testing.assert_array_equal(decision.actions[1], BRAKE.backup_action(obs[1:])[0])


def test_nan_proposal_executes_the_backup() -> None:
    obs = np.array([[0.0, 0.0, 0.5, 0.0]])
    decision = BRAKE.shield(obs, np.array([[np.nan, 0.0]]))
    assert decision.intervened[0]
    np.testing.assert_array_equal(decision.actions, BRAKE.backup_action(obs))


def test_nan_observation_executes_a_finite_backup() -> None:
    decision = ConstantBackupRule().shield(np.array([[np.nan, 0.0, 0.0, 0.0]]), np.array([[1.0, 1.0]]))
    assert decision.intervened[0]
    np.testing.assert_array_equal(decision.actions, [[0.0, 0.0]])


def test_nan_observation_without_a_finite_backup_raises() -> None:
    with pytest.raises(ShieldFailure, match="backup action is not finite"):
        BRAKE.shield(np.array([[0.0, 0.0, np.nan, 0.0]]), np.array([[1.0, 1.0]]))


def test_an_overriding_shield_also_fails_closed() -> None:
    obs = np.array([[1.0, 0.0, 0.5, 0.0]])
    decision = NaNOverride(nan_beyond=0.0).shield(obs, np.array([[0.5, 0.0]]))
    assert decision.intervened[0]
    np.testing.assert_array_equal(decision.actions, BRAKE.backup_action(obs))


# ------------------------------------------------------------------------- 1. fail closed: the wrapper
class NaNObservation(gym.ObservationWrapper):
    """Observations turn NaN after ``after`` steps; records the actions the env executes."""

    def __init__(self, env: gym.Env, after: int) -> None:
        super().__init__(env)
        self.after, self.steps, self.executed = after, 0, []

    def reset(self, **kwargs: Any) -> Any:
        self.steps = 0
        return super().reset(**kwargs)

    def step(self, action: np.ndarray) -> Any:
        self.executed.append(np.array(action))
        self.steps += 1
        return super().step(action)

    def observation(self, obs: np.ndarray) -> np.ndarray:
        return np.full_like(obs, np.nan) if self.steps > self.after else obs


def test_wrapper_executes_the_backup_on_a_nan_observation() -> None:
    inner = NaNObservation(gym.make("SafePointCircle-v0"), after=1)
    env = ShieldWrapper(inner, ConstantBackupRule())
    env.reset(seed=0)
    env.step(np.ones(2, dtype=np.float32))
    env.step(np.ones(2, dtype=np.float32))  # decided on the NaN observation
    _, _, _, _, info = env.step(np.ones(2, dtype=np.float32))
    assert info[INTERVENED] and np.isnan(info["shield_advantage"])
    np.testing.assert_array_equal(inner.executed[-1], [0.0, 0.0])
    np.testing.assert_array_equal(info[EXECUTED_ACTION_KEY], [0.0, 0.0])


def test_wrapper_raises_where_nothing_safe_can_be_computed() -> None:
    env = ShieldWrapper(NaNObservation(gym.make("SafePointCircle-v0"), after=-1), BRAKE)
    with pytest.raises(ValueError, match="NaN/inf"):  # the probe at the first reset already sees it
        env.reset(seed=0)
    env = ShieldWrapper(NaNObservation(gym.make("SafePointCircle-v0"), after=0), BRAKE)
    env.reset(seed=0)
    env.step(np.ones(2, dtype=np.float32))
    with pytest.raises(ShieldFailure):
        env.step(np.ones(2, dtype=np.float32))


# ------------------------------------------------------------------------- 1. fail closed: SPPO and SAILR
def test_sppo_executes_the_backup_where_q_is_nan() -> None:
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", shield=NaNOffBackupRule(), **SPPO_TINY)
    model.learn(40)  # warm-up: uniform proposals, every one with a NaN Q̄
    assert model.safety_metrics.interventions == 40
    obs = np.array([0.5, 0.5, 0.3, 0.0], dtype=np.float32)
    action, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(action, BRAKE.backup_action(obs[None].astype(np.float64))[0], rtol=1e-6)


def test_sppo_predict_raises_on_a_nan_observation() -> None:
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", **SPPO_TINY)
    with pytest.raises(ShieldFailure):
        model.predict(np.array([0.0, 0.0, np.nan, 0.0], dtype=np.float32), deterministic=True)  # the brake reads v


class RecordInfos(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.infos: list[dict[str, Any]] = []

    def _on_step(self) -> bool:
        self.infos.extend(self.locals["infos"])
        return True


def test_sailr_executes_the_backup_where_q_is_nan() -> None:
    model = SAILR("MlpPolicy", "SafePointCircle-v0", shield=NaNOffBackupRule(), seed=0, **TINY_SAILR)
    callback = RecordInfos()
    model.learn(64, callback=callback)
    assert all(info[INTERVENED] for info in callback.infos)
    for info in callback.infos:
        assert not np.array_equal(info[EXECUTED_ACTION_KEY], info[PROPOSED_ACTION_KEY])


# ------------------------------------------------------------------------- 2. no silent unshielded run
def test_sppo_auto_without_a_rule_warns() -> None:
    with pytest.warns(UserWarning, match="nothing is shielded.*registered for env id 'Pendulum-v1'"):
        model = SPPO("TOLDPolicy", "Pendulum-v1", **SPPO_TINY)
    assert model.shield_rule is None


def test_sppo_auto_on_an_env_without_spec_warns() -> None:
    with pytest.warns(UserWarning, match="nothing is shielded.*no spec"):
        SPPO("TOLDPolicy", PendulumEnv(), **SPPO_TINY)


def test_sppo_shield_none_is_silent() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SPPO("TOLDPolicy", "Pendulum-v1", shield=None, compile=False, **SPPO_TINY)


def test_sailr_auto_on_an_env_without_spec_raises() -> None:
    with pytest.raises(ValueError, match="no spec"):
        SAILR("MlpPolicy", PendulumEnv(), **TINY_SAILR)


@pytest.fixture
def unimportable_rule(tmp_path: Path) -> Any:
    """A rule whose class lives in a module that is importable now and gone after the test's ``forget()``."""
    module = tmp_path / "my_point_rule.py"
    module.write_text(
        textwrap.dedent(
            """
            from sppo_sb3.shield import PointCircleShieldingRule

            class MyPointRule(PointCircleShieldingRule):
                pass
            """
        )
    )
    sys.path.insert(0, str(tmp_path))
    import my_point_rule  # type: ignore[import-not-found]

    def forget() -> None:
        sys.path.remove(str(tmp_path))
        del sys.modules["my_point_rule"]

    yield my_point_rule.MyPointRule(), forget
    if "my_point_rule" in sys.modules:
        forget()


@pytest.mark.parametrize("algo", ["sppo", "sailr"])
def test_load_with_a_rule_that_cannot_be_rebuilt(algo: str, unimportable_rule: Any, tmp_path: Path) -> None:
    rule, forget = unimportable_rule
    if algo == "sppo":
        cls: Any = SPPO
        model = SPPO("TOLDPolicy", "SafePointCircle-v0", shield=rule, **SPPO_TINY)
    else:
        cls = SAILR
        model = SAILR("MlpPolicy", "SafePointCircle-v0", shield=rule, **TINY_SAILR)
    model.save(tmp_path / "model.zip")
    forget()
    with pytest.raises(ShieldRuleLoadError, match=r"custom_objects=\{'shield_rule': YourRule\(\)\}"):
        cls.load(tmp_path / "model.zip")
    mine = PointCircleShieldingRule()
    assert cls.load(tmp_path / "model.zip", custom_objects={"shield_rule": mine}).shield_rule is mine
    assert cls.load(tmp_path / "model.zip", custom_objects={"shield": None}).shield_rule is None
    assert cls.load(tmp_path / "model.zip", shield=None).shield_rule is None
    with pytest.raises(ValueError, match="'shield': None"):
        cls.load(tmp_path / "model.zip", custom_objects={"shield_rule": None})


def test_load_rebuilds_an_importable_rule(tmp_path: Path) -> None:
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", shield=PointCircleShieldingRule(eta=0.3), **SPPO_TINY)
    model.save(tmp_path / "model.zip")
    with open(tmp_path / "model.zip", "rb") as file:
        loaded = SPPO.load(file)
    assert isinstance(loaded.shield_rule, PointCircleShieldingRule) and loaded.shield_rule.eta == 0.3


# ------------------------------------------------------------------------- 3. checked rules
class ColumnValueRule(PointCircleShieldingRule):
    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return super().cost_value(obs, actions)[:, None]


class FlatBackupRule(ShieldingRule):
    """A one-dimensional task whose backup forgot the action axis."""

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(len(obs))

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.zeros(len(obs))


class ListValueRule(PointCircleShieldingRule):
    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> Any:
        return super().cost_value(obs, actions).tolist()


class NaNEverywhereRule(PointCircleShieldingRule):
    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.full(len(obs), np.nan)


def test_cost_value_of_shape_b1_names_the_fix() -> None:
    with pytest.raises(ValueError, match=r"returned shape \(4, 1\).*return shape \(4,\).*drop the last axis"):
        ShieldWrapper(gym.make("SafePointCircle-v0"), ColumnValueRule()).reset(seed=0)
    with pytest.raises(ValueError, match="drop the last axis"):
        ColumnValueRule().shield(np.zeros((3, 4)), np.ones((3, 2)))


def test_backup_of_shape_b_names_the_fix() -> None:
    with pytest.raises(ValueError, match=r"returned shape \(2,\).*return shape \(2, 1\).*add the action axis"):
        ShieldWrapper(gym.make("Pendulum-v1"), FlatBackupRule()).reset(seed=0)


def test_a_list_is_not_an_array() -> None:
    with pytest.raises(TypeError, match="returned a list; return a numpy array"):
        ListValueRule().shield(np.zeros((2, 4)), np.ones((2, 2)))


def test_a_nan_value_at_the_first_reset_is_reported() -> None:
    with pytest.raises(ValueError, match="cost_value returned NaN/inf"):
        ShieldWrapper(gym.make("SafePointCircle-v0"), NaNEverywhereRule()).reset(seed=0)
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", shield=NaNEverywhereRule(), **SPPO_TINY)
    with pytest.raises(ValueError, match="cost_value returned NaN/inf"):
        model.learn(10)


def test_register_rejects_an_instance_and_accepts_a_class_or_factory() -> None:
    with pytest.raises(TypeError, match=r"instance; pass the class or a factory"):
        register_shielding_rule("Failsafe-v0", PointCircleShieldingRule())
    try:
        register_shielding_rule("Failsafe-v0", PointCircleShieldingRule)
        register_shielding_rule("Failsafe-v1", lambda: PointCircleShieldingRule(eta=0.5))
        assert SHIELDING_RULES["Failsafe-v1"]().eta == 0.5
    finally:
        SHIELDING_RULES.pop("Failsafe-v0", None)
        SHIELDING_RULES.pop("Failsafe-v1", None)


# ------------------------------------------------------------------------- 4. the wrapper tells the learner the truth
class AlwaysShield(PointCircleShieldingRule):
    """``Q̄(s, a) = |a - ζ(s)|``: every action but the backup's is shielded."""

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.abs(actions - self.backup_action(obs)).sum(axis=1)


def test_wrapper_info_reports_the_executed_action() -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), AlwaysShield())
    obs, _ = env.reset(seed=0)
    _, _, terminated, _, info = env.step(np.ones(2, dtype=np.float32))
    assert info[INTERVENED] and not info[ABSORBED_KEY] and not terminated
    np.testing.assert_array_equal(info[PROPOSED_ACTION_KEY], [1.0, 1.0])
    np.testing.assert_allclose(info[EXECUTED_ACTION_KEY], BRAKE.backup_action(obs[None].astype(np.float64))[0])


def test_terminate_turns_an_intervention_into_the_absorbing_terminal() -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), AlwaysShield(), on_intervention="terminate", penalty=3.0)
    env.reset(seed=0)
    _, reward, terminated, truncated, info = env.step(np.ones(2, dtype=np.float32))
    assert (reward, terminated, truncated) == (-3.0, True, False)
    assert info[ABSORBED_KEY] and ENV_REWARD_KEY in info


def test_continue_subtracts_the_penalty_from_intervened_steps_only() -> None:
    """``"continue"``: the learner's step is the proposal's with the executed reward less the penalty; the default
    penalty 0 tells it nothing (the shielded env)."""
    told, silent = (ShieldWrapper(gym.make("SafePointCircle-v0"), AlwaysShield(), penalty=p) for p in (0.25, 0.0))
    plain = gym.make("SafePointCircle-v0")
    for env in (told, silent, plain):
        env.reset(seed=0)
    for _ in range(5):
        _, told_reward, told_done, _, info = told.step(np.ones(2, dtype=np.float32))
        _, silent_reward, _, _, _ = silent.step(np.ones(2, dtype=np.float32))
        _, reward, *_ = plain.step(np.asarray(info[EXECUTED_ACTION_KEY], dtype=np.float32))
        assert info[INTERVENED] and not told_done
        assert told_reward == pytest.approx(reward - 0.25) and info[ENV_REWARD_KEY] == reward
        assert silent_reward == reward
    accepted = ShieldWrapper(gym.make("SafePointCircle-v0"), PointCircleShieldingRule(), penalty=0.25)
    accepted.reset(seed=0)
    _, reward, _, _, info = accepted.step(np.zeros(2, dtype=np.float32))
    assert not info[INTERVENED] and ENV_REWARD_KEY not in info  # an accepted step keeps its reward


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"on_intervention": "absorb"}, "not a value of sppo_sb3.shield.intervention; ShieldWrapper takes"),
        ({"on_intervention": "restart"}, "ShieldWrapper cannot implement on_intervention='restart'"),
        ({"on_intervention": "none"}, "ShieldWrapper cannot implement on_intervention='none'"),
        ({"penalty": -1.0}, "a number >= 0.*for R̃ = -1 pass penalty=1.0"),
        ({"on_intervention": "takeover", "penalty": 1.0}, "pass penalty=0.0"),
    ],
)
def test_wrapper_rejects_what_it_cannot_implement(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ShieldWrapper(gym.make("SafePointCircle-v0"), "auto", **kwargs)


def test_sac_stores_the_proposal_in_the_absorbing_mdp() -> None:
    env = ShieldWrapper(gym.make("SafePointCircle-v0"), AlwaysShield(), on_intervention="terminate", penalty=1.0)
    model = SAC("MlpPolicy", env, learning_starts=1000, buffer_size=1000, seed=0)
    callback = RecordInfos()
    model.learn(50, callback=callback)
    stored = model.replay_buffer.actions[:50, 0]
    proposed = np.array([info[PROPOSED_ACTION_KEY] for info in callback.infos])
    np.testing.assert_allclose(stored, proposed, rtol=1e-6)  # the Point task's actions are already in [-1, 1]
    np.testing.assert_array_equal(model.replay_buffer.rewards[:50, 0], -1.0)
    np.testing.assert_array_equal(model.replay_buffer.dones[:50, 0], 1.0)
