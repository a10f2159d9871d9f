"""A shielding rule on SPPO's own world model: ``Q̄`` rolled through TOLD's latent dynamics (Alg. 1 line 12).

SPPO already learns TOLD (eq. 9). For a task without a model, this rule gives TOLD what it lacks to predict danger
and rolls "``a``, then ``ζ``" in latent space, as the model-based rules roll the true dynamics:

- a **cost head** ``C(z, a)``: the logits of the shaped cost ``ĉ`` of eq. 18 of the state the step leads to, and of
  the violation indicator ``c`` (entering the unsafe set, which is absorbing);
- a **backup head** ``ζ̂(z)``: the user's backup ``ζ(s)`` distilled onto latent states, so that the roll can follow
  ``ζ`` where there is no observation to apply it to.

Both heads learn from the real transitions of ``B`` on TOLD's latents; TOLD itself is not changed by them (the latents
are detached), so the shield cannot alter what TOPO learns.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn

from sppo_sb3.common.networks import mlp
from sppo_sb3.shield.base import advantage_from_values
from sppo_sb3.shield.learned.base import INITIAL_LOGIT, BackupPolicy, CostTransitions, RefinableRule

ObservationTransform = Callable[[np.ndarray], np.ndarray]


class LatentDynamics(Protocol):
    """What the rule reads of a world model: SPPO's TOLD (eq. 9) has it; the shield layer does not import SPPO."""

    latent_dim: int

    def encode(self, obs: th.Tensor) -> th.Tensor:
        """``z = h(s)``."""

    def next_latent(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """``z' = d(z, a)``."""

    def parameters(self) -> Iterator[nn.Parameter]:
        """Its weights (the rule's heads follow them to their device)."""


class LatentModelRule(RefinableRule):
    """``Q̄(s, a) = E Σ_t γ^(t+1) ĉ_(t+1)`` along "``a``, then ``ζ̂``" rolled by TOLD from ``z = h(s)``.

    Each latent step ``(z_t, a_t)`` gives the cost head's violation probability ``p_t`` and shaped cost ``ĉ_t``; a
    violation is absorbing (``ĉ = 1`` forever: ``γ^(t+1) / (1 - γ)``), so the roll adds
    ``γ^(t+1) [(1 - p_t) ĉ_t + p_t / (1 - γ)]`` weighted by the probability of no violation before ``t``. That is the
    model-based rules' ``Q̄`` (shaped scale) in expectation over the predicted violations. The first action is the
    given one, the later ones ``ζ̂(z_t)``.

    **Binding.** The rule reads TOLD from the model it shields: ``SPPO(shield=LatentModelRule(...))`` binds it to its
    own TOLD (:meth:`bind`) when it builds (or loads) the policy; an unbound rule raises rather than decide. Before its
    heads have learned anything ``Ā = 0`` everywhere: nothing is shielded, so it protects only once it has seen the
    task, as every learned rule (SPPO fits it on ``B`` every training round: ``refine_shield="auto"``).

    **What it keeps.** ``Ā(s, ζ(s)) = 0`` exactly: both terms are rolled in batches of one shape, so the backup is never
    shielded (Proposition 1). With ``Q̄`` within ``δ`` of the true ``Q̄^ζ`` the rule is ``(β + (1 + γ)δ)``-adoptable
    (Proposition 2.3); ``δ`` is measured (:mod:`sppo_sb3.shield.analysis`), not bounded.

    :param observation_space: the env's flat Box observation space; the rule reads raw observations.
    :param action_space: the env's Box action space.
    :param backup_policy: the known backup ``ζ``: ``(B, obs_dim)`` observations → ``(B, act_dim)`` actions in env units.
    :param gamma: discount of ``Q̄``.
    :param horizon: latent steps of each roll: long enough for ``ζ`` to make any state safe for good (e.g. to stop).
    :param eta: advantage threshold ``η >= 0`` (shaped scale).
    :param net_arch: hidden layer sizes of the cost and backup heads (ELU).
    :param lr: Adam learning rate of the heads.
    :param device: torch device of the heads (``"auto"``: CUDA when available); :meth:`bind` moves them to TOLD's.
    :param seed: seeds the heads' initial weights and the minibatch sampling (``None``: not seeded).
    """

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Space,
        backup_policy: BackupPolicy,
        gamma: float = 0.99,
        horizon: int = 30,
        eta: float = 0.0,
        net_arch: Sequence[int] = (128, 128),
        lr: float = 1e-3,
        device: th.device | str = "auto",
        seed: int | None = None,
    ) -> None:
        super().__init__(observation_space, action_space, backup_policy, gamma, eta, seed)
        if horizon < 1:
            raise ValueError(f"horizon must be at least 1 step, got {horizon}.")
        self.horizon, self.net_arch, self.lr = int(horizon), tuple(int(n) for n in net_arch), float(lr)
        self.device, self.seed = get_device(device), seed
        self.model: LatentDynamics | None = None
        self.latent_dim: int | None = None
        self.transform: ObservationTransform | None = None
        self.cost_head: nn.Sequential | None = None
        self.backup_head: nn.Sequential | None = None
        self.optimizer: th.optim.Optimizer | None = None

    # ----------------------------------------------------------------------------------------------- binding
    def bind(self, model: LatentDynamics, transform: ObservationTransform | None = None) -> None:
        """Roll on ``model`` (a TOLD); ``transform`` maps raw observations to its inputs (e.g. VecNormalize's).

        The heads are built on the first bind (their sizes follow TOLD's latent) and kept on the next ones, so a loaded
        model's rule keeps what it learned.

        :raises ValueError: heads learned on a TOLD of another latent size.
        """
        if self.latent_dim is not None and self.latent_dim != model.latent_dim:
            raise ValueError(
                f"This rule's heads were learned on a TOLD with latent_dim {self.latent_dim}; it cannot roll on one with "
                f"latent_dim {model.latent_dim}: build a new LatentModelRule for this model."
            )
        self.model, self.transform, self.latent_dim = model, transform, model.latent_dim
        self.device = next(model.parameters()).device
        if self.cost_head is None:
            with th.random.fork_rng(devices=[]):
                if self.seed is not None:
                    th.manual_seed(self.seed)
                self.cost_head = mlp(model.latent_dim + self.act_dim, self.net_arch, 2, nn.ELU, zero_head=True).to(self.device)
                self.backup_head = mlp(model.latent_dim, self.net_arch, self.act_dim, nn.ELU, zero_head=True).to(self.device)
            head = self.cost_head[-1]
            assert isinstance(head, nn.Linear)
            nn.init.constant_(head.bias, INITIAL_LOGIT)  # no cost, no violation before learning: Ā ≡ 0
            self.optimizer = th.optim.Adam([*self.cost_head.parameters(), *self.backup_head.parameters()], lr=self.lr)
        assert self.backup_head is not None
        self.cost_head.to(self.device)
        self.backup_head.to(self.device)

    def _check_bound(self) -> None:
        if self.model is None:
            raise RuntimeError(
                "LatentModelRule rolls Q̄ on SPPO's TOLD and is not bound to one: pass it as SPPO(shield=rule), which binds "
                "it to the model's TOLD, or bind it to a trained model's with rule.bind(model.policy.model)."
            )

    def __getstate__(self) -> dict[str, Any]:
        """Saved with the heads, without the TOLD it is bound to: the model saves that, and binds it again on load."""
        return {**self.__dict__, "model": None, "transform": None}

    # ----------------------------------------------------------------------------------------------- the roll
    def _latents(self, obs: np.ndarray) -> th.Tensor:
        """``z = h(s)`` of raw observations, on TOLD's inputs."""
        assert self.model is not None
        inputs = self.transform(obs) if self.transform is not None else obs
        return self.model.encode(th.as_tensor(inputs, dtype=th.float32, device=self.device))

    def _scaled(self, actions: np.ndarray) -> th.Tensor:
        """Env actions clipped to the action space, rescaled to TOLD's ``[-1, 1]``."""
        actions = np.clip(actions, self.action_space.low, self.action_space.high)
        return th.as_tensor((actions - self._act_centre) / self._act_half, dtype=th.float32, device=self.device)

    def _backup_latent(self, z: th.Tensor) -> th.Tensor:
        """``ζ̂(z)`` in ``[-1, 1]``."""
        assert self.backup_head is not None
        return th.tanh(self.backup_head(z))

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``Q̄(s, a)`` rolled for :attr:`horizon` latent steps (see the class docstring).

        :raises RuntimeError: the rule is not bound to a TOLD (it has no model to roll on).
        """
        obs, actions = self.flat_pairs(obs, actions)
        self._check_bound()
        assert self.model is not None and self.cost_head is not None
        with th.no_grad():
            z, action = self._latents(obs), self._scaled(actions)
            q, alive = th.zeros(len(obs), device=self.device), th.ones(len(obs), device=self.device)
            for t in range(self.horizon):
                shaped, violation = th.sigmoid(self.cost_head(th.cat([z, action], dim=-1))).unbind(-1)
                q += alive * self.gamma ** (t + 1) * ((1.0 - violation) * shaped + violation / (1.0 - self.gamma))
                alive = alive * (1.0 - violation)
                z = self.model.next_latent(z, action)
                action = self._backup_latent(z)
        return q.cpu().numpy().astype(np.float64)

    def advantage(self, obs: np.ndarray, actions: np.ndarray, backup: np.ndarray | None = None) -> np.ndarray:
        """``Ā(s, a)``, its two terms rolled in two batches of the same shape, so that ``Ā(s, ζ(s)) = 0`` exactly."""
        if backup is None:
            backup = self.backup_action(obs)
        return advantage_from_values(self.cost_value(obs, actions), self.cost_value(obs, backup))

    # ----------------------------------------------------------------------------------------------- learning
    def refine(self, transitions: CostTransitions, batch_size: int) -> float:
        """One step of both heads on a minibatch of ``B`` (actions in env units); returns the summed loss.

        The cost head fits ``(ĉ(s'), c(s'))`` at ``(h(s), a)`` by cross-entropy; the backup head fits ``ζ(s)`` at
        ``h(s)`` and ``ζ(s')`` at the rolled ``d(h(s), a)``, the latents it meets in a roll.

        :raises RuntimeError: the rule is not bound to a TOLD yet.
        """
        self._check_bound()
        assert self.model is not None and self.cost_head is not None
        t = transitions
        obs, actions = self.flat_pairs(t.observations, t.actions)
        next_obs = np.asarray(t.next_observations, dtype=np.float64).reshape(len(obs), -1)
        idx = self.minibatch(len(obs), batch_size)
        obs, actions, next_obs = obs[idx], actions[idx], next_obs[idx]
        labels = np.stack([np.clip(t.shaped_costs[idx], 0.0, 1.0), np.asarray(t.violations)[idx] > 0], axis=1)
        with th.no_grad():
            z, action = self._latents(obs), self._scaled(actions)
            rolled = self.model.next_latent(z, action)
            backups = self._scaled(np.concatenate([self.backup_action(obs), self.backup_action(next_obs)]))
        logits = self.cost_head(th.cat([z, action], dim=-1))
        cost_loss = nn.functional.binary_cross_entropy_with_logits(
            logits, th.as_tensor(labels, dtype=th.float32, device=self.device)
        )
        backup_loss = nn.functional.mse_loss(self._backup_latent(th.cat([z, rolled])), backups)
        loss = cost_loss + backup_loss
        assert self.optimizer is not None
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        return float(loss.item())
