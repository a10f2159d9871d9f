"""``MujocoShieldingRule``: a certified MPC shield for a gymnasium MuJoCo task, from its own model and a constraint.

Every particle of every MPC solve of a batch runs in one call of :mod:`mujoco.rollout` (C, threaded), so the cost of
the rule is the physics; certificates (see the class) spare most solves. The constraint
(:class:`~sppo_sb3.shield.mujoco.model.StateConstraint`) reads the rolled physics states and the sensors it adds to the model.
"""

from __future__ import annotations

import copy
import itertools
import math
import os
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.shield.base import ShieldDecision, ShieldingRule, in_shielding_set
from sppo_sb3.shield.mujoco.model import ConstraintSteps, MujocoLayout, StateConstraint
from sppo_sb3.shield.mujoco.mpc import MPCSolution, ShieldStep, SolveCounts, physics_controls
from sppo_sb3.shield.mujoco.warm_starts import WarmStarts

#: certificate candidates rolled per call (:meth:`MujocoShieldingRule.certify_in_chunks`): a few for the threads, and
#: few to waste past the first certificate
CERTIFICATE_CHUNK = 4


def lookahead_horizon(dt: float, seconds: float, least: int = 2) -> int:
    """The MPC horizon, in env steps of ``dt`` seconds, that looks ``seconds`` ahead (at least ``least`` steps).

    A rule's horizon is a time: long enough for the backup to stop what the task's robot can start in that time.
    """
    return max(least, math.ceil(seconds / dt - 1e-9))


def none_before(flags: np.ndarray) -> np.ndarray:
    """``(..., T)``: no flag is set strictly before each step of the last axis."""
    return (np.cumsum(flags, axis=-1) - flags) == 0


class MujocoShieldingRule(ShieldingRule):
    """MPPI backup ``ζ`` and ``Q̄`` rolled on a gymnasium MuJoCo task's own model, for any constraint on its state.

    The rule rebuilds the physics state from the observation (:class:`~sppo_sb3.shield.mujoco.model.MujocoLayout`) and
    rolls the env's MJCF model, with the constraint's sensors, in :mod:`mujoco.rollout` (C, threaded): every particle
    of every MPC solve of a batch in one call.

    Costs: along a rollout ``s_0 = s, s_1, ...`` (env steps of ``frame_skip`` physics steps), the discounted shaped cost
    ``J = Σ_{t<H} γ^(t+1) ĉ_(t+1)`` with ``ĉ`` of eq. 18 on the constraint's distance after each step. The unsafe set
    is absorbing: at the first step ``t`` that the constraint calls unsafe the rest of the sum is replaced by
    ``γ^(t+1) / (1 - γ)`` (``ĉ = 1`` forever), as in the Point rule. Deviation: each later step the rollout is still
    in the unsafe set adds ``γ^(t+1) (1 + depth / α)``, its depth inside (:meth:`StateConstraint.depth
    <sppo_sb3.shield.mujoco.model.StateConstraint.depth>`) in units of the band. The tail alone prices every plan from
    inside the unsafe set alike, so that ``Ā = 0`` there and eq. 12 would pass any proposal, also one that goes
    deeper; where a violation does not end the episode (the velocity and navigation tasks), the steps spent inside and
    their depth rank the plans, and the backup leads out. Second deviation, where the unsafe set keeps out of more than
    what costs (:meth:`StateConstraint.costly <sppo_sb3.shield.mujoco.model.StateConstraint.costly>`: the path a
    gremlin will sweep): the steps that cost are priced so again, as a second unsafe set inside the first, so that a
    robot cornered between a kept-out path and a wrong button enters the path, where nothing costs yet. Where the
    task ends its episodes on its own
    (:class:`~sppo_sb3.shield.mujoco.model.EpisodeEnd`: a fall), the sum stops after the step that ends the episode: a
    fallen robot's sliding costs nothing in the env, and counting it would make every plan look as bad as a violation,
    so that ``Ā ≈ 0`` and the shield let proposals through. Every ``J`` is ``>= 0``.

    The MPC from a state ``s`` (optionally after a fixed first action) around a nominal plan ``W``: one MPPI iteration
    over ``N`` particles ``clip(W + σ·ε_i)`` (``ε_0 = 0``: particle 0 is ``W`` itself; the last
    ``constant_particles`` hold controls at their bounds), each scored by ``J``;
    weights ``softmax(-J / λ)``; the MPPI plan is the weighted mean of the particles. Of the MPPI plan and the best
    particle, the MPC returns the one with the lower ``J``; so its ``J`` is never above ``W``'s.

    - Backup ``ζ(s)``: the first action of the MPC plan from ``s`` around ``W`` (``H`` steps).
    - ``Q̄(s, a)`` (the paper's ``Q̄ = E[Σ_(t=0)^(H_m) γ^t ĉ | â_(1:H) = MPC(ŝ_1)]``, as SAILR computes it): ``J`` of
      ``a`` followed by the MPC re-solved from ``ŝ_1`` around ``W[1:]`` (``H - 1`` steps; its particles are rolled
      from ``s`` with ``a`` as their first action, so each is scored over the same ``H`` steps).
    - Shield (eqs. 5, 12): execute ``a`` unless ``Ā(s, a) = Q̄(s, a) - Q̄(s, ζ(s)) > η``, else ``ζ(s)``.

    The noise ``ε`` is drawn once, from ``seed``, and shared by every solve (common random numbers): ``Q̄``, ``ζ`` and
    the decisions are deterministic functions of ``(s, a, W)``, ``Ā(s, ζ(s)) = 0`` exactly (Proposition 1), and the
    certified and the full rule can be compared decision by decision.

    Warm start: ``W`` is the plan the rule meant to follow from ``s`` when it shielded the previous step (see
    :class:`~sppo_sb3.shield.mujoco.warm_starts.WarmStarts`; the zero plan at an episode's start). After the step it is, from
    the next state: where shielded, the tail of ``ζ``'s plan (the backup plan, shifted); else ``W[1:]`` if "``a``,
    then ``W[1:]``" has ``J <= η`` (the warm plan still certifies the executed ``a``), else the first of the next
    ``certificate_particles`` particles of ``Q̄(s, a)``'s solve that does; else the plan of the ``Q̄(s, a)`` solve.
    A zero step is appended.

    Certificates (``certify=True``): since ``J >= 0`` and the MPC never does worse than its nominal plan,
    ``Ā(s, a) <= Q̄(s, a) <= J([a, W[1:]])``, and the same holds for every particle of ``Q̄(s, a)``'s solve. Per env
    step the rule rolls ``[a, W[1:]]`` once; where its ``J <= η``, ``(s, a) ∉ I`` and nothing is solved; elsewhere it
    tries a few more particles the same way. Only then it solves ``Q̄(s, a)`` (where ``<= η``, again ``(s, a) ∉ I``),
    then ``ζ(s)``, and ``Q̄(s, ζ(s))`` only where its upper bounds leave the decision open
    (:meth:`_shield_certified`). Each stage is one batch over the envs of the call. The decisions and the warm plans
    are those of ``certify=False``, which solves ``Q̄(s, a)``, ``ζ(s)`` and ``Q̄(s, ζ(s))`` on every step.

    :param env: the task: a gymnasium MuJoCo env, its id (made with ``env_kwargs``), or its
        :class:`~sppo_sb3.shield.mujoco.model.MujocoLayout`. Its observation must begin with ``[qpos[k:], qvel]``.
    :param constraint: the unsafe set, a :class:`~sppo_sb3.shield.mujoco.model.StateConstraint`.
    :param horizon: ``H_m``, the MPC and ``Q̄`` horizon in env steps.
    :param n_particles: MPPI particles per solve (SAILR: 64).
    :param temperature: MPPI temperature ``λ`` (SAILR: 0.2).
    :param noise_std: standard deviation ``σ`` of the particle controls around the nominal plan.
    :param alpha: shaped-cost band width of eq. 18, in the constraint's distance units.
    :param gamma: discount of ``Q̄`` (paper: 0.99).
    :param eta: advantage threshold ``η`` (on the shaped scale, where a violation is worth about ``1 / (1 - γ)``).
    :param seed: seed of the particle noise ``ε`` (``None``: fresh entropy).
    :param certify: skip the solves that a certificate makes unnecessary (same decisions); ``False`` solves
        ``ζ(s)``, ``Q̄(s, a)`` and ``Q̄(s, ζ(s))`` on every step, the reference.
    :param certificate_particles: particles of ``Q̄(s, a)``'s solve, after ``W[1:]``, tried as certificates (and as
        the plan to follow) before solving.
    :param constant_particles: how many of the last particles hold each control at its lower bound, its upper bound or
        the nominal plan's value for the whole plan (the directions of ``{-1, 0, 1}^nu`` but zero, in lexicographic
        order; a robot with two controls has 8): plans a search around ``W`` with noise ``σ`` rarely draws, such as
        a full turn held for the whole lookahead. 0: every particle is ``W + σ·ε_i``.
    :param permissive: where the rule rejects a proposal, execute the accepted action nearest to it (in units of the
        control range) instead of the backup's: the first action of a particle of ``ζ``'s solve whose plan has
        ``J <= η`` (then ``Ā <= Q̄ <= J <= η``: the rule's own test accepts it, as a certificate does), or ``ζ(s)``
        itself where none is nearer; its plan is followed after it. It costs no rollout more than the rule's own
        (:meth:`nearest_accepted`). Not in the paper (Dalal et al. 2018 execute the nearest safe action).
    :param n_threads: threads of the rollout pool; ``None``: one per available core; 0: the calling thread.
    :param warm_starts: how many warm plans the rule keeps (one per running env is needed).
    :param env_kwargs: keyword arguments of ``gym.make`` when ``env`` is an id.
    """

    def __init__(
        self,
        env: gym.Env | str | MujocoLayout,
        constraint: StateConstraint,
        horizon: int = 15,
        n_particles: int = 64,
        temperature: float = 0.2,
        noise_std: float = 0.5,
        alpha: float = 0.05,
        gamma: float = 0.99,
        eta: float = 0.2,
        seed: int | None = 0,
        certify: bool = True,
        certificate_particles: int = 16,
        constant_particles: int = 0,
        permissive: bool = False,
        n_threads: int | None = None,
        warm_starts: int = 256,
        env_kwargs: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(eta=eta)
        if horizon < 2 or n_particles < 1 or temperature <= 0 or noise_std < 0 or alpha < 0:
            raise ValueError("Need horizon >= 2, n_particles >= 1, temperature > 0, noise_std >= 0 and alpha >= 0.")
        if not 0 <= constant_particles < n_particles:
            raise ValueError(
                f"constant_particles={constant_particles} must be in [0, n_particles={n_particles}): particle 0 is the "
                "nominal plan itself."
            )
        if not isinstance(constraint, StateConstraint):
            raise TypeError(
                f"constraint must be a sppo_sb3.shield.StateConstraint (is_unsafe and distance of rolled steps), got "
                f"{constraint!r}."
            )
        self.layout = env if isinstance(env, MujocoLayout) else MujocoLayout.of(env, **(env_kwargs or {}))
        self.constraint = constraint
        self.horizon = horizon
        self.n_particles = n_particles
        self.temperature = temperature
        self.noise_std = noise_std
        self.alpha = alpha
        self.gamma = gamma
        self.seed = seed
        self.certify = certify
        self.certificate_particles = min(certificate_particles, n_particles - 1)
        self.constant_particles = constant_particles
        self.permissive = permissive
        self.n_threads = len(os.sched_getaffinity(0)) if n_threads is None else n_threads
        self._build()
        self.noise = noise_std * np.random.default_rng(seed).standard_normal((n_particles, horizon, self.model.nu))
        self.noise[0] = 0.0
        if constant_particles:
            self.noise[n_particles - constant_particles :] = self.held_directions(constant_particles)[:, None, :]
        self.warm_starts = WarmStarts(warm_starts, horizon, self.model.nu)
        self.solve_counts = SolveCounts()

    def held_directions(self, count: int) -> np.ndarray:
        """``(count, nu)`` noise that, added to any control and clipped, holds it at a bound or leaves it (``ε = 0``)."""
        directions = [d for d in itertools.product((-1.0, 0.0, 1.0), repeat=self.model.nu) if any(d)]
        if count > len(directions):
            n = len(directions)
            raise ValueError(f"constant_particles={count}: a robot with {self.model.nu} controls has {n} directions.")
        return np.array(directions[:count]) * (self.action_high - self.action_low)

    # --- MuJoCo objects: rebuilt after unpickling ---------------------------------------------------------------

    def _build(self) -> None:
        """Compile the model and create the per-thread data and the rollout thread pool."""
        self.model = self.layout.build_model(self.constraint)
        self._datas = [mujoco.MjData(self.model) for _ in range(max(1, self.n_threads))]
        self._pool = mj_rollout.Rollout(nthread=self.n_threads)
        self._dt = float(self.model.opt.timestep) * self.layout.frame_skip
        low, high = self.model.actuator_ctrlrange.T
        self.action_low, self.action_high = low.copy(), high.copy()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for key in ("model", "_datas", "_pool"):
            state.pop(key)
        state["warm_starts"] = copy.copy(self.warm_starts)  # the plans belong to the running episodes: not saved
        state["warm_starts"].clear()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._build()

    # --- rollouts and costs -------------------------------------------------------------------------------------

    def _rollout(self, states: np.ndarray, ctrl: np.ndarray, **outputs: np.ndarray) -> None:
        """Open-loop rollouts of per-physics-step controls ``(M, nstep, nu)`` into ``outputs`` (``state``, ``sensordata``)."""
        m = len(ctrl)
        self._pool.rollout(
            [self.model] * m,
            self._datas,
            np.ascontiguousarray(states),
            ctrl,
            skip_checks=True,
            nstep=ctrl.shape[1],
            initial_warmstart=np.zeros((m, self.model.nv)),  # same start on every thread: deterministic
            **outputs,
        )

    def rollout_steps(self, states: np.ndarray, controls: np.ndarray) -> ConstraintSteps:
        """Open-loop rollouts of per-env-step controls, as the constraint reads them, in one :mod:`mujoco.rollout` call.

        A sensor is evaluated by ``mj_step`` *before* it integrates, so ``sensordata[k]`` belongs to the state entering
        physics step ``k``: the rollouts run one extra physics step, and the sensors after env step ``j`` are those at
        index ``frame_skip · (j + 1)``.

        :param states: ``(M, nstate)`` full physics states.
        :param controls: ``(M, T, nu)`` controls, one per env step, inside the control range.
        """
        skip = self.layout.frame_skip
        ctrl = physics_controls(controls, skip)
        outputs = {}
        if self.model.nsensordata:
            outputs["sensordata"] = np.empty((len(ctrl), ctrl.shape[1], self.model.nsensordata))
        if self.constraint.uses_states or self.layout.episode_end is not None:
            outputs["state"] = np.empty((len(ctrl), ctrl.shape[1], states.shape[1]))
        self._rollout(states, ctrl, **outputs)
        m, t = controls.shape[:2]
        boundaries = outputs.get("sensordata", np.empty((m, ctrl.shape[1], 0)))[:, ::skip]
        after = outputs["state"][:, skip - 1 :: skip][:, :t] if "state" in outputs else np.empty(0)
        before = np.concatenate([states[:, None], after[:, :-1]], axis=1) if "state" in outputs else np.empty(0)
        return ConstraintSteps(self.model, before, after, boundaries[:, :-1], boundaries[:, 1:], self._dt)

    def next_states(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Full physics states after one env step of ``actions`` ``(M, nu)`` from ``states``, as rebuilt states are
        (time and the excluded positions 0)."""
        skip = self.layout.frame_skip
        ctrl = np.ascontiguousarray(np.repeat(actions[:, None], skip, axis=1))
        trajectory = np.empty((len(ctrl), skip, len(states[0])))
        self._rollout(states, ctrl, state=trajectory)
        return self.layout.at_origin(trajectory[:, -1])

    def next_observations(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """State observations ``[qpos[k:], qvel]`` after one env step of ``actions`` ``(M, nu)`` from ``states``, as the
        env reports them."""
        return self.layout.obs_from_states(self.next_states(states, actions))

    def discounted_cost(self, steps: ConstraintSteps) -> np.ndarray:
        """``J = Σ_t γ^(t+1) ĉ_(t+1)`` (eq. 18) with the absorbing tail ``γ^(t+1)/(1-γ)`` at the first violation, and
        ``γ^(t+1) (1 + depth / α)`` for each later step still in the unsafe set; the same again for the set of steps
        that cost, where the constraint keeps out of more (see the class).

        :param steps: ``(..., T)`` rolled env steps.
        :return: ``(...)`` discounted costs, ``>= 0``.
        """
        costs = self.constraint.assess(steps)
        unsafe = np.asarray(costs.unsafe, dtype=bool)
        live = np.ones_like(unsafe)
        end = self.layout.episode_end
        if end is not None:  # nothing costs after the step that ends the episode (a fall)
            live = none_before(end.ended(steps.qpos(steps.after), steps.qvel(steps.after)))
        discount = self.gamma ** np.arange(1, unsafe.shape[-1] + 1)
        shaped = shaped_cost(costs.distance, self.alpha) * discount
        cost = np.sum(np.where(none_before(unsafe) & ~unsafe & live, shaped, 0.0), axis=-1)
        cost += self.violation_cost(unsafe, costs.depth, live, discount)
        if costs.costly is not None:
            cost += self.violation_cost(np.asarray(costs.costly[0], dtype=bool), costs.costly[1], live, discount)
        return cost

    def violation_cost(
        self, unsafe: np.ndarray, depth: np.ndarray | float, live: np.ndarray, discount: np.ndarray
    ) -> np.ndarray:
        """``(...)`` the absorbing tail at the first of the ``(..., T)`` ``unsafe`` steps, and ``1 + depth / α`` for
        each later one, discounted by ``discount`` ``(T,)``, over the ``live`` steps."""
        first = none_before(unsafe)
        depth = np.asarray(depth) / (self.alpha if self.alpha > 0 else 1.0)
        step = np.where(first, discount / (1.0 - self.gamma), discount * (1.0 + depth))
        return np.sum(np.where(unsafe & live, step, 0.0), axis=-1)

    def plan_costs(self, states: np.ndarray, plans: np.ndarray, first_action: np.ndarray | None = None) -> np.ndarray:
        """``J`` of each rollout "``first_action`` (if given), then ``plans``" from ``states``.

        :param states: ``(M, nstate)`` full physics states.
        :param plans: ``(M, K, L, nu)`` ``K`` plans per state, or ``(M, L, nu)`` one.
        :param first_action: ``(M, nu)`` a fixed first action, or ``None``.
        :return: ``(M, K)`` or ``(M,)`` costs.
        """
        shape = plans.shape[:-2]
        if plans.size == 0:
            return np.zeros(shape)
        plans = plans.reshape(len(states), -1, *plans.shape[-2:])
        if first_action is not None:
            prefix = np.broadcast_to(first_action[:, None, None, :], (*plans.shape[:2], 1, plans.shape[-1]))
            plans = np.concatenate([prefix, plans], axis=2)
        k = plans.shape[1]
        steps = self.rollout_steps(np.repeat(states, k, axis=0), plans.reshape(-1, *plans.shape[2:]))
        return self.discounted_cost(steps).reshape(shape)

    def particles(self, nominal: np.ndarray, count: int | None = None) -> np.ndarray:
        """The first ``count`` (default: all ``N``) MPPI particles ``clip(W + σ·ε_i)`` around ``nominal`` ``(M, L, nu)``.

        The ``Q̄`` solves (``L = H - 1``, around ``W[1:]``) perturb with ``ε_i[1:]``, as ``ζ``'s solve perturbs ``W``
        with ``ε_i``: :return: ``(M, count, L, nu)``, particle 0 being ``nominal`` itself.
        """
        noise = self.noise[:count, self.horizon - nominal.shape[1] :]
        return np.clip(nominal[:, None] + noise[None], self.action_low, self.action_high)

    def solve(
        self,
        states: np.ndarray,
        nominal: np.ndarray,
        first_action: np.ndarray | None = None,
        scored: np.ndarray | None = None,
    ) -> MPCSolution:
        """The MPC: one MPPI iteration around ``nominal``; of the MPPI plan and the best particle, the one with lower ``J``.

        The weighted mean of a few good particles can be worse than each of them (with the thigh 2 cm from its limit
        it often is): keeping the better of the two makes ``J`` never worse than the nominal plan's (particle 0).
        ``M·(N + 1)`` rollouts in two calls; each state's answer does not depend on the others of the batch.

        :param states: ``(M, nstate)`` full physics states.
        :param nominal: ``(M, L, nu)`` nominal plans inside the control range (``L = H``, or ``H - 1`` after a first
            action).
        :param first_action: ``(M, nu)`` a fixed first action, or ``None``.
        :param scored: ``(M, K)`` the ``J`` of the first ``K`` particles, already rolled (certificates); they are
            not rolled again.
        """
        m = len(nominal)
        if m == 0:
            return MPCSolution(nominal.copy(), np.zeros(0), np.zeros(0, dtype=bool), np.zeros((0, self.n_particles)))
        particles = self.particles(nominal)
        scored = np.zeros((m, 0)) if scored is None else scored
        scores = np.concatenate([scored, self.plan_costs(states, particles[:, scored.shape[1] :], first_action)], axis=1)
        weights = np.exp(-(scores - scores.min(axis=1, keepdims=True)) / self.temperature)
        weights /= weights.sum(axis=1, keepdims=True)
        mppi = np.clip(np.sum(weights[:, :, None, None] * particles, axis=1), self.action_low, self.action_high)
        mppi_cost = self.plan_costs(states, mppi, first_action)
        best = scores.argmin(axis=1)
        best_cost = scores[np.arange(m), best]
        is_particle = mppi_cost >= best_cost
        plans = np.where(is_particle[:, None, None], particles[np.arange(m), best], mppi)
        return MPCSolution(plans, np.where(is_particle, best_cost, mppi_cost), is_particle, scores)

    def first_certifying(self, costs: np.ndarray) -> np.ndarray:
        """Per row of ``costs`` ``(M, K)``, the index of the first ``J <= η``; ``K`` where there is none."""
        below = np.concatenate([costs <= self.eta, np.ones((len(costs), 1), dtype=bool)], axis=1)
        return np.argmax(below, axis=1)

    def certify_in_chunks(
        self, states: np.ndarray, candidates: np.ndarray, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`first_certifying` of "``a``, then each candidate", rolling the candidates a few at a time and
        stopping for each state at its first certificate: the same answer as rolling them all, in fewer rollouts.

        :param candidates: ``(M, K, L, nu)`` plans after ``actions``.
        :return: ``(M,)`` the first certifying index (``K``: none) and ``(M, K)`` the costs (NaN where not rolled;
            complete for the states none certified).
        """
        m, k = candidates.shape[:2]
        costs = np.full((m, k), np.nan)
        first = np.full(m, k)
        for start in range(0, k, CERTIFICATE_CHUNK):
            open_ = np.flatnonzero(first == k)
            chunk = slice(start, start + CERTIFICATE_CHUNK)
            costs[open_, chunk] = self.plan_costs(states[open_], candidates[open_, chunk], actions[open_])
            found = self.first_certifying(costs[open_, chunk])
            certified = found < costs[open_, chunk].shape[1]
            first[open_[certified]] = start + found[certified]
        return first, costs

    def certificate_candidates(self, warm: np.ndarray) -> np.ndarray:
        """``(M, 1 + certificate_particles, H - 1, nu)``: ``W[1:]`` and the next particles of ``Q̄(s, a)``'s solve."""
        return self.particles(warm[:, 1:], 1 + self.certificate_particles)

    def nearest_accepted(
        self, proposals: np.ndarray, warm: np.ndarray, zeta: MPCSolution
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The accepted action nearest each rejected proposal (``permissive``), from ``ζ``'s solve around ``warm``.

        Particle ``i`` of ``ζ``'s solve is ``c_i`` followed by particle ``i`` of ``Q̄(s, c_i)``'s solve (the same noise,
        shifted), so ``Q̄(s, c_i) <= J_i`` and, ``Q̄ >= 0``, ``Ā(s, c_i) <= J_i``: where ``J_i <= η`` the rule accepts
        ``c_i``. Of those and ``ζ(s)``, the nearest to the proposal in units of the control range is executed.

        :param proposals: ``(M, nu)`` the rejected proposals (clipped to the control range).
        :param warm: ``(M, H, nu)`` the warm plans ``ζ``'s solve was around.
        :param zeta: that solve.
        :return: ``(M, nu)`` the actions to execute, ``(M, H - 1, nu)`` the plans to follow after them, and ``(M,)``
            where the action is an edit (not ``ζ(s)``).
        """
        particles = self.particles(warm)
        span = self.action_high - self.action_low
        distance = np.linalg.norm((particles[:, :, 0] - proposals[:, None]) / span, axis=-1)
        distance = np.where(zeta.scores <= self.eta, distance, np.inf)
        nearest = distance.argmin(axis=1)
        rows = np.arange(len(proposals))
        edited = distance[rows, nearest] < np.linalg.norm((zeta.plans[:, 0] - proposals) / span, axis=-1)
        chosen = particles[rows, nearest]
        actions = np.where(edited[:, None], chosen[:, 0], zeta.plans[:, 0])
        return actions, np.where(edited[:, None, None], chosen[:, 1:], zeta.plans[:, 1:]), edited

    def _edit_rejected(
        self, rows: np.ndarray, actions: np.ndarray, warm: np.ndarray, zeta: MPCSolution, step: dict[str, np.ndarray]
    ) -> None:
        """Where ``permissive``, replace the backup's action and plan by the nearest accepted edit in ``rows`` of
        ``step`` (``backup``, ``tails``, ``edited``), whose ``ζ`` solve is ``zeta``."""
        if not self.permissive or len(rows) == 0:
            return
        executed, tails, edited = self.nearest_accepted(actions[rows], warm[rows], zeta)
        step["backup"][rows], step["tails"][rows], step["edited"][rows] = executed, tails, edited

    # --- the rule -----------------------------------------------------------------------------------------------

    def tracked_states(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The physics states of ``obs``, whether each is known, the warm plans and the warm-start entries used.

        A state is rebuilt from its observation; where the observation does not determine it (a velocity the env
        clipped), it is the state the rule predicted for that observation when it shielded the step before (the
        rule's model is the env's, so the prediction is the env's next state up to rounding); with no such
        prediction it is unknown.
        """
        warm, used, predicted = self.warm_starts.lookup(self._state_obs(obs))
        states = self.layout.states_from_obs(self.model, obs)
        known = self.layout.known_states(obs)
        tracked = ~known & (used >= 0)
        if tracked.any():
            states[tracked] = predicted[tracked]
        return states, known | tracked, warm, used

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        """``ζ(s)``: the first action of the MPC plan from ``s`` (around the warm plan stored for ``s``)."""
        states, _, warm, _ = self.tracked_states(obs)
        return self.solve(states, warm).plans[:, 0]

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)``: ``J`` of "take ``a``, then the MPC plan re-solved from ``ŝ_1``" (around the warm plan's tail)."""
        states, known, warm, _ = self.tracked_states(obs)
        costs = self.solve(states, warm[:, 1:], self._clipped(actions, len(obs))).costs
        return np.where(known, costs, np.nan)  # an unknown state: nothing is known of Q̄

    def shield(self, obs: np.ndarray, actions: np.ndarray) -> ShieldDecision:
        """Eq. 12 from the warm plans stored for ``obs``; stores the plans to follow from the next states.

        :param obs: ``(B, obs_dim)`` raw observations.
        :param actions: ``(B, nu)`` proposed actions.
        """
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        actions = np.asarray(actions, dtype=np.float64).reshape(len(obs), -1)
        states, known, warm, used = self.tracked_states(obs)
        clipped = self._clipped(actions, len(obs))
        step = (self._shield_certified if self.certify else self._shield_solved)(states, clipped, warm)
        executed = np.where(step.intervened[:, None], step.backup, clipped)
        next_states = self.next_states(states, executed)
        next_plans = np.concatenate([step.tails, np.zeros_like(step.tails[:, :1])], axis=1)
        self.warm_starts.replace(used, self.layout.obs_from_states(next_states), next_plans, next_states)
        self._count(len(obs), step)
        safe = np.where(step.intervened[:, None], step.backup, actions)
        # where the state is unknown, so is Ā: the guard of ShieldingRule.shield executes the backup there (fail closed)
        advantage = np.where(known, step.advantage, np.nan)
        return ShieldDecision(actions=safe, intervened=step.intervened, advantage=advantage, edited=step.edited)

    def _shield_solved(self, states: np.ndarray, actions: np.ndarray, warm: np.ndarray) -> ShieldStep:
        """The reference: ``Q̄(s, a)``, ``ζ(s)`` and ``Q̄(s, ζ(s))`` solved for every state, ``Ā`` exact.

        The plan after the executed action: ``ζ``'s plan's tail where shielded; else the first of the certificate
        candidates (:meth:`certificate_candidates`) with ``J([a, candidate]) <= η``; else the ``Q̄(s, a)`` solve's plan.
        """
        n = len(states)
        after_a = self.solve(states, warm[:, 1:], actions)
        zeta = self.solve(states, warm)
        backup_plan = zeta.plans
        backup_value = self.solve(states, warm[:, 1:], backup_plan[:, 0]).costs
        advantage = after_a.costs - backup_value
        intervened = in_shielding_set(advantage, self.eta)
        candidates = self.certificate_candidates(warm)
        first = self.first_certifying(self.plan_costs(states, candidates, actions))
        certified = first < candidates.shape[1]
        chosen = candidates[np.arange(n), np.minimum(first, candidates.shape[1] - 1)]
        tails = np.where(certified[:, None, None], chosen, after_a.plans)
        tails = np.where(intervened[:, None, None], backup_plan[:, 1:], tails)
        step = {"backup": backup_plan[:, 0].copy(), "tails": tails, "edited": np.zeros(n, dtype=bool)}
        shielded = np.flatnonzero(intervened)
        self._edit_rejected(
            shielded, actions, warm, zeta._replace(plans=zeta.plans[shielded], scores=zeta.scores[shielded]), step
        )
        return ShieldStep(step["backup"], intervened, advantage, step["tails"], n, n, n, step["edited"])

    def _shield_certified(self, states: np.ndarray, actions: np.ndarray, warm: np.ndarray) -> ShieldStep:
        """:meth:`_shield_solved`'s decisions and plans, solving only what the bounds on ``Ā`` leave open.

        1. ``Ā(s, a) <= Q̄(s, a) <= J([a, c])`` for every particle ``c`` of ``Q̄(s, a)``'s solve (``J >= 0``, and the
           solve does no worse than its best particle). Roll ``[a, W[1:]]`` (particle 0); where its ``J > η``, the
           next ``certificate_particles`` particles, a few at a time: where one has ``J <= η``, keep ``a`` and follow
           the first that does.
        2. Else solve ``Q̄(s, a)`` (its particles already rolled in 1 are not rolled again): where ``<= η``, keep ``a``
           and follow the solve's plan.
        3. Else solve ``ζ(s)`` and bound ``Q̄(s, ζ(s))`` from above by two of its solve's candidates, ``W[1:]`` and,
           when ``ζ``'s plan is a particle, that plan's tail (then ``J([ζ, tail])`` is ``ζ``'s plan's own ``J``):
           where ``Q̄(s, a) - bound > η``, ``Ā > η``: shield.
        4. Else solve ``Q̄(s, ζ(s))``: ``Ā`` exact.

        The advantage reported is the bound that decided (an upper bound ``<= η`` in 1-2, a lower bound ``> η`` in 3).
        """
        candidates = self.certificate_candidates(warm)
        advantage = self.plan_costs(states, candidates[:, 0], actions)
        tails = candidates[:, 0].copy()
        backup = actions.copy()
        intervened = np.zeros(len(states), dtype=bool)

        open_ = np.flatnonzero(advantage > self.eta)
        first, costs = self.certify_in_chunks(states[open_], candidates[open_, 1:], actions[open_])
        certified = first < costs.shape[1]
        done, first = open_[certified], first[certified]
        advantage[done], tails[done] = costs[certified, first], candidates[done, 1 + first]

        scored = np.concatenate([advantage[open_[~certified], None], costs[~certified]], axis=1)  # its first particles
        open_ = open_[~certified]
        after_a = self.solve(states[open_], warm[open_, 1:], actions[open_], scored=scored)
        advantage[open_], tails[open_] = after_a.costs, after_a.plans
        q_solves = len(open_)

        open_ = open_[after_a.costs > self.eta]
        q_a = advantage[open_]
        solved_zeta, zeta = open_, self.solve(states[open_], warm[open_])
        backup[open_] = zeta.plans[:, 0]
        bound = self.plan_costs(states[open_], warm[open_, 1:], backup[open_])
        bound = np.where(zeta.is_particle, np.minimum(bound, zeta.costs), bound)
        advantage[open_] = q_a - bound
        decided = in_shielding_set(advantage[open_], self.eta)
        intervened[open_[decided]] = True
        tails[open_] = np.where(decided[:, None, None], zeta.plans[:, 1:], tails[open_])
        backup_solves = len(open_)

        open_, zeta_plans, q_a = open_[~decided], zeta.plans[~decided], q_a[~decided]
        backup_value_solves = len(open_)
        advantage[open_] = q_a - self.solve(states[open_], warm[open_, 1:], backup[open_]).costs
        shielded = in_shielding_set(advantage[open_], self.eta)
        intervened[open_] = shielded
        tails[open_] = np.where(shielded[:, None, None], zeta_plans[:, 1:], tails[open_])
        step = {"backup": backup, "tails": tails, "edited": np.zeros(len(states), dtype=bool)}
        rejected = intervened[solved_zeta]  # every rejected row solved ζ in 3
        zeta = zeta._replace(plans=zeta.plans[rejected], scores=zeta.scores[rejected])
        self._edit_rejected(solved_zeta[rejected], actions, warm, zeta, step)
        return ShieldStep(
            step["backup"], intervened, advantage, step["tails"], q_solves, backup_solves, backup_value_solves, step["edited"]
        )

    def _count(self, steps: int, step: ShieldStep) -> None:
        """Add a call's figures to :attr:`solve_counts`."""
        self.solve_counts.steps += steps
        self.solve_counts.q_solves += step.q_solves
        self.solve_counts.backup_solves += step.backup_solves
        self.solve_counts.backup_value_solves += step.backup_value_solves

    def _clipped(self, actions: np.ndarray, n: int) -> np.ndarray:
        """``n`` actions as ``(n, nu)`` floats clipped to the control range (what MuJoCo executes)."""
        return np.clip(np.asarray(actions, dtype=np.float64).reshape(n, -1), self.action_low, self.action_high)

    def _state_obs(self, obs: np.ndarray) -> np.ndarray:
        """The entries of raw observations that hold the state (the warm plans' keys)."""
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        return np.ascontiguousarray(obs[:, : self.layout.state_obs_dim])
