"""What a MuJoCo shield needs of a gymnasium MuJoCo task: its model, its physics state rebuilt from the observation,
and a constraint on that state.

:class:`MujocoLayout` is read off an env once (its MJCF file, frame skip and observation layout) and checked: the
observation must begin with ``[qpos[k:], qvel]`` for some ``k`` (the standard locomotion layouts leave out the first
``k`` position coordinates, ``x`` and maybe ``y``, which do not change the dynamics of a robot on flat ground). Where it
does not, the layout says so at construction. :class:`StateConstraint` is the unsafe set: a predicate and a shaped
distance (eq. 18) of each env step, computed from the physics states before and after it and, optionally, from
sensors it adds to the model. :class:`EpisodeEnd` is where the task ends an episode on its own (a fall): no cost is
paid after it.
"""

from __future__ import annotations

import os
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, NamedTuple

import gymnasium as gym
import mujoco
import numpy as np

#: the physics state :mod:`mujoco.rollout` starts from and records: time, qpos, qvel, act, ...
FULL_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


class ConstraintSteps(NamedTuple):
    """Rolled env steps, as a :class:`StateConstraint` reads them: ``(..., T, ·)`` arrays, one row per env step.

    :param model: the rule's model (with the constraint's sensors).
    :param before: full physics states at the start of each step.
    :param after: full physics states at its end.
    :param sensors_before: ``sensordata`` of the ``before`` states (empty when the model has no sensor).
    :param sensors_after: ``sensordata`` of the ``after`` states.
    :param dt: duration of an env step (``frame_skip`` physics steps).
    """

    model: mujoco.MjModel
    before: np.ndarray
    after: np.ndarray
    sensors_before: np.ndarray
    sensors_after: np.ndarray
    dt: float

    def qpos(self, states: np.ndarray) -> np.ndarray:
        """The ``qpos`` part of full physics states ``(..., nstate)``."""
        return states[..., 1 : 1 + self.model.nq]

    def qvel(self, states: np.ndarray) -> np.ndarray:
        """The ``qvel`` part of full physics states ``(..., nstate)``."""
        return states[..., 1 + self.model.nq : 1 + self.model.nq + self.model.nv]


class ConstraintCosts(NamedTuple):
    """What the rule prices of rolled env steps, ``(..., T)`` each (see :class:`StateConstraint`)."""

    unsafe: np.ndarray
    distance: np.ndarray
    depth: np.ndarray | float
    costly: tuple[np.ndarray, np.ndarray | float] | None


class StateConstraint(ABC):
    """An unsafe set on the simulator state: which env steps violate it, and how far each step ends from it.

    A subclass implements :meth:`is_unsafe` (the cost predicate ``c(s, a) = 1``) and :meth:`distance` (the distance
    to the unsafe set that the shaped cost of eq. 18 reads), both vectorised over the rows of a
    :class:`ConstraintSteps`. A constraint that reads a quantity MuJoCo computes (a body's position, a contact) adds a
    sensor in :meth:`add_sensors` and reads it from ``sensors_after``: sensors are evaluated natively in the rollouts.
    Set :attr:`uses_states` to ``False`` when only sensors are read (the rollouts then skip recording states).
    The rule reads all of them at once through :meth:`assess`; a constraint whose methods share work overrides it.
    Constraints are pickled with the rule: keep them plain data.
    """

    uses_states: bool = True

    def add_sensors(self, spec: mujoco.MjSpec) -> None:  # noqa: B027  (optional hook: most constraints add none)
        """Add the sensors the constraint reads to the model's spec (default: none)."""

    @abstractmethod
    def is_unsafe(self, steps: ConstraintSteps) -> np.ndarray:
        """``(..., T)`` booleans: the step enters the unsafe set (``info["cost"] = 1``)."""

    @abstractmethod
    def distance(self, steps: ConstraintSteps) -> np.ndarray:
        """``(..., T)`` distances ``>= 0`` from each step's outcome to the unsafe set (0 at or inside it)."""

    def costly(self, steps: ConstraintSteps) -> tuple[np.ndarray, np.ndarray | float] | None:
        """Where :meth:`is_unsafe` keeps out of more than what costs in the env (a path that a moving object will take):
        ``(..., T)`` whether each step costs, and how deep inside what costs it is (as :meth:`depth`). ``None`` (the
        default): every unsafe step costs. The rule prices a costly step above one that is only kept out of, so that a
        robot cornered between the two takes the latter."""
        return None

    def assess(self, steps: ConstraintSteps) -> ConstraintCosts:
        """:meth:`is_unsafe`, :meth:`distance`, :meth:`depth` and :meth:`costly` of the same steps."""
        return ConstraintCosts(self.is_unsafe(steps), self.distance(steps), self.depth(steps), self.costly(steps))

    def depth(self, steps: ConstraintSteps) -> np.ndarray | float:
        """``(..., T)`` how far inside the unsafe set each step's outcome is (``>= 0``; 0 outside), in the units of
        :meth:`distance`: the rule leads a robot that is inside out the shortest way. Default: 0 (then only the steps
        spent inside rank the ways out)."""
        return 0.0


@dataclass(frozen=True)
class EpisodeEnd:
    """Where a gymnasium locomotion task ends its episode on its own: ``terminate_when_unhealthy`` outside its healthy
    ranges (Hopper, Walker2d, Ant, Humanoid). A rolled step that ends the episode is the last one that can cost.

    The ranges are read from the env (:meth:`of`) and checked against the env's own ``is_healthy`` on probe states.
    They are taken as closed intervals, where gymnasium's are mostly open: at the boundary the rollout goes on
    counting costs, so the shield never stops counting where the env would not stop (fail closed).

    :param z_index: the ``qpos`` index of the height (1: a planar robot's ``rootz``; 2: a free joint's ``z``).
    :param z_range: the healthy height.
    :param angle_range: the healthy pitch ``qpos[2]`` of a planar robot (Hopper, Walker2d), or ``None``.
    :param state_range: the healthy range of every entry of ``[qpos, qvel][2:]`` (Hopper), or ``None``.
    """

    z_index: int
    z_range: tuple[float, float]
    angle_range: tuple[float, float] | None = None
    state_range: tuple[float, float] | None = None

    @classmethod
    def of(cls, env: Any, probes: int = 256) -> EpisodeEnd | None:
        """The episode end of a gymnasium MuJoCo env (``env.unwrapped``); ``None`` where it ends none on its own.

        :raises ValueError: the env terminates when unhealthy, but not where these ranges say (its ``is_healthy`` is
            not gymnasium's locomotion rule): a shield that stopped counting costs there could fail open.
        """
        if not getattr(env, "_terminate_when_unhealthy", False):
            return None
        free = env.model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
        z_range = _interval(env._healthy_z_range)
        if z_range is None:
            raise ValueError(f"{type(env).__name__} terminates when unhealthy but has no healthy height range")
        end = cls(
            2 if free else 1,
            z_range,
            None if free else _interval(getattr(env, "_healthy_angle_range", None)),
            _interval(getattr(env, "_healthy_state_range", None)),
        )
        end.check_against(env, probes)
        return end

    def ended(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """``(...)`` booleans: the states ``qpos (..., nq)``, ``qvel (..., nv)`` end the episode."""
        outside = _outside(qpos[..., self.z_index], self.z_range)
        if self.angle_range is not None:
            outside |= _outside(qpos[..., 2], self.angle_range)
        if self.state_range is not None:
            outside |= _outside(np.concatenate([qpos, qvel], axis=-1)[..., 2:], self.state_range).any(axis=-1)
        finite = np.isfinite(qpos).all(axis=-1) & np.isfinite(qvel).all(axis=-1)
        return outside & finite

    def check_against(self, env: Any, probes: int) -> None:
        """Compare :meth:`ended` with the env's ``is_healthy`` on states scattered around its initial state."""
        qpos, qvel = env.data.qpos.copy(), env.data.qvel.copy()
        rng = np.random.default_rng(0)
        try:
            for _ in range(probes):
                probe_qpos = env.init_qpos + rng.normal(0.0, 0.5, env.model.nq)
                probe_qvel = rng.normal(0.0, 5.0, env.model.nv)
                env.set_state(probe_qpos, probe_qvel)
                if bool(self.ended(env.data.qpos, env.data.qvel)) and bool(env.is_healthy):
                    raise ValueError(
                        f"{type(env).__name__} terminates when unhealthy, but not where gymnasium's locomotion ranges "
                        f"say (qpos {env.data.qpos.tolist()} is healthy to the env): the shield cannot tell where its "
                        "episodes end. Pass terminate_when_unhealthy=False, or subclass MujocoShieldingRule."
                    )
        finally:
            env.set_state(qpos, qvel)


def _interval(bounds: Any) -> tuple[float, float] | None:
    return None if bounds is None else (float(bounds[0]), float(bounds[1]))


def _outside(values: np.ndarray, bounds: tuple[float, float]) -> np.ndarray:
    return (values < bounds[0]) | (values > bounds[1])


@dataclass(frozen=True)
class MujocoLayout:
    """A gymnasium MuJoCo task as its shield sees it.

    :param xml_path: the MJCF file the env loads.
    :param frame_skip: physics steps per env step.
    :param excluded_positions: ``k``: the observation begins with ``qpos[k:]``, then ``qvel``.
    :param nq: ``model.nq`` of the env.
    :param nv: ``model.nv`` of the env.
    :param obs_dim: size of the flat observation (at least ``nq - k + nv``; the rest is derived from the state).
    :param velocity_clip: the bound the env clips its observed ``qvel`` to (gymnasium's Hopper and Walker2d: 10), or
        ``None``. An observation with a velocity at the bound does not say the state: :meth:`known_states` is False.
    :param env_id: the env's gymnasium id, where known: a rule unpickled where ``xml_path`` does not exist (another
        installation) finds the model through it.
    :param episode_end: where the env ends an episode on its own (:class:`EpisodeEnd`), or ``None``.
    """

    xml_path: str
    frame_skip: int
    excluded_positions: int
    nq: int
    nv: int
    obs_dim: int
    velocity_clip: float | None = None
    env_id: str | None = None
    episode_end: EpisodeEnd | None = None

    @classmethod
    def of(cls, env: gym.Env | str, **env_kwargs: Any) -> MujocoLayout:
        """Read and check the layout of ``env`` (an env or its gymnasium id, made with ``env_kwargs``).

        :raises ValueError: the env is not a gymnasium MuJoCo env, or its observation does not begin with
            ``[qpos[k:], qvel]`` for any ``k``: then its state cannot be rebuilt from the observation.
        """
        made = gym.make(env, **env_kwargs) if isinstance(env, str) else env
        try:
            inner: Any = made.unwrapped  # a gymnasium MujocoEnv: model, data, fullpath, frame_skip
            name = made.spec.id if made.spec is not None else type(inner).__name__
            model = getattr(inner, "model", None)
            if not isinstance(model, mujoco.MjModel) or not hasattr(inner, "fullpath"):
                raise ValueError(
                    f"{name} is not a gymnasium MuJoCo env (no MjModel / MJCF path): MujocoShieldingRule rolls the env's "
                    "own MuJoCo model. For another simulator write a ShieldingRule (docs/guide/custom_tasks.md)."
                )
            obs, _ = made.reset(seed=0)
            obs = np.asarray(obs, dtype=np.float64).ravel()
            k = _excluded_positions(obs, inner.data.qpos, inner.data.qvel)
            if k is None:
                raise ValueError(
                    f"Cannot rebuild {name}'s MuJoCo state from its observation: it does not begin with [qpos[k:], qvel] "
                    f"for any k (obs size {obs.size}, nq {model.nq}, nv {model.nv}). Fix: make the env observe its "
                    "positions and velocities first, as gymnasium's locomotion envs do, or write a ShieldingRule."
                )
            clip = _observed_velocity_clip(inner, k)
            env_id = made.spec.id if made.spec is not None else None
            end = EpisodeEnd.of(inner)
            return cls(inner.fullpath, int(inner.frame_skip), k, model.nq, model.nv, obs.size, clip, env_id, end)
        finally:
            if isinstance(env, str):
                made.close()

    @property
    def state_obs_dim(self) -> int:
        """Entries of the observation that hold the state: ``nq - k + nv``."""
        return self.nq - self.excluded_positions + self.nv

    def build_model(self, constraint: StateConstraint) -> mujoco.MjModel:
        """The env's model compiled from its MJCF file, with the constraint's sensors."""
        path = self.xml_path
        if not os.path.exists(path) and self.env_id is not None:  # unpickled in another installation
            path = MujocoLayout.of(self.env_id).xml_path
        spec = mujoco.MjSpec.from_file(path)
        constraint.add_sensors(spec)
        with warnings.catch_warnings():  # stock models use deprecated attributes (`settotalmass`); gymnasium loads them
            warnings.simplefilter("ignore")
            model = spec.compile()
        if (model.nq, model.nv) != (self.nq, self.nv):
            raise ValueError(f"{self.xml_path} compiles to nq={model.nq}, nv={model.nv}; the env has {self.nq}, {self.nv}.")
        return model

    def at_origin(self, states: np.ndarray) -> np.ndarray:
        """Full physics states as :meth:`states_from_obs` rebuilds them: time 0, the excluded positions 0."""
        states = np.array(states)
        states[:, : 1 + self.excluded_positions] = 0.0
        return states

    def states_from_obs(self, model: mujoco.MjModel, obs: np.ndarray) -> np.ndarray:
        """Full physics states ``(B, nstate)`` rebuilt from observations: time 0, the excluded positions 0.

        :raises ValueError: on observations of another size.
        """
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        if obs.shape[1] != self.obs_dim:
            raise ValueError(f"Expected observations of size {self.obs_dim} for {self.xml_path}, got {obs.shape[1]}.")
        k, observed = self.excluded_positions, self.nq - self.excluded_positions
        states = np.zeros((len(obs), mujoco.mj_stateSize(model, FULL_STATE)))
        states[:, 1 + k : 1 + self.nq] = obs[:, :observed]
        states[:, 1 + self.nq : 1 + self.nq + self.nv] = obs[:, observed : observed + self.nv]
        return states

    def known_states(self, obs: np.ndarray) -> np.ndarray:
        """``(B,)``: the observation alone determines the state (no observed velocity at :attr:`velocity_clip`)."""
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        if self.velocity_clip is None:
            return np.ones(len(obs), dtype=bool)
        observed = self.nq - self.excluded_positions
        velocities = np.abs(obs[:, observed : observed + self.nv])
        return np.all(velocities < self.velocity_clip * (1.0 - 1e-12), axis=1)

    def obs_from_states(self, states: np.ndarray) -> np.ndarray:
        """The state part of the observation, ``[qpos[k:], qvel]``, of full physics states ``(B, nstate)``, as the env
        reports it (velocities clipped to :attr:`velocity_clip`)."""
        obs = np.array(states[:, 1 + self.excluded_positions : 1 + self.nq + self.nv])
        if self.velocity_clip is not None:
            observed = self.nq - self.excluded_positions
            obs[:, observed:] = np.clip(obs[:, observed:], -self.velocity_clip, self.velocity_clip)
        return obs


def _excluded_positions(obs: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> int | None:
    """The ``k`` for which ``obs`` begins with ``[qpos[k:], qvel]`` (``None``: none does)."""
    for k in range(len(qpos) + 1):
        expected = np.concatenate([qpos[k:], qvel])
        if obs.size >= expected.size and np.allclose(obs[: expected.size], expected, rtol=0.0, atol=1e-9):
            return k
    return None


def _observed_velocity_clip(env: Any, k: int, probe: float = 1e3) -> float | None:
    """The bound an env clips its observed velocities to, probed by observing a state of huge velocities (``None``:
    the env does not clip, or cannot be probed: it has no ``_get_obs``, as gymnasium's MuJoCo envs have)."""
    get_obs = getattr(env, "_get_obs", None)
    if get_obs is None:
        return None
    qpos, qvel = env.data.qpos.copy(), env.data.qvel.copy()
    try:
        env.set_state(qpos, np.full_like(qvel, probe))
        observed = np.asarray(get_obs(), dtype=np.float64).ravel()[len(qpos) - k : len(qpos) - k + len(qvel)]
    finally:
        env.set_state(qpos, qvel)
    top = float(np.max(np.abs(observed)))
    return top if top < probe else None
