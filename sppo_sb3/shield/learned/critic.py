"""A learned shielding rule for tasks without a model: ``Q̄`` is a cost critic fitted on real transitions.

This is Alg. 1 line 12 (``G ← UpdateShieldingRule(B)``, optional): the backup policy ``ζ`` must be known (it is the
user's safe fallback, e.g. "brake"); only ``Q̄`` — the discounted shaped cost of taking ``a`` and following ``ζ``
afterwards — is learned, by fitted policy evaluation of ``ζ`` on the transitions of the real buffer ``B``.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any, ClassVar, Literal

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn

from sppo_sb3.common.networks import mlp
from sppo_sb3.shield.base import advantage_from_values
from sppo_sb3.shield.learned.base import INITIAL_LOGIT, BackupPolicy, CostTransitions, RefinableRule


def definition2_step_costs(shaped_costs: np.ndarray, violations: np.ndarray, gamma: float) -> np.ndarray:
    """The per-step costs whose backup targets give ``Q̄`` on Definition 2's scale, for :meth:`LearnedCostCriticRule.update`.

    The model-based rules' ``Q̄`` times ``1 - γ`` satisfies ``Q̄(s, a) = γ (1 - γ) ĉ(s') + γ Q̄(s', ζ(s'))`` while ``s'``
    is safe, and ``Q̄(s, a) = γ`` where ``s'`` is unsafe (the absorbing tail ``γ / (1 - γ)`` times ``1 - γ``). So the
    step cost is ``γ (1 - γ) ĉ`` on safe steps and ``γ`` on a violating step (which must be passed as done).

    :param shaped_costs: ``ĉ`` of eq. 18 of each step (``info["shaped_cost"]``).
    :param violations: the violation indicator ``c`` of each step (``info["cost"]``).
    :param gamma: discount of ``Q̄``.
    """
    shaped_costs = np.asarray(shaped_costs, dtype=np.float64)
    return np.where(np.asarray(violations) > 0, gamma, gamma * (1.0 - gamma) * shaped_costs)


class LearnedCostCriticRule(RefinableRule):
    """Shielding rule ``G = (Q̄, ζ, Ā, η, I)`` with a known backup ``ζ`` and an MLP cost critic ``Q̄(s, a)``.

    ``Q̄`` is fitted by the backup's Bellman targets on real transitions ``(s, a, ĉ, s', done)`` of the buffer ``B``:

    ``Q̄(s, a) ← min(ĉ(s, a) + γ·(1 - done)·Q̄⁻(s', ζ(s')), γ)``

    where ``Q̄⁻`` is an EMA target copy of the critic. The critic's output lies in ``(0, γ)``, the range of
    Definition 2 (a β-adoptable rule), by construction: ``Q̄ = γ·σ(f(s, a))``, fitted by the cross-entropy of
    ``σ(f)`` and ``target / γ``. So no target is clipped at 0: a critic's noise around 0 averages out instead of only
    ever pushing the targets up, which compounds over the backups at ``γ`` close to 1. The loss is a proper scoring
    rule, so its minimiser is the mean target, as least squares'. By Proposition 2.3 a critic within ``δ`` of an
    adoptable ``Q̄`` gives a ``(β + (1 + γ)δ)``-adoptable rule. With ``η >= 0`` the backup action is never shielded
    (Proposition 1) whatever the weights are: :meth:`advantage` evaluates ``Q̄(s, a)`` and ``Q̄(s, ζ(s))`` in two
    forward passes of the same shape, so that ``a = ζ(s)`` gives ``Ā = 0`` exactly.

    **The shaped cost it expects** (``shaped_costs`` of :meth:`update`): ``ĉ`` of eq. 18 for the step,
    ``ĉ = 1[dist = 0]`` if ``α = 0`` else ``max(0, 1 - dist / α)``, with ``dist`` the distance from the state the
    step leads to (``s'``) to the unsafe set — e.g. ``info["shaped_cost"]`` of ``SafePointCircle-v0``. A step that
    enters the unsafe set has ``ĉ = 1`` and must be passed with ``done = True`` (the unsafe set is absorbing).
    Because values are capped at ``γ``, a wide band ``α`` saturates ``Q̄`` near the unsafe set, where the shield then
    cannot rank actions any more (``Ā = 0``): prefer ``α = 0`` or a narrow band, or pass
    :func:`definition2_step_costs` (``γ (1 - γ) ĉ``, and ``γ`` on a violation), which gives the model-based rules'
    ``Q̄`` on Definition 2's scale; SPPO (``refine_shield="auto"``) does. ``done`` must be termination only, not a
    time-limit truncation.

    A learned ``Q̄`` carries approximation error, so with ``η = 0`` tiny positive ``Ā`` between equally safe actions
    get shielded: choose ``η`` above the critic's error (the paper uses ``η = 0.2`` where ``Q̄`` is approximate).

    Observations are standardised by their running mean and standard deviation over the transitions :meth:`update`
    has seen (the bounds of an observation space are often far wider than the states a task visits); actions are
    rescaled to ``[-1, 1]`` by the action space's bounds.

    :param observation_space: the env's (flat, Box) observation space; the rule reads raw observations.
    :param action_space: the env's Box action space.
    :param backup_policy: the known backup ``ζ``: ``obs`` ``(B, obs_dim)`` ndarray → ``(B, act_dim)`` ndarray of actions
        in the env's action units, inside the action space.
    :param gamma: discount of ``Q̄``; also the upper bound of Definition 2.
    :param eta: advantage threshold ``η >= 0``.
    :param net_arch: hidden layer sizes of the critic MLP (ReLU).
    :param lr: Adam learning rate.
    :param tau: EMA coefficient of the target critic, applied after every gradient step. Each backup carries a cost
        one step back along ``ζ``'s path, so a danger ``H`` backup steps ahead needs about ``H / tau`` gradient steps to
        reach ``Q̄``.
    :param device: torch device (``"auto"``: CUDA when available).
    :param seed: seeds the critic's initial weights and the minibatch sampling (``None``: not seeded).
    """

    value_scale: ClassVar[Literal["shaped", "definition2"]] = "definition2"

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Space,
        backup_policy: BackupPolicy,
        gamma: float = 0.99,
        eta: float = 0.0,
        net_arch: Sequence[int] = (64, 64),
        lr: float = 1e-3,
        tau: float = 0.01,
        device: th.device | str = "auto",
        seed: int | None = None,
    ) -> None:
        super().__init__(observation_space, action_space, backup_policy, gamma, eta, seed)
        if not 0.0 < tau <= 1.0:
            raise ValueError(f"tau must be in (0, 1], got {tau}.")
        self.tau = float(tau)
        self.net_arch = tuple(int(n) for n in net_arch)
        self.lr = float(lr)
        self.device = get_device(device)

        if seed is None:
            self.critic = self._build_critic()
        else:
            with th.random.fork_rng(devices=[]):
                th.manual_seed(seed)
                self.critic = self._build_critic()
        self.critic_target = copy.deepcopy(self.critic)
        self.critic_target.requires_grad_(False)
        self.optimizer = th.optim.Adam(self.critic.parameters(), lr=self.lr)

    def _build_critic(self) -> nn.Sequential:
        critic = mlp(self.obs_dim + self.act_dim, self.net_arch, 1, nn.ReLU, zero_head=True).to(self.device)
        # a constant output before learning (as TD-MPC's zero-initialised Q heads): Ā ≡ 0, nothing is shielded yet, and
        # Q̄ starts near 0, so no initial bias has to be unlearnt at the slow rate γ per backup
        head = critic[-1]
        assert isinstance(head, nn.Linear)
        nn.init.constant_(head.bias, INITIAL_LOGIT)
        return critic

    # ----------------------------------------------------------------------------------------------- evaluation
    def _inputs(self, obs: np.ndarray, actions: np.ndarray) -> th.Tensor:
        """Critic input :meth:`scaled_inputs` as a float32 tensor."""
        obs, actions = self.flat_pairs(obs, actions)
        return th.as_tensor(self.scaled_inputs(obs, actions), dtype=th.float32, device=self.device)

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a) = γ·σ(f(s, a)) ∈ [0, γ]`` of the critic for a batch: ``(B, obs_dim)``, ``(B, act_dim)`` → ``(B,)``."""
        with th.no_grad():
            logits = self.critic(self._inputs(obs, actions)).squeeze(-1).cpu().numpy().astype(np.float64)
        return self.gamma / (1.0 + np.exp(-logits))  # in float64: a float32 γ·σ would round above γ

    def advantage(self, obs: np.ndarray, actions: np.ndarray, backup: np.ndarray | None = None) -> np.ndarray:
        """``Ā(s, a) = Q̄(s, a) - Q̄(s, ζ(s))``.

        Unlike the base class, the two terms come from two forward passes of the same batch shape: a concatenated
        batch may compute a row differently depending on its position, and ``Ā(s, ζ(s))`` must be exactly 0 for
        Proposition 1 to hold.
        """
        if backup is None:
            backup = self.backup_action(obs)
        return advantage_from_values(self.cost_value(obs, actions), self.cost_value(obs, backup))

    # ----------------------------------------------------------------------------------------------- learning
    def update(
        self,
        obs: np.ndarray,
        actions: np.ndarray,
        shaped_costs: np.ndarray,
        next_obs: np.ndarray,
        dones: np.ndarray,
        gradient_steps: int = 1,
        batch_size: int = 256,
    ) -> float:
        """Fit ``Q̄`` on real transitions of ``B`` (Alg. 1 line 12) with the backup's Bellman targets.

        The observations' running statistics first take in ``obs``. Each gradient step fits ``Q̄(s, a)`` to
        ``min(ĉ + γ·(1 - done)·Q̄⁻(s', ζ(s')), γ)`` (cross-entropy on the scale ``Q̄ / γ``) over a minibatch of
        ``batch_size`` transitions drawn from the given arrays (all of them when there are fewer), then moves the
        target critic ``Q̄⁻`` by EMA with ``tau``.

        :param obs: ``(N, obs_dim)`` raw observations ``s``.
        :param actions: ``(N, act_dim)`` executed actions ``a`` (the safe ones), in env action units.
        :param shaped_costs: ``(N,)`` shaped costs ``ĉ`` of eq. 18 of each step (see the class docstring).
        :param next_obs: ``(N, obs_dim)`` next observations ``s'``.
        :param dones: ``(N,)`` terminations (entering the unsafe set); not time-limit truncations.
        :param gradient_steps: number of gradient steps.
        :param batch_size: minibatch size of each step.
        :return: the mean squared TD error of ``Q̄`` over the gradient steps.
        """
        n = len(obs)
        shaped_costs = np.asarray(shaped_costs, dtype=np.float64).reshape(-1)
        dones = np.asarray(dones, dtype=np.float64).reshape(-1)
        if not (len(actions) == len(next_obs) == len(shaped_costs) == len(dones) == n) or n == 0:
            raise ValueError(
                f"update() needs non-empty arrays of one length, got obs {len(obs)}, actions {len(actions)}, "
                f"shaped_costs {len(shaped_costs)}, next_obs {len(next_obs)}, dones {len(dones)}."
            )
        if not np.all(np.isfinite(shaped_costs)) or np.any(shaped_costs < 0):
            raise ValueError("shaped_costs must be finite and >= 0 (the shaped cost of eq. 18 lies in [0, 1]).")
        # ζ(s') is fixed during the update: compute it once for the whole batch
        next_backup = self.backup_action(next_obs)
        obs = np.asarray(obs, dtype=np.float64).reshape(n, -1)
        actions = np.asarray(actions, dtype=np.float64).reshape(n, -1)
        next_obs = np.asarray(next_obs, dtype=np.float64).reshape(n, -1)
        self.obs_rms.update(obs)
        costs_t = th.as_tensor(shaped_costs, dtype=th.float32, device=self.device)
        dones_t = th.as_tensor(dones, dtype=th.float32, device=self.device)

        losses = []
        for _ in range(gradient_steps):
            idx = self.minibatch(n, batch_size)
            with th.no_grad():
                next_q = self.gamma * th.sigmoid(self.critic_target(self._inputs(next_obs[idx], next_backup[idx])).squeeze(-1))
                target = (costs_t[idx] + self.gamma * (1.0 - dones_t[idx]) * next_q).clamp(max=self.gamma)
            logits = self.critic(self._inputs(obs[idx], actions[idx])).squeeze(-1)
            loss = nn.functional.binary_cross_entropy_with_logits(logits, target / self.gamma)
            self.optimizer.zero_grad()
            loss.backward()
            self.optimizer.step()
            with th.no_grad():
                for param, target_param in zip(self.critic.parameters(), self.critic_target.parameters()):
                    target_param.mul_(1.0 - self.tau).add_(param, alpha=self.tau)
                losses.append(float(((self.gamma * th.sigmoid(logits) - target) ** 2).mean()))
        return float(np.mean(losses)) if losses else 0.0

    def refine(self, transitions: CostTransitions, batch_size: int) -> float:
        """One :meth:`update` step on Definition 2's scale (:func:`definition2_step_costs`), a violation ending the roll."""
        t = transitions
        costs = definition2_step_costs(t.shaped_costs, t.violations, self.gamma)
        dones = np.maximum(np.asarray(t.terminations, dtype=np.float64), np.asarray(t.violations) > 0)
        return self.update(t.observations, t.actions, costs, t.next_observations, dones, 1, batch_size)

    # ----------------------------------------------------------------------------------------------- persistence
    def state_dict(self) -> dict[str, Any]:
        """Critic, target critic and optimiser states, the observations' statistics and the settings they depend on
        (``torch.save``-able).

        The backup policy is code, not state: pass it again to the constructor before :meth:`load_state_dict`.
        """
        return {
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "obs_mean": self.obs_rms.mean.copy(),
            "obs_var": self.obs_rms.var.copy(),
            "obs_count": self.obs_rms.count,
            "obs_dim": self.obs_dim,
            "act_dim": self.act_dim,
            "net_arch": self.net_arch,
            "gamma": self.gamma,
            "eta": self.eta,
            "tau": self.tau,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a :meth:`state_dict`; the rule must have been built for the same spaces and ``net_arch``.

        :raises ValueError: when the saved critic was built for other spaces or another architecture.
        """
        saved = (state.get("obs_dim"), state.get("act_dim"), tuple(state.get("net_arch", ())))
        if saved != (self.obs_dim, self.act_dim, self.net_arch):
            raise ValueError(
                f"Cannot load a cost critic for obs_dim, act_dim, net_arch = {saved} into a rule built for "
                f"{(self.obs_dim, self.act_dim, self.net_arch)}: construct the rule with the same spaces and net_arch."
            )
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.obs_rms.mean, self.obs_rms.var = np.array(state["obs_mean"]), np.array(state["obs_var"])
        self.obs_rms.count = float(state["obs_count"])
        self.gamma, self.eta, self.tau = float(state["gamma"]), float(state["eta"]), float(state["tau"])
