"""The Half-Cheetah's shielding rule (Section V-A-2): an MPPI backup and ``Q̄`` rolled on the MuJoCo model itself.

Every particle of every MPC solve of a batch runs in one call of :mod:`mujoco.rollout` (C, threaded), so the cost of
the rule is the physics alone. The front thigh's height is read per physics step by a ``framepos`` sensor added to
the model on the body frame (``objtype="xbody"``, i.e. ``data.xpos``, the quantity of the env; ``"body"`` would
measure the inertial frame ``data.xipos``).
A position sensor is evaluated by ``mj_step`` *before* it integrates, so ``sensordata[k]`` is the height of the state
*entering* physics step ``k``: the rollouts run one extra physics step and read the height after env step ``j`` at
index ``frame_skip · j``.
"""

from __future__ import annotations

import os
import warnings
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.envs.half_cheetah_height import HEIGHT_BODY, half_cheetah_xml_path, height_distance_to_unsafe, height_is_unsafe
from sppo_sb3.shield.base import ShieldDecision, ShieldingRule, in_shielding_set

FRAME_SKIP = 5
_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def build_height_model(xml_path: str | None = None) -> mujoco.MjModel:
    """The env's MuJoCo model plus a ``framepos`` sensor on ``fthigh``'s body frame (its last 3 sensor values).

    :param xml_path: the MJCF file; gymnasium's ``half_cheetah.xml`` by default.
    """
    spec = mujoco.MjSpec.from_file(xml_path or half_cheetah_xml_path())
    spec.add_sensor(
        name="fthigh_frame", type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_XBODY, objname=HEIGHT_BODY
    )
    with warnings.catch_warnings():  # the stock model uses the deprecated `settotalmass`; gymnasium loads it as is
        warnings.simplefilter("ignore")
        return spec.compile()


def states_from_obs(model: mujoco.MjModel, obs: np.ndarray) -> np.ndarray:
    """Full physics states ``(B, nstate)`` rebuilt from observations ``[qpos[1:], qvel]``: time = 0, x = 0.

    The x position is unobserved and irrelevant to the dynamics and to the height (the ground is flat).
    """
    obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
    nq, nv = model.nq, model.nv
    if obs.shape[1] != nq - 1 + nv:
        raise ValueError(f"Expected observations [qpos[1:], qvel] of size {nq - 1 + nv}, got {obs.shape[1]}.")
    states = np.zeros((len(obs), mujoco.mj_stateSize(model, _FULL)))
    states[:, 2 : 1 + nq] = obs[:, : nq - 1]  # layout: time, qpos, qvel, (act, ... empty for this model)
    states[:, 1 + nq : 1 + nq + nv] = obs[:, nq - 1 :]
    return states


def physics_controls(controls: np.ndarray, frame_skip: int = FRAME_SKIP) -> np.ndarray:
    """Per-env-step controls ``(M, T, nu)`` → per-physics-step ``(M, T·frame_skip + 1, nu)`` (last step repeated)."""
    ctrl = np.repeat(controls, frame_skip, axis=1)
    return np.ascontiguousarray(np.concatenate([ctrl, ctrl[:, -1:]], axis=1))


def rollout_heights_python(
    model: mujoco.MjModel, data: mujoco.MjData, states: np.ndarray, controls: np.ndarray, frame_skip: int = FRAME_SKIP
) -> np.ndarray:
    """Reference implementation of :meth:`HalfCheetahHeightShieldingRule.rollout_heights`: a Python ``mj_step`` loop.

    :param states: ``(M, nstate)`` full physics states.
    :param controls: ``(M, T, nu)`` controls, one per env step.
    :return: ``(M, T)`` front-thigh heights (body frame) after each env step.
    """
    body = model.body(HEIGHT_BODY).id
    heights = np.empty(controls.shape[:2])
    for i in range(len(states)):
        mujoco.mj_setState(model, data, states[i], _FULL)
        data.qacc_warmstart[:] = 0.0  # as the native rollouts' initial warm start
        for t in range(controls.shape[1]):
            data.ctrl[:] = controls[i, t]
            mujoco.mj_step(model, data, nstep=frame_skip)
            mujoco.mj_kinematics(model, data)
            heights[i, t] = data.xpos[body, 2]
    return heights


class HalfCheetahHeightShieldingRule(ShieldingRule):
    """MPPI backup ``ζ`` and ``Q̄`` rolled on the MuJoCo model (Section V-A-2, SAILR's MPC intervention).

    Costs: along a rollout ``s_0 = s, s_1, ...`` (env steps of ``frame_skip = 5`` physics steps), the discounted shaped
    cost ``J = Σ_{t<H} γ^(t+1) ĉ(s_(t+1))`` with ``ĉ`` of eq. 18 on the front-thigh height. The unsafe set is
    absorbing: at the first step ``t`` whose height leaves ``[0.4, 1.0]`` the rest of the sum is replaced by
    ``γ^(t+1) / (1 - γ)`` (``ĉ = 1`` forever), as in the Point rule.

    The MPC from a state ``s`` (optionally after a fixed first action): one MPPI iteration over the ``H`` env steps,
    nominal plan 0 (no warm start: the rule is stateless, as SAILR's solves), ``N`` particles ``clip(σ·ε, -1, 1)``
    (particle 0 is the nominal plan), each scored by ``J``; weights ``softmax(-J / λ)``; the MPPI plan is the weighted
    mean of the particles (inside the bounds). Of the MPPI plan and the best particle, the MPC returns the one with the
    lower ``J`` (both are rolled): the mean of a few good particles can be worse than each of them.

    Backup ``ζ(s)``: the first action of the MPC plan from ``s``.

    ``Q̄(s, a)`` with ``replan=True`` (default; the paper's ``Q̄ = E[Σ_(t=0)^(H_m) γ^t ĉ | â_(1:H) = MPC(ŝ_1)]``, as
    SAILR computes it): take ``a``, re-solve the MPC from ``ŝ_1`` for the remaining ``H - 1`` steps (its particles
    are rolled from ``s`` with ``a`` as their first action, so each is scored by ``J`` over the same ``H`` steps),
    and return ``J`` of ``[a, plan]``. Per shield call on ``B`` states: ``B·N`` particle rollouts for ``ζ``,
    ``2B·N`` for the ``Q̄(s, a)`` and ``Q̄(s, ζ(s))`` solves (one batch, :meth:`ShieldingRule.advantage`), and ``6B``
    candidate rollouts, each of ``5H + 1`` physics steps, in four :mod:`mujoco.rollout` calls.

    ``Q̄(s, a)`` with ``replan=False`` (3× cheaper, more conservative): ``J`` of ``a`` followed by the tail
    ``plan[1:]`` of the MPC plan solved at ``s`` itself; ``Q̄(s, ζ(s))`` is then the plan's own ``J``, and one
    solve serves ``ζ``, ``Q̄(s, a)`` and ``Q̄(s, ζ(s))`` (:meth:`advantage` and :meth:`shield` are overridden to
    share it): ``B·N + 4B`` rollouts per shield call. The tail is not adapted to ``a``, so ``Q̄(s, a)`` is larger
    than with re-planning and the rule intervenes more.

    All states of a call share the same noise ``ε`` (common random numbers): ``Q̄(s, a)`` is a deterministic function
    of ``(s, a)`` within a call, so ``Ā(s, ζ(s)) = 0`` exactly (Proposition 1). The noise comes from a generator
    seeded by ``seed``: two rules with the same seed give the same answers to the same calls, whatever the threads.

    :param horizon: ``H_m``, the MPC and ``Q̄`` horizon in env steps.
    :param n_particles: MPPI particles per solve (SAILR: 64).
    :param temperature: MPPI temperature ``λ`` (SAILR: 0.2).
    :param noise_std: standard deviation ``σ`` of the particle controls around the nominal plan 0.
    :param alpha: shaped-cost band width of eq. 18 (paper: 0.05).
    :param gamma: discount of ``Q̄`` (paper: 0.99).
    :param eta: advantage threshold (paper: 0.2).
    :param penalty: absorbing reward ``R̃``.
    :param seed: seed of the particle noise.
    :param replan: re-solve the MPC after ``a`` for ``Q̄(s, a)`` (paper, SAILR), or reuse the plan solved at ``s``.
    :param n_threads: threads of the rollout pool; ``None``: one per available core; 0: the calling thread.
    :param xml_path: the MJCF model (must be the env's); gymnasium's ``half_cheetah.xml`` by default.
    """

    def __init__(
        self,
        horizon: int = 15,
        n_particles: int = 64,
        temperature: float = 0.2,
        noise_std: float = 0.5,
        alpha: float = 0.05,
        gamma: float = 0.99,
        eta: float = 0.2,
        penalty: float = -1.0,
        seed: int | None = 0,
        replan: bool = True,
        n_threads: int | None = None,
        xml_path: str | None = None,
    ) -> None:
        super().__init__(eta=eta, penalty=penalty)
        if horizon < 2 or n_particles < 1 or temperature <= 0 or noise_std < 0:
            raise ValueError("Need horizon >= 2, n_particles >= 1, temperature > 0 and noise_std >= 0.")
        self.horizon = horizon
        self.n_particles = n_particles
        self.temperature = temperature
        self.noise_std = noise_std
        self.alpha = alpha
        self.gamma = gamma
        self.seed = seed
        self.replan = replan
        self.n_threads = len(os.sched_getaffinity(0)) if n_threads is None else n_threads
        self.xml_path = xml_path
        self.rng = np.random.default_rng(seed)
        self._build()

    # --- MuJoCo objects: rebuilt after unpickling ---------------------------------------------------------------

    def _build(self) -> None:
        """Compile the model and create the per-thread data and the rollout thread pool."""
        self.model = build_height_model(self.xml_path)
        self._datas = [mujoco.MjData(self.model) for _ in range(max(1, self.n_threads))]
        self._pool = mj_rollout.Rollout(nthread=self.n_threads)
        self._height_index = self.model.nsensordata - 1  # z of the framepos sensor added last
        low, high = self.model.actuator_ctrlrange.T
        self.action_low, self.action_high = low.copy(), high.copy()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for key in ("model", "_datas", "_pool"):
            state.pop(key)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._build()

    # --- rollouts and costs -------------------------------------------------------------------------------------

    def rollout_heights(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """Front-thigh heights after each env step of open-loop rollouts, all in one :mod:`mujoco.rollout` call.

        :param states: ``(M, nstate)`` full physics states.
        :param controls: ``(M, T, nu)`` controls, one per env step, inside the control range.
        :return: ``(M, T)`` heights.
        """
        m = len(controls)
        ctrl = physics_controls(controls)
        nstep = ctrl.shape[1]
        sensordata = np.empty((m, nstep, self.model.nsensordata))
        self._pool.rollout(
            [self.model] * m,
            self._datas,
            np.ascontiguousarray(states),
            ctrl,
            skip_checks=True,
            nstep=nstep,
            initial_warmstart=np.zeros((m, self.model.nv)),  # same start on every thread: deterministic
            state=None,  # only the sensors are read: the states are not recorded
            sensordata=sensordata,
        )
        return sensordata[:, FRAME_SKIP::FRAME_SKIP, self._height_index]

    def discounted_cost(self, heights: np.ndarray) -> np.ndarray:
        """``J = Σ_t γ^(t+1) ĉ(h_(t+1))`` (eq. 18 cost) with the absorbing tail ``γ^(t+1)/(1-γ)`` at the first violation.

        :param heights: ``(..., T)`` heights after each env step.
        :return: ``(...)`` discounted costs.
        """
        unsafe = height_is_unsafe(heights)
        before_violation = (np.cumsum(unsafe, axis=-1) - unsafe) == 0  # no violation strictly before t
        discount = self.gamma ** np.arange(1, heights.shape[-1] + 1)
        cost = shaped_cost(height_distance_to_unsafe(heights), self.alpha)
        step = np.where(unsafe, discount / (1.0 - self.gamma), cost * discount)
        return np.sum(np.where(before_violation, step, 0.0), axis=-1)

    def _particles(self, length: int) -> np.ndarray:
        """``(N, length, nu)`` particle controls ``clip(σ·ε, low, high)``; particle 0 is the nominal plan 0."""
        noise = self.noise_std * self.rng.standard_normal((self.n_particles, length, self.model.nu))
        noise[0] = 0.0
        return np.clip(noise, self.action_low, self.action_high)

    def mppi_candidates(self, states: np.ndarray, first_action: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One MPPI iteration per state, all particles of all states in one rollout call.

        :param states: ``(M, nstate)`` full physics states.
        :param first_action: ``(M, nu)`` a fixed first action (plan from ``ŝ_1`` after it), or ``None``.
        :return: the MPPI plans (weighted means of the particles) and the best particles, both ``(M, L, nu)`` with
            ``L = H`` without a first action, else ``H - 1``.
        """
        m, n = len(states), self.n_particles
        particles = self._particles(self.horizon - (first_action is not None))  # shared by every state of the call
        scores = self.discounted_cost(
            self.rollout_heights(np.repeat(states, n, axis=0), self._with_prefix(particles, first_action, m))
        )
        scores = scores.reshape(m, n)
        weights = np.exp(-(scores - scores.min(axis=1, keepdims=True)) / self.temperature)
        weights /= weights.sum(axis=1, keepdims=True)
        return np.einsum("mn,nlu->mlu", weights, particles), particles[scores.argmin(axis=1)]

    def _with_prefix(self, controls: np.ndarray, first_action: np.ndarray | None, m: int) -> np.ndarray:
        """``(m·K, H, nu)`` rollout controls: ``K`` sequences per state (``controls``), after its first action."""
        controls = np.broadcast_to(controls, (m, *controls.shape[-3:]))
        if first_action is not None:
            prefix = np.broadcast_to(first_action[:, None, None, :], (m, controls.shape[1], 1, self.model.nu))
            controls = np.concatenate([prefix, controls], axis=2)
        return controls.reshape(-1, self.horizon, self.model.nu)

    def solve(self, states: np.ndarray, first_action: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The MPC: of the MPPI plan and the best particle, the one with the lower cost ``J``, and that cost.

        The weighted mean of a few good particles can be worse than each of them (with the thigh 2 cm above its
        limit, it often is): keeping the better of the two makes ``J`` never worse than the nominal plan's.

        :param states: ``(M, nstate)`` full physics states.
        :param first_action: ``(M, nu)`` a fixed first action, or ``None``.
        :return: ``(M, L, nu)`` plans and ``(M,)`` costs ``J`` of the full rollout (first action included).
        """
        m = len(states)
        plans = np.stack(self.mppi_candidates(states, first_action), axis=1)  # (M, 2, L, nu)
        costs = self.discounted_cost(
            self.rollout_heights(np.repeat(states, 2, axis=0), self._with_prefix(plans, first_action, m))
        )
        choice = costs.reshape(m, 2).argmin(axis=1)
        return plans[np.arange(m), choice], costs.reshape(m, 2)[np.arange(m), choice]

    # --- the rule -----------------------------------------------------------------------------------------------

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """``ζ(s)``: the first action of the MPC plan from ``s``."""
        plan, _ = self.solve(states_from_obs(self.model, obs))
        return np.clip(plan[:, 0], self.action_low, self.action_high)

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)``: ``J`` of "take ``a``, then the MPC plan" (re-solved from ``ŝ_1``, or solved at ``s``)."""
        states, actions = self._inputs(obs, actions)
        if self.replan:
            return self.solve(states, first_action=actions)[1]
        return self._shared(states, actions)[1]

    def advantage(self, obs: np.ndarray, actions: np.ndarray, backup: np.ndarray | None = None) -> np.ndarray:
        """``Ā(s, a) = Q̄(s, a) - Q̄(s, ζ(s))``; with ``replan=False`` from one shared solve (``backup`` is recomputed)."""
        if self.replan:
            return super().advantage(obs, actions, backup)
        _, q, v = self._shared(*self._inputs(obs, actions))
        return q - v

    def shield(self, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        """Eq. 12; with ``replan=False``, ``ζ(s)``, ``Q̄(s, a)`` and ``Q̄(s, ζ(s))`` come from one MPC solve."""
        if self.replan:
            return super().shield(obs, actions)
        states, clipped = self._inputs(obs, actions)
        backup, q, v = self._shared(states, clipped)
        intervened = in_shielding_set(q - v, self.eta)
        safe = np.where(intervened[:, None], backup, np.asarray(actions, dtype=np.float64).reshape(clipped.shape))
        return ShieldDecision(actions=safe, intervened=intervened, advantage=q - v)

    def _inputs(self, obs: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Physics states rebuilt from ``obs`` and the actions clipped to the control range."""
        states = states_from_obs(self.model, obs)
        actions = np.asarray(actions, dtype=np.float64).reshape(len(states), -1)
        return states, np.clip(actions, self.action_low, self.action_high)

    def _shared(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``replan=False``: ``(ζ(s), Q̄(s, a), Q̄(s, ζ(s)))`` from the MPC plan solved at ``s``."""
        plan, value = self.solve(states)
        tails = np.concatenate([actions[:, None], plan[:, 1:]], axis=1)
        return (
            np.clip(plan[:, 0], self.action_low, self.action_high),
            self.discounted_cost(self.rollout_heights(states, tails)),
            value,
        )
