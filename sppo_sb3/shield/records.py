"""Replayable records of the episodes that paid cost behind a shield, and their closed-loop replay.

A costly step behind a shield is a bug in the rule or a limit of what it certifies; either way it must be possible to
replay it on another machine, where the training run that produced it cannot be (its networks' floating point
differs from one CPU to another). :class:`ShieldWrapper <sppo_sb3.shield.ShieldWrapper>` keeps an :class:`EpisodeLog`
of every episode: the randomness its ``reset`` started from and, per env step, the proposal, the executed action, the
rule's decision and the cost. An episode that paid cost becomes a :class:`CostlyEpisode` record (JSON): that log, the
simulator state before its last :data:`WINDOW` env steps, the rule's name and parameters, the commit and the package
versions.

:func:`~sppo_sb3.shield.replay.replay` rebuilds the env from the record, resets it from the recorded randomness and
feeds the recorded proposals, one per env step, through a fresh ``ShieldWrapper`` with the recorded rule (or another
one): closed loop, so that each decision is the rule's own, on the states its own decisions lead to. With the rule
that was recorded, the replay repeats the episode step for step (MuJoCo's physics and the rules are deterministic);
with a fixed rule, it says whether the rule now holds. ``python scripts/replay_costly.py RECORD.json`` prints it.
"""

from __future__ import annotations

import dataclasses
import json
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sppo_sb3.common.provenance import package_versions, source_revision

#: env steps before the last costly one whose first simulator state a record keeps (the issue's "last N steps")
WINDOW = 50
#: records a wrapper keeps in memory (the first ones: a run that pays cost on every episode repeats one failure)
MAX_RECORDS = 16
#: format of the record files
RECORD_VERSION = 1


def reset_randomness(env: gym.Env, seed: int | None) -> dict[str, Any]:
    """What ``env.reset(seed=seed)`` will draw from: the seed, else the env's random streams as they are now.

    The streams are gymnasium's ``np_random`` and, where the env has one, its own layout stream (``rng_state()``,
    as the navigation tasks keep Safety-Gymnasium's Mersenne Twister). An env reset without a seed before its streams
    exist draws fresh entropy: that episode cannot be replayed (``replayable`` is then false).
    """
    base = env.unwrapped
    if seed is not None:
        return {"seed": int(seed), "replayable": True}
    streams: dict[str, Any] = {"seed": None, "np_random": base.np_random.bit_generator.state}
    own = getattr(base, "rng_state", None)
    if own is not None:
        streams["layout_rng"] = own()
        streams["replayable"] = streams["layout_rng"] is not None
    else:
        streams["replayable"] = True
    return streams


def restore_randomness(env: gym.Env, randomness: dict[str, Any]) -> int | None:
    """Set ``env``'s streams to a record's :func:`reset_randomness`; return the seed to reset with (``None``: none)."""
    if not randomness.get("replayable", False):
        raise ValueError(
            "This episode started from fresh entropy (its env was reset without a seed before its random streams "
            "existed), so it cannot be replayed. Seed the env (SB3: the model's seed) to make its episodes replayable."
        )
    if randomness["seed"] is not None:
        return int(randomness["seed"])
    base = env.unwrapped
    bit_generator = base.np_random.bit_generator
    bit_generator.state = randomness["np_random"]
    if "layout_rng" in randomness:
        keys, position = randomness["layout_rng"]
        base.set_rng_state(np.asarray(keys, dtype=np.uint32), int(position))  # type: ignore[attr-defined]
    return None


@dataclass
class EpisodeLog:
    """One episode behind a shield, env step by env step (actions in the env's units, flat)."""

    randomness: dict[str, Any]
    proposed: list[list[float]] = field(default_factory=list)
    executed: list[list[float]] = field(default_factory=list)
    intervened: list[bool] = field(default_factory=list)
    advantage: list[float | None] = field(default_factory=list)
    cost: list[float] = field(default_factory=list)
    #: the simulator state before each of the last WINDOW + 1 steps
    states: deque[Any] = field(default_factory=lambda: deque(maxlen=WINDOW + 1))

    def add(
        self, state: Any, proposed: np.ndarray, executed: np.ndarray, intervened: bool, advantage: float, cost: float
    ) -> None:
        """Log one env step: the state before it, what was proposed and executed, the decision and the cost."""
        self.states.append(state)
        self.proposed.append(np.asarray(proposed, dtype=np.float64).ravel().tolist())
        self.executed.append(np.asarray(executed, dtype=np.float64).ravel().tolist())
        self.intervened.append(bool(intervened))
        self.advantage.append(float(advantage) if np.isfinite(advantage) else None)
        self.cost.append(float(cost))

    @property
    def costly_steps(self) -> list[int]:
        """The env steps (0-based, within the episode) that paid cost."""
        return [t for t, c in enumerate(self.cost) if c > 0]


@dataclass
class CostlyEpisode:
    """A record of an episode that paid cost behind a shield (see the module); :meth:`save` / :meth:`load` as JSON.

    :param env_id: the env's registered id; ``env_kwargs`` its ``gym.make`` keyword arguments.
    :param rule: the rule's registered name, as the wrapper was given it (``"auto"``, an env id; ``None``: an object,
        which :func:`replay` needs passed in); ``rule_class`` and ``rule_params`` say what it was.
    :param episode: the episode's index among the wrapper's episodes (0: the first).
    :param log: the episode, env step by env step, up to the end of the record.
    :param window_start: the env step whose state ``state_before_window`` is (``WINDOW`` steps before the last costly
        one, or the episode's start).
    :param state_before_window: the simulator state there (the env's ``get_state()`` as plain data, else the
        observation).
    :param provenance: the commit and the package versions.
    """

    env_id: str
    env_kwargs: dict[str, Any]
    rule: str | None
    rule_class: str
    rule_params: dict[str, Any]
    episode: int
    log: EpisodeLog
    window_start: int
    state_before_window: Any
    provenance: dict[str, Any]
    version: int = RECORD_VERSION

    @property
    def costly_steps(self) -> list[int]:
        return self.log.costly_steps

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = dataclasses.asdict(self)
        data["log"].pop("states")
        path.write_text(json.dumps(data, indent=1, default=plain_json))
        return path

    @classmethod
    def load(cls, path: str | Path) -> CostlyEpisode:
        data = json.loads(Path(path).read_text())
        if data.get("version") != RECORD_VERSION:
            raise ValueError(
                f"{path} is a record of format {data.get('version')}; this package reads format {RECORD_VERSION}."
            )
        data["log"] = EpisodeLog(**data["log"])
        return cls(**data)


def plain_json(value: Any) -> Any:
    """JSON for what :func:`json.dumps` does not know: numpy arrays and scalars, dataclasses."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    raise TypeError(f"cannot write {type(value).__name__} to a record")


def simulator_state(env: gym.Env) -> Any:
    """The env's state before a step, as plain data: its ``get_state()`` where it has one, else ``None``."""
    get_state = getattr(env.unwrapped, "get_state", None)
    return get_state() if get_state is not None else None


def rule_params(rule: Any) -> dict[str, Any]:
    """A rule's scalar settings (``eta``, ``gamma``, horizons...): what a record says about the rule that decided."""
    return {
        key: value
        for key, value in vars(rule).items()
        if not key.startswith("_") and isinstance(value, (bool, int, float, str))
    }


def costly_episode(
    env: gym.Env, rule: Any, rule_name: str | None, episode: int, log: EpisodeLog, obs: np.ndarray
) -> CostlyEpisode:
    """The record of ``log``, an episode of ``env`` that paid cost (see :class:`CostlyEpisode`)."""
    spec = env.unwrapped.spec or env.spec
    if spec is None:
        raise ValueError("Only a registered env (gym.make) can be recorded for replay: its id rebuilds it.")
    last = log.costly_steps[-1]
    start = max(0, last - WINDOW)
    kept_from = len(log.cost) - len(log.states)
    state = log.states[start - kept_from] if start >= kept_from else None
    return CostlyEpisode(
        env_id=spec.id,
        env_kwargs=dict(spec.kwargs),
        rule=rule_name,
        rule_class=type(rule).__name__,
        rule_params=rule_params(rule),
        episode=episode,
        log=log,
        window_start=start,
        state_before_window=state if state is not None else np.asarray(obs).tolist(),
        provenance={**source_revision(), "packages": package_versions()},
    )
