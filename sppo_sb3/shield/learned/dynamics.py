"""A shielding rule with a learned model: ``Q̄`` rolled out on dynamics fitted to the real transitions of ``B``.

For tasks without a model (Alg. 1 line 12). The user knows what makes a state unsafe (the functions behind their
``info["cost"]`` and ``info["shaped_cost"]``) and a backup ``ζ``; the dynamics are learned. Unlike a cost critic
(:class:`~sppo_sb3.shield.learned.critic.LearnedCostCriticRule`), a dynamics model learns from every transition, none of
which has to be a violation, and ``Q̄(s, a)`` and ``Q̄(s, ζ(s))`` are rolled on the same model, so the shield
compares the two actions on one footing.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.utils import get_device
from torch import nn

from sppo_sb3.common.costs import shaped_cost
from sppo_sb3.common.networks import mlp
from sppo_sb3.shield.base import advantage_from_values
from sppo_sb3.shield.learned.base import OBS_EPSILON, BackupPolicy, CostTransitions, RefinableRule

StateFunction = Callable[[np.ndarray], np.ndarray]


class LearnedDynamicsRule(RefinableRule):
    """``Q̄(s, a) = Σ_t γ^(t+1) ĉ(ŝ_(t+1))`` along "``a``, then ``ζ``" on a learned model ``ŝ' = s + f(s, a)``.

    The sum runs ``horizon`` steps and is absorbed where the model's state enters the unsafe set (``ĉ = 1`` forever:
    ``γ^(t+1) / (1 - γ)``), as the model-based rules' (eq. 18's shaped cost, on the shaped scale). ``f`` is an MLP on
    standardised ``[s, a]`` predicting the standardised change of the observation, fitted by least squares on real
    transitions (:meth:`update`; SPPO calls :meth:`refine` on ``B`` every training round, ``refine_shield="auto"``).
    Before it has learned anything it predicts no change, so nothing is shielded that was not unsafe already.

    **What it keeps.** With a model of one-step error ``ε`` the rolled ``Q̄`` is within some ``δ`` of the true
    ``Q̄^ζ``, and by Proposition 2.3 the rule is ``(β + (1 + γ)δ)``-adoptable; ``δ`` is measured, not bounded
    (:mod:`sppo_sb3.shield.analysis`). Both terms of ``Ā`` are rolled on the same model in batches of one shape, so
    ``Ā(s, ζ(s)) = 0`` exactly and the backup is never shielded (Proposition 1).

    :param observation_space: the env's flat Box observation space; the rule reads raw observations.
    :param action_space: the env's Box action space.
    :param backup_policy: the known backup ``ζ``: ``(B, obs_dim)`` observations → ``(B, act_dim)`` actions in env
        units; it must accept the model's predicted observations.
    :param is_unsafe: ``(B, obs_dim)`` observations → ``(B,)`` booleans: in the unsafe set.
    :param distance: ``(B, obs_dim)`` observations → ``(B,)`` distances to the unsafe set (0 inside), for eq. 18.
    :param alpha: band of eq. 18 on ``distance``.
    :param gamma: discount of ``Q̄``.
    :param horizon: steps of each rollout: long enough for ``ζ`` to make any state safe for good (e.g. to stop).
    :param eta: advantage threshold ``η >= 0`` (shaped scale).
    :param net_arch: hidden layer sizes of the dynamics MLP (ELU).
    :param lr: Adam learning rate.
    :param device: torch device (``"auto"``: CUDA when available).
    :param seed: seeds the model's initial weights and the minibatch sampling (``None``: not seeded).
    """

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Space,
        backup_policy: BackupPolicy,
        is_unsafe: StateFunction,
        distance: StateFunction,
        alpha: float,
        gamma: float = 0.99,
        horizon: int = 30,
        eta: float = 0.0,
        net_arch: Sequence[int] = (128, 128),
        lr: float = 1e-3,
        device: th.device | str = "auto",
        seed: int | None = None,
    ) -> None:
        super().__init__(observation_space, action_space, backup_policy, gamma, eta, seed)
        for name, function in (("is_unsafe", is_unsafe), ("distance", distance)):
            if not callable(function):
                raise TypeError(f"{name} must be a callable of observations (B, obs_dim) -> (B,), got {function!r}.")
        if alpha < 0:
            raise ValueError(f"alpha is the band of eq. 18, >= 0; got {alpha}.")
        if horizon < 1:
            raise ValueError(f"horizon must be at least 1 step, got {horizon}.")
        self.is_unsafe, self.distance = is_unsafe, distance
        self.alpha, self.horizon = float(alpha), int(horizon)
        self.net_arch, self.lr, self.device = tuple(int(n) for n in net_arch), float(lr), get_device(device)
        self.delta_rms = RunningMeanStd(shape=(self.obs_dim,))
        with th.random.fork_rng(devices=[]):
            if seed is not None:
                th.manual_seed(seed)
            self.model = self._build_model()
        self.optimizer = th.optim.Adam(self.model.parameters(), lr=self.lr)

    def _build_model(self) -> nn.Sequential:
        """Before learning it predicts no change (a zero head), so ``ŝ' = s``: nothing new is shielded."""
        return mlp(self.obs_dim + self.act_dim, self.net_arch, self.obs_dim, nn.ELU, zero_head=True).to(self.device)

    # ----------------------------------------------------------------------------------------------- the model
    def _inputs(self, obs: np.ndarray, actions: np.ndarray) -> th.Tensor:
        """Model input: :meth:`scaled_inputs` of the actions clipped to the action space, as a float32 tensor."""
        actions = np.clip(actions, self.action_space.low, self.action_space.high)  # as the env clips them
        return th.as_tensor(self.scaled_inputs(obs, actions), dtype=th.float32, device=self.device)

    def predict_next(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The model's next observations ``ŝ' = s + f(s, a)``: ``(B, obs_dim)``, ``(B, act_dim)`` → ``(B, obs_dim)``."""
        obs, actions = self.flat_pairs(obs, actions)
        with th.no_grad():
            change = self.model(self._inputs(obs, actions)).cpu().numpy().astype(np.float64)
        return obs + self.delta_rms.mean + change * np.sqrt(self.delta_rms.var + OBS_EPSILON)

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` rolled on the model for :attr:`horizon` steps (see the class docstring)."""
        state = self.predict_next(obs, actions)
        q, running = np.zeros(len(state)), np.ones(len(state), dtype=bool)
        forever = 1.0 / (1.0 - self.gamma)
        for t in range(self.horizon):
            unsafe = np.asarray(self.is_unsafe(state), dtype=bool)
            cost = np.where(unsafe, forever, shaped_cost(np.asarray(self.distance(state), dtype=np.float64), self.alpha))
            q += running * self.gamma ** (t + 1) * cost
            running &= ~unsafe
            if not running.any():
                break
            state = self.predict_next(state, self.backup_action(state))
        return q

    def advantage(self, obs: np.ndarray, actions: np.ndarray, backup: np.ndarray | None = None) -> np.ndarray:
        """``Ā(s, a)``, its two terms rolled in two batches of the same shape, so that ``Ā(s, ζ(s)) = 0`` exactly."""
        if backup is None:
            backup = self.backup_action(obs)
        return advantage_from_values(self.cost_value(obs, actions), self.cost_value(obs, backup))

    # ----------------------------------------------------------------------------------------------- learning
    def update(
        self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray, gradient_steps: int = 1, batch_size: int = 256
    ) -> float:
        """Fit the dynamics on real transitions ``(s, a, s')`` by least squares on the standardised change.

        The running statistics of the observations and of their changes first take in the transitions.

        :param obs: ``(N, obs_dim)`` raw observations.
        :param actions: ``(N, act_dim)`` executed actions in env units.
        :param next_obs: ``(N, obs_dim)`` the real next observations (the terminal one where an episode ended).
        :param gradient_steps: number of gradient steps.
        :param batch_size: minibatch size of each step.
        :return: the mean squared error of the standardised change over the gradient steps.
        """
        obs, actions = self.flat_pairs(obs, actions)
        next_obs = np.asarray(next_obs, dtype=np.float64).reshape(len(obs), -1)
        if len(obs) == 0 or next_obs.shape != obs.shape:
            raise ValueError(f"update() needs non-empty obs and next_obs of one shape, got {obs.shape} and {next_obs.shape}.")
        self.obs_rms.update(obs)
        self.delta_rms.update(next_obs - obs)
        target = th.as_tensor(
            (next_obs - obs - self.delta_rms.mean) / np.sqrt(self.delta_rms.var + OBS_EPSILON),
            dtype=th.float32,
            device=self.device,
        )
        inputs = self._inputs(obs, actions)
        losses = []
        for _ in range(gradient_steps):
            idx = th.as_tensor(self.minibatch(len(obs), batch_size), device=self.device)
            loss = nn.functional.mse_loss(self.model(inputs[idx]), target[idx])
            self.optimizer.zero_grad()
            loss.backward()
            self.optimizer.step()
            losses.append(loss.item())
        return float(np.mean(losses)) if losses else 0.0

    def refine(self, transitions: CostTransitions, batch_size: int) -> float:
        """One gradient step of :meth:`update` on a minibatch of ``B`` (the costs are the user's functions': unused)."""
        return self.update(transitions.observations, transitions.actions, transitions.next_observations, 1, batch_size)

    # ----------------------------------------------------------------------------------------------- persistence
    def state_dict(self) -> dict[str, Any]:
        """Model and optimiser states and the statistics they are read with (``torch.save``-able).

        The backup and the constraint's functions are code, not state: pass them again to the constructor.
        """
        return {
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "obs_rms": copy.deepcopy(self.obs_rms),
            "delta_rms": copy.deepcopy(self.delta_rms),
            "shape": (self.obs_dim, self.act_dim, self.net_arch),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a :meth:`state_dict` saved by a rule of the same spaces and ``net_arch``.

        :raises ValueError: a model of other spaces or another architecture.
        """
        if tuple(state["shape"]) != (self.obs_dim, self.act_dim, self.net_arch):
            raise ValueError(
                f"Cannot load a dynamics model for obs_dim, act_dim, net_arch = {tuple(state['shape'])} into a rule built "
                f"for {(self.obs_dim, self.act_dim, self.net_arch)}: construct the rule with the same spaces and net_arch."
            )
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.obs_rms, self.delta_rms = copy.deepcopy(state["obs_rms"]), copy.deepcopy(state["delta_rms"])
