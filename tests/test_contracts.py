"""SB3's contracts, kept by every algorithm of the package: the one parametrised place, in sb3-contrib's manner.

Every test runs over :data:`MODEL_LIST` (the six algorithms, and SPPO and SAILR behind a shield) on a small
identity task with a cost, :class:`IdentityCostEnv`, with tiny networks and budgets. What is tested is what
Stable-Baselines3's and sb3-contrib's own suites test for their algorithms (``tests/test_save_load.py``,
``tests/test_spaces.py``, ``tests/test_callbacks.py``, ``tests/test_vec_normalize.py``): save/load, policy
save/load, ``set_env``, resuming, seeding, ``predict``, evaluation, callbacks, ``VecNormalize`` and the spaces. The
spaces table of each algorithm's page in ``docs/modules/`` is :data:`UNSUPPORTED` below.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecNormalize
from tiny_hyperparams import QUICK_CSC, TINY_ON_POLICY, TINY_SACLAG, TINY_SPPO

from sppo_sb3 import CPO, CSC, PDO, SAILR, SPPO, SACLag
from sppo_sb3.common.monitor import CostEvalCallback
from sppo_sb3.shield import ShieldingRule, ShieldWrapper

pytestmark = pytest.mark.filterwarnings("ignore:SAILR got shield=None")  # plain SAILR is unshielded on purpose here

EPISODE_STEPS = 16
STEPS = 64  # two rollouts of the on-policy algorithms; SPPO's and SACLag's warm-up, then updates


class IdentityCostEnv(gym.Env):
    """SB3's identity task with a cost: the observation is a target action, the reward how close the action came.

    The observation is a target in ``[-1, 1]^A`` (``A`` the number of action entries); the reward is minus the mean
    squared distance between the action, rescaled to ``[-1, 1]``, and the target; ``info["cost"]`` is 1.0 where an
    entry of the rescaled action leaves ``[-0.9, 0.9]``. Every action is checked against the action space, so an
    algorithm that sends a wrong shape or leaves the bounds fails here rather than being broadcast silently.

    :param action_space: the action space (any Box, or a discrete space for the space tests).
    :param observation_space: overrides the target observation (for the space tests: rewards are then 0).
    :param max_episode_steps: episode length (truncation).
    """

    def __init__(
        self,
        action_space: spaces.Space | None = None,
        observation_space: spaces.Space | None = None,
        max_episode_steps: int = EPISODE_STEPS,
    ) -> None:
        self.action_space = action_space if action_space is not None else spaces.Box(-1, 1, (3,), np.float32)
        self.n_targets = int(np.prod(self.action_space.shape)) if isinstance(self.action_space, spaces.Box) else 1
        target_space = spaces.Box(-1, 1, (self.n_targets,), np.float32)
        self.observation_space = observation_space if observation_space is not None else target_space
        self.max_episode_steps = max_episode_steps
        self._steps = 0
        self._target = np.zeros(self.n_targets, dtype=np.float32)

    def _observe(self) -> Any:
        if isinstance(self.observation_space, spaces.Box) and self.observation_space.shape == (self.n_targets,):
            self._target = self.np_random.uniform(-1, 1, self.n_targets).astype(np.float32)
            return self._target.astype(self.observation_space.dtype)
        return self.observation_space.sample()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self.observation_space.seed(seed)
        self._steps = 0
        return self._observe(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        action = np.asarray(action)
        if isinstance(self.action_space, spaces.Box):
            if action.shape != self.action_space.shape:
                raise ValueError(f"IdentityCostEnv got an action of shape {action.shape}, expected {self.action_space.shape}")
            low, high = self.action_space.low, self.action_space.high
            if np.any(action < low - 1e-5) or np.any(action > high + 1e-5):
                raise ValueError(f"IdentityCostEnv got an action outside the action space: {action}")
            scaled = (2.0 * (action - low) / (high - low) - 1.0).reshape(-1)
        elif not self.action_space.contains(action):
            raise ValueError(f"IdentityCostEnv got an action outside {self.action_space}: {action!r}")
        else:
            scaled = np.zeros(self.n_targets)
        reward = -float(np.mean((scaled - self._target) ** 2))
        cost = float(np.any(np.abs(scaled) > 0.9))
        self._steps += 1
        return self._observe(), reward, False, self._steps >= self.max_episode_steps, {"cost": cost}


class KeepCentreRule(ShieldingRule):
    """A shielding rule for :class:`IdentityCostEnv`: the backup acts at the centre of the action space.

    ``Q̄(s, a)`` is how far the rescaled action's largest entry goes beyond 0.8 (0 inside), so the shield replaces
    every proposal with an entry beyond 0.8 by the centre, and no executed action ever costs (the env's cost starts
    at 0.9).

    :param action_space: the env's action space (a Box).
    """

    def __init__(self, action_space: spaces.Box) -> None:
        super().__init__(eta=0.0)
        self.low = np.asarray(action_space.low, dtype=np.float64).reshape(-1)
        self.high = np.asarray(action_space.high, dtype=np.float64).reshape(-1)

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.tile((self.low + self.high) / 2.0, (len(obs), 1))

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        scaled = 2.0 * (actions - self.low) / (self.high - self.low) - 1.0
        return np.maximum(0.0, np.abs(scaled).max(axis=1) - 0.8)


def shield_for(env: gym.Env | VecEnv) -> ShieldingRule:
    """:class:`KeepCentreRule` of ``env``'s action space (a unit Box where the space is not a Box)."""
    space = env.action_space
    return KeepCentreRule(space if isinstance(space, spaces.Box) else spaces.Box(-1, 1, (1,), np.float32))


# the tiny settings (tests/tiny_hyperparams.py), shortened to this file's budget of STEPS
ON_POLICY = {**TINY_ON_POLICY, "n_steps": 32}
SHORT_SPPO = {
    **TINY_SPPO,
    "learning_starts": 24,
    "batch_size": 8,
    "horizon": 2,
    "buffer_size": 2_000,
    "planner_kwargs": {**TINY_SPPO["planner_kwargs"], "num_samples": 12},
}
SHORT_CSC = {**QUICK_CSC, "n_steps": 32, "n_cost_baseline_samples": 2}
SHORT_SACLAG = {**TINY_SACLAG, "batch_size": 8}


@dataclass(frozen=True)
class Algo:
    """One entry of :data:`MODEL_LIST`: an algorithm with tiny settings, shielded by :class:`KeepCentreRule` or not.

    :param name: the test id.
    :param cls: the algorithm class.
    :param kwargs: tiny settings.
    :param shielded: pass a :class:`KeepCentreRule` as ``shield`` (``shield=None`` for SPPO and SAILR otherwise).
    """

    name: str
    cls: type[BaseAlgorithm]
    kwargs: dict[str, Any] = field(default_factory=dict)
    shielded: bool = False

    @property
    def has_shield_argument(self) -> bool:
        return self.cls in (SPPO, SAILR)

    def make(self, env: gym.Env | VecEnv, **overrides: Any) -> BaseAlgorithm:
        """The algorithm on ``env`` with the tiny settings, ``seed=0`` and ``overrides``."""
        kwargs: dict[str, Any] = {"seed": 0, **copy.deepcopy(self.kwargs), **overrides}
        if self.has_shield_argument:
            kwargs.setdefault("shield", shield_for(env) if self.shielded else None)
        return self.cls("MlpPolicy", env, **kwargs)


MODEL_LIST = [
    Algo("SPPO", SPPO, SHORT_SPPO),
    Algo("PDO", PDO, {**ON_POLICY, "n_epochs": 1}),
    Algo("CPO", CPO, {**ON_POLICY, "n_critic_updates": 1}),
    Algo("SAILR", SAILR, {**ON_POLICY, "n_epochs": 1}),
    Algo("CSC", CSC, SHORT_CSC),
    Algo("SACLag", SACLag, SHORT_SACLAG),
    Algo("SPPO-shield", SPPO, SHORT_SPPO, shielded=True),
    Algo("SAILR-shield", SAILR, {**ON_POLICY, "n_epochs": 1}, shielded=True),
]
ALGOS = pytest.mark.parametrize("algo", MODEL_LIST, ids=lambda algo: algo.name)


def vec_env(n_envs: int = 1, seed: int = 0, **env_kwargs: Any) -> DummyVecEnv:
    """``n_envs`` :class:`IdentityCostEnv` in ``Monitor`` in a ``DummyVecEnv``, seeded."""
    env = DummyVecEnv([lambda: Monitor(IdentityCostEnv(**env_kwargs)) for _ in range(n_envs)])
    env.seed(seed)
    return env


def observations(n: int = 6, n_targets: int = 3) -> np.ndarray:
    """A fixed batch of observations of :class:`IdentityCostEnv`."""
    return np.random.default_rng(42).uniform(-1, 1, (n, n_targets)).astype(np.float32)


def deterministic_actions(model: BaseAlgorithm, obs: np.ndarray) -> np.ndarray:
    return model.predict(obs, deterministic=True)[0]


def assert_same_parameters(expected: dict[str, Any], got: dict[str, Any]) -> None:
    """The networks' parameters of two ``get_parameters()`` are exactly equal (optimizer states are not compared)."""
    assert expected.keys() == got.keys()
    for name, params in expected.items():
        if "optim" in name:
            continue
        assert params.keys() == got[name].keys(), name
        for key, value in params.items():
            assert th.equal(value, got[name][key]), f"{name}.{key} differs"


def check_safety_metrics(model: BaseAlgorithm, shielded: bool) -> None:
    """The safety metrics counted every step; behind the shield, no step cost."""
    metrics = model.safety_metrics  # type: ignore[attr-defined]
    assert metrics.steps == model.num_timesteps
    if shielded:
        assert metrics.violations == 0 and metrics.interventions > 0


# ------------------------------------------------------------------------------------------------ save and load
def randomised(params: dict[str, Any]) -> dict[str, Any]:
    """sb3-contrib's test: every network tensor but the last of each object drawn at random (optimizers kept)."""

    def rand_like(tensor: th.Tensor) -> th.Tensor:
        return th.rand_like(tensor) if th.is_floating_point(tensor) else th.randint_like(tensor, high=10)

    return {
        name: values if "optim" in name else OrderedDict((key, rand_like(v)) for key, v in list(values.items())[:-1])
        for name, values in params.items()
    }


@ALGOS
def test_save_load(tmp_path, algo: Algo) -> None:
    """``set_parameters`` as sb3-contrib tests it, then exact parameters and the same deterministic predictions
    after ``load``; the loaded model learns on. Loading never writes into the env's action space."""
    env = vec_env()
    low, high = env.action_space.low.copy(), env.action_space.high.copy()
    model = algo.make(env).learn(STEPS)
    check_safety_metrics(model, algo.shielded)
    original = copy.deepcopy(model.get_parameters())
    with pytest.raises(ValueError):
        model.set_parameters({**original, "I_should_not_be_a_valid_object": "and_I_am_an_invalid_tensor"})
    with pytest.raises(ValueError):
        model.set_parameters(dict(list(original.items())[:-1]), exact_match=True)
    model.set_parameters(randomised(original), exact_match=False)
    params = copy.deepcopy(model.get_parameters())
    for name, values in original.items():
        if "optim" in name:
            continue
        *changed, last = values
        assert th.equal(values[last], params[name][last]), f"{name}.{last} was not in the new parameters"
        assert not any(th.equal(values[key], params[name][key]) for key in changed), f"{name} did not change"
    obs = observations()
    expected = deterministic_actions(model, obs)
    np.testing.assert_array_equal(deterministic_actions(model, obs), expected)  # they repeat
    model.save(tmp_path / "model.zip")

    loaded = algo.cls.load(tmp_path / "model.zip", env=env)
    assert_same_parameters(params, loaded.get_parameters())
    np.testing.assert_array_equal(deterministic_actions(loaded, obs), expected)
    np.testing.assert_equal(loaded.safety_metrics.summary(), model.safety_metrics.summary())  # type: ignore[attr-defined]
    np.testing.assert_array_equal(env.action_space.low, low)
    np.testing.assert_array_equal(env.action_space.high, high)
    loaded.learn(32, reset_num_timesteps=False)
    assert loaded.num_timesteps == model.num_timesteps + 32


@ALGOS
def test_save_load_policy(tmp_path, algo: Algo) -> None:
    """``model.policy.save`` / ``PolicyClass.load``: the same parameters and deterministic predictions."""
    model = algo.make(vec_env())
    policy = model.policy
    obs = observations()
    expected = policy.predict(obs, deterministic=True)[0]
    policy.save(tmp_path / "policy.pth")
    loaded = type(policy).load(tmp_path / "policy.pth")
    for (name, value), got in zip(policy.state_dict().items(), loaded.state_dict().values()):
        assert th.equal(value, got), name
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], expected)


# ------------------------------------------------------------------------------------------------ envs and resuming
@ALGOS
def test_set_env(tmp_path, algo: Algo) -> None:
    """``set_env`` with another VecEnv and with a plain gym env; another number of envs goes through ``load``.

    As in SB3, ``set_env`` keeps the number of envs (it asserts so) and ``load(path, env)`` changes it.
    """
    model = algo.make(vec_env())
    model.learn(32)
    model.set_env(vec_env(seed=1))
    model.learn(32)
    model.set_env(IdentityCostEnv())
    model.learn(32)
    assert model.safety_metrics.steps == 3 * 32  # type: ignore[attr-defined]  # counted over the three runs
    with pytest.raises(AssertionError, match="number of environments"):
        model.set_env(vec_env(n_envs=2))
    model.save(tmp_path / "model.zip")
    loaded = algo.cls.load(tmp_path / "model.zip", env=vec_env(n_envs=3, seed=2))
    assert loaded.n_envs == 3
    loaded.learn(96, reset_num_timesteps=False)
    assert loaded.num_timesteps == 32 + 96
    assert loaded.safety_metrics.steps == 3 * 32 + 96  # type: ignore[attr-defined]


@ALGOS
def test_resume_continues_num_timesteps(algo: Algo) -> None:
    model = algo.make(vec_env()).learn(STEPS)
    model.learn(32, reset_num_timesteps=False)
    assert model.num_timesteps == STEPS + 32
    assert model.safety_metrics.steps == STEPS + 32  # type: ignore[attr-defined]
    model.learn(32)  # reset_num_timesteps=True starts counting again; the safety metrics are cumulative
    assert model.num_timesteps == 32


@ALGOS
def test_seeded_runs_are_identical(algo: Algo) -> None:
    def parameters(seed: int) -> th.Tensor:
        model = algo.make(vec_env(), seed=seed).learn(STEPS)
        return th.nn.utils.parameters_to_vector(model.policy.parameters()).detach()

    first = parameters(3)
    assert th.equal(first, parameters(3))
    assert not th.equal(first, parameters(4))


@ALGOS
def test_multiprocessing(algo: Algo) -> None:
    """Learning on a ``SubprocVecEnv`` (SAILR's shield goes into each sub-process env with ``wrapper_class``)."""
    wrapper: dict[str, Any] = {}
    if algo.shielded and algo.cls is SAILR:  # SAILR cannot shield envs of another process in place
        wrapper = dict(wrapper_class=ShieldWrapper, wrapper_kwargs=dict(rule=shield_for(IdentityCostEnv())))
    # "fork": a fresh interpreter per env (SB3's default "forkserver") costs seconds of imports per test
    subprocess = dict(vec_env_cls=SubprocVecEnv, vec_env_kwargs=dict(start_method="fork"))
    env = make_vec_env(IdentityCostEnv, n_envs=2, seed=0, **subprocess, **wrapper)
    try:
        overrides = {"shield": None} if wrapper else {}
        model = algo.make(env, **overrides).learn(64)
        assert model.num_timesteps == 64
        if wrapper:
            assert model.safety_metrics.violations == 0  # type: ignore[attr-defined]
    finally:
        env.close()


# ------------------------------------------------------------------------------------------------ predict and evaluate
@ALGOS
def test_predict_single_and_vectorised_observations(algo: Algo) -> None:
    model = algo.make(vec_env())
    obs = observations(5)
    single, _ = model.predict(obs[0], deterministic=True)
    batch, _ = model.predict(obs, deterministic=True)
    assert single.shape == (3,) and batch.shape == (5, 3)
    assert np.all(np.abs(batch) <= 1.0)
    stochastic, _ = model.predict(obs)
    assert stochastic.shape == (5, 3)
    reference = PPO("MlpPolicy", vec_env())  # SB3's own predict path, whose messages users know
    for wrong in (np.zeros(4, dtype=np.float32), (obs[0], {})):  # a wrong shape; obs, info = env.reset(): the Gym API
        with pytest.raises(ValueError) as sb3_error:
            reference.predict(wrong)  # type: ignore[arg-type]
        with pytest.raises(ValueError) as error:
            model.predict(wrong)  # type: ignore[arg-type]
        assert str(error.value) == str(sb3_error.value)


@ALGOS
@pytest.mark.parametrize("n_eval_envs", [1, 3])
def test_evaluate_policy_on_vec_envs_of_other_sizes(algo: Algo, n_eval_envs: int) -> None:
    """Trained on 2 envs, evaluated on 1 and on 3 (the episodes are shared out among the envs)."""
    model = algo.make(vec_env(n_envs=2)).learn(STEPS)
    eval_env = vec_env(n_envs=n_eval_envs, seed=1, max_episode_steps=5)
    rewards, lengths = evaluate_policy(model, eval_env, n_eval_episodes=3, return_episode_rewards=True)
    assert len(rewards) == 3 and set(lengths) == {5}
    assert all(-4.0 * 5 <= r <= 0.0 for r in rewards)


# ------------------------------------------------------------------------------------------------ callbacks
class StopAfter(BaseCallback):
    """Counts its calls and stops training after ``n_steps`` of them."""

    def __init__(self, n_steps: int) -> None:
        super().__init__()
        self.n_steps = n_steps
        self.started = self.ended = False

    def _on_training_start(self) -> None:
        self.started = True

    def _on_step(self) -> bool:
        assert len(self.locals["infos"]) == self.training_env.num_envs
        return self.n_calls < self.n_steps

    def _on_training_end(self) -> None:
        self.ended = True


@ALGOS
def test_callback_is_called_and_stops_training(algo: Algo) -> None:
    model = algo.make(vec_env())
    callback = StopAfter(5)
    model.learn(1_000, callback=callback)
    assert callback.started and callback.ended
    assert callback.n_calls == 5 and model.num_timesteps == 5


@ALGOS
def test_cost_eval_callback_on_another_number_of_envs(tmp_path, algo: Algo) -> None:
    """``CostEvalCallback`` (SB3's ``EvalCallback`` plus costs) on 3 evaluation envs while training on 1."""
    eval_env = vec_env(n_envs=3, seed=1, max_episode_steps=5)
    callback = CostEvalCallback(eval_env, eval_freq=32, n_eval_episodes=3, log_path=str(tmp_path), verbose=0)
    algo.make(vec_env()).learn(64, callback=callback)
    assert len(callback.evaluations_results) == 2 and len(callback.evaluations_costs) == 2
    assert all(len(costs) == 3 for costs in callback.evaluations_costs)
    saved = np.load(tmp_path / "evaluations.npz")
    assert saved["costs"].shape == (2, 3) and saved["violations"].shape == (2, 3)


# ------------------------------------------------------------------------------------------------ VecNormalize
@ALGOS
def test_vec_normalize(tmp_path, algo: Algo) -> None:
    """Learning under ``VecNormalize``; its statistics saved and loaded beside the model predict the same."""
    env = VecNormalize(vec_env(), gamma=0.99)
    model = algo.make(env).learn(STEPS)
    check_safety_metrics(model, algo.shielded)
    model.save(tmp_path / "model.zip")
    env.save(str(tmp_path / "vec_normalize.pkl"))

    loaded_env = VecNormalize.load(str(tmp_path / "vec_normalize.pkl"), vec_env(seed=1))
    np.testing.assert_array_equal(loaded_env.obs_rms.mean, env.obs_rms.mean)
    np.testing.assert_array_equal(loaded_env.ret_rms.var, env.ret_rms.var)
    loaded_env.training = env.training = False
    loaded = algo.cls.load(tmp_path / "model.zip", env=loaded_env)
    obs = env.normalize_obs(observations())
    np.testing.assert_array_equal(deterministic_actions(loaded, obs), deterministic_actions(model, obs))
    loaded_env.training = True
    loaded.learn(32, reset_num_timesteps=False)


# ------------------------------------------------------------------------------------------------ spaces
BOX_ACTIONS = {
    "Box(1,)": spaces.Box(-1, 1, (1,), np.float32),
    "Box(3,) float64 asymmetric": spaces.Box(np.array([-0.5, -2.0, 0.0]), np.array([1.5, 2.0, 0.1]), dtype=np.float64),
    "Box(2, 2)": spaces.Box(-2, 2, (2, 2), np.float32),
}


@pytest.mark.parametrize(
    ("algo", "space_name"),
    [pytest.param(algo, name, id=f"{algo.name}-{name}") for algo in MODEL_LIST for name in BOX_ACTIONS],
)
def test_box_action_spaces(algo: Algo, space_name: str) -> None:
    """Any Box works: one entry, float64 with asymmetric bounds, several dimensions (the env checks every action)."""
    space = BOX_ACTIONS[space_name]
    env = vec_env(action_space=space)
    model = algo.make(env).learn(STEPS)
    check_safety_metrics(model, algo.shielded)
    n_targets = int(np.prod(space.shape))
    obs = observations(4, n_targets)
    single, _ = model.predict(obs[0], deterministic=True)
    batch, _ = model.predict(obs)
    assert single.shape == space.shape and batch.shape == (4, *space.shape)
    assert np.all(batch >= space.low - 1e-6) and np.all(batch <= space.high + 1e-6)


OTHER_SPACES: dict[str, tuple[str, spaces.Space]] = {
    "Discrete actions": ("action", spaces.Discrete(3)),
    "MultiDiscrete actions": ("action", spaces.MultiDiscrete([2, 3])),
    "MultiBinary actions": ("action", spaces.MultiBinary(2)),
    "Dict actions": ("action", spaces.Dict({"force": spaces.Box(-1, 1, (3,), np.float32)})),
    "Discrete observations": ("observation", spaces.Discrete(4)),
    "MultiDiscrete observations": ("observation", spaces.MultiDiscrete([2, 3])),
    "MultiBinary observations": ("observation", spaces.MultiBinary(3)),
    "Dict observations": ("observation", spaces.Dict({"target": spaces.Box(-1, 1, (3,), np.float32)})),
}
DISCRETE = ("Discrete actions", "MultiDiscrete actions", "MultiBinary actions")
NON_BOX_OBS = ("Discrete observations", "MultiDiscrete observations", "MultiBinary observations")
DICT_MESSAGE = r"(?i)dict observation"
SB3_ACTIONS_MESSAGE = "only supports"  # SB3's own check of the action space, before the algorithm's
#: what each algorithm rejects, with the message that says why: the spaces tables of docs/modules/*.md
UNSUPPORTED: dict[str, dict[str, str]] = {
    "SPPO": {
        **dict.fromkeys(DISCRETE, "needs a Box action space"),
        **dict.fromkeys(NON_BOX_OBS, "MLP on flat state vectors"),
        "Dict actions": "needs a Box action space",
        "Dict observations": "Flatten Dict observations",
    },
    "PDO": {"Dict actions": SB3_ACTIONS_MESSAGE, "Dict observations": DICT_MESSAGE},
    "CPO": {"Dict actions": SB3_ACTIONS_MESSAGE, "Dict observations": DICT_MESSAGE},
    "SAILR": {"Dict actions": SB3_ACTIONS_MESSAGE, "Dict observations": DICT_MESSAGE},
    "CSC": {
        **dict.fromkeys(DISCRETE, "supports Box action spaces only"),
        **dict.fromkeys(NON_BOX_OBS, "supports Box observations only"),
        "Dict actions": SB3_ACTIONS_MESSAGE,
        "Dict observations": DICT_MESSAGE,
    },
    "SACLag": {  # SB3's SAC: Box actions only
        **dict.fromkeys(DISCRETE, SB3_ACTIONS_MESSAGE),
        "Dict actions": SB3_ACTIONS_MESSAGE,
        "Dict observations": DICT_MESSAGE,
    },
}
UNSUPPORTED["SPPO-shield"] = UNSUPPORTED["SPPO"]
UNSUPPORTED["SAILR-shield"] = {**UNSUPPORTED["SAILR"], **dict.fromkeys(DISCRETE, "Box action space")}


@ALGOS
@pytest.mark.parametrize("space_name", list(OTHER_SPACES))
def test_other_spaces_work_or_are_rejected_clearly(algo: Algo, space_name: str) -> None:
    """A space an algorithm supports learns and predicts; one it does not is an error at construction saying why."""
    kind, space = OTHER_SPACES[space_name]
    env_kwargs = {f"{kind}_space": space}
    env = DummyVecEnv([lambda: IdentityCostEnv(**env_kwargs)])
    message = UNSUPPORTED[algo.name].get(space_name)
    if message is not None:
        with pytest.raises((TypeError, ValueError, AssertionError), match=message):
            algo.make(env)
        return
    model = algo.make(env).learn(32)
    assert model.num_timesteps == 32
    obs = np.stack([env.observation_space.sample() for _ in range(2)])
    actions, _ = model.predict(obs)
    assert all(model.action_space.contains(action) for action in actions)
