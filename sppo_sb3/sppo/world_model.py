"""SPPO's world model: TOLD, the task-oriented latent dynamics model of eq. 9.

Five deterministic MLPs (TD-MPC sizes by default): encoder ``h(s) → z``, latent dynamics ``d(z, a) → z'``,
reward ``R(z, a)``, twin value ``Q(z, a)`` and policy ``π(z) → a ∈ [-1, 1]``; optionally a sixth, the termination
head ``T(z, a)``: the logit of the probability that ``(z, a)`` ends the episode of the absorbing MDP ``M̃`` (eq. 8: a
shielded proposal, a violation or a real termination), so that planning adds nothing after it (eq. 10).

Two variants (``TOLD(..., told=...)``): ``"paper"``, TD-MPC's (v1) networks, the paper's model and the default, and
``"tdmpc2"``, with TD-MPC2's robustness pieces (LayerNorm + Mish hidden layers, SimNorm latents, five Q heads).
"""

from __future__ import annotations

from typing import Literal

import torch as th
from torch import nn

from sppo_sb3.common.networks import mlp


class ELU(nn.ELU):
    """ELU (α = 1) whose no-grad forward takes ``max(x, exp(min(x, 0)) - 1)``: four vectorised passes.

    The planner evaluates ELU on every hidden layer of every rollout step, and PyTorch's CPU ELU kernel is slower than
    these four passes on the planner's shapes. With autograd on it is ``F.elu``.
    """

    def forward(self, x: th.Tensor) -> th.Tensor:
        if th.is_grad_enabled() or self.alpha != 1.0:
            return super().forward(x)
        negative = th.clamp(x, max=0.0).exp_().sub_(1.0)
        return th.maximum(x, negative, out=negative)


def q_network(in_dim: int, hidden_dim: int) -> nn.Sequential:
    """TD-MPC's value head: ``Linear → LayerNorm → Tanh → Linear → ELU → Linear``."""
    return nn.Sequential(
        nn.Linear(in_dim, hidden_dim),
        nn.LayerNorm(hidden_dim),
        nn.Tanh(),
        nn.Linear(hidden_dim, hidden_dim),
        ELU(),
        nn.Linear(hidden_dim, 1),
    )


def orthogonal_init(module: nn.Module) -> None:
    """Orthogonal weights and zero biases on every Linear layer (TD-MPC's initialisation)."""
    if isinstance(module, nn.Linear):
        nn.init.orthogonal_(module.weight)
        nn.init.zeros_(module.bias)


def zero_last_layer(net: nn.Sequential, bias: float = 0.0) -> None:
    """Zero the output layer's weights, so the head starts at the constant ``bias`` (0: reward and values)."""
    last = net[-1]
    assert isinstance(last, nn.Linear)
    nn.init.zeros_(last.weight)
    nn.init.constant_(last.bias, bias)


INITIAL_TERMINATION_LOGIT = -4.6
"""``log(0.01 / 0.99)``: the untrained termination head predicts that 1% of steps end the episode."""

INITIAL_INTERVENTION_LOGIT = -3.0
"""The untrained intervention head predicts that the shield rejects about 5% of proposals."""

TOLDName = Literal["paper", "tdmpc2"]
TOLD_NAMES: tuple[TOLDName, ...] = ("paper", "tdmpc2")
"""The TOLD variants: TD-MPC's (v1) networks, the paper's model, and TD-MPC2's robust ones."""
SIMNORM_GROUP = 8
"""``V`` of TD-MPC2's SimNorm: the latent is softmaxed in groups of this many entries."""
TDMPC2_NUM_Q = 5
"""Size of the Q ensemble of the ``"tdmpc2"`` TOLD."""


def check_told_name(told: str) -> None:
    """Reject an unknown TOLD variant with a message that names the choices."""
    if told not in TOLD_NAMES:
        raise ValueError(
            f"told={told!r} is not a TOLD variant: use 'paper' (TD-MPC's model, the paper's; the default) or 'tdmpc2' "
            "(TD-MPC2's LayerNorm + Mish layers, SimNorm latents and five Q heads)."
        )


class SimNorm(nn.Module):
    """Simplicial normalisation (TD-MPC2): the last dimension cut into groups of ``group`` entries, each group
    softmaxed (temperature 1), so that every group lies on a simplex (non-negative, sums to 1)."""

    def __init__(self, group: int = SIMNORM_GROUP) -> None:
        super().__init__()
        self.group = group

    def forward(self, x: th.Tensor) -> th.Tensor:
        shape = x.shape
        groups = x.reshape(*shape[:-1], shape[-1] // self.group, self.group)  # no -1: empty batches reshape too
        return th.softmax(groups, dim=-1).reshape(shape)

    def extra_repr(self) -> str:
        return f"group={self.group}"


class TOLD(nn.Module):
    """The TOLD model of eq. 9.

    ``told="paper"`` (default) is TD-MPC's (v1) model, the paper's: ELU hidden layers (Q heads ``Linear → LayerNorm →
    Tanh → Linear → ELU → Linear``), an unnormalised latent and twin Q heads ``q1, q2``. ``told="tdmpc2"`` follows
    TD-MPC2 (Hansen, Su & Wang 2024) in three pieces: every hidden layer of every network is ``Linear → LayerNorm →
    Mish``; the latent ``z`` (output of ``h`` and of ``d``) is ``Linear → LayerNorm → SimNorm`` (groups of
    :data:`SIMNORM_GROUP`, so ``latent_dim`` must be a multiple of 8); five Q heads ``q1 .. q5``, of which the TD
    target takes the min of two drawn at random per update (:func:`~sppo_sb3.sppo.topo.td_target`) while planning and
    the policy loss use their mean (:meth:`min_q`). Not included from TD-MPC2: the two-hot discrete regression of
    reward and value, the stochastic policy with its entropy bonus and percentile-scaled Q, dropout in the Q heads,
    its initialisation and its larger default sizes (the sizes and the orthogonal initialisation stay TD-MPC's).

    :param obs_dim: flat observation size.
    :param action_dim: action size (actions live in [-1, 1]).
    :param latent_dim: size of the latent state ``z``.
    :param encoder_dim: hidden width of the encoder ``h``.
    :param hidden_dim: hidden width of ``d``, ``R``, ``π`` (two layers each) and ``Q``.
    :param termination: add the termination head ``T(z, a)`` (two hidden layers, like ``R``); without it TOLD is
        TD-MPC's model and plans as if no episode ever ended.
    :param intervention: add the intervention head ``I(z, a)``: the logit of the probability that the shield rejects
        the proposal ``a`` (two hidden layers, like ``R``); not in the paper (SPPO's ``intervention_target``).
    :param told: the variant: ``"paper"`` (TD-MPC's) or ``"tdmpc2"`` (TD-MPC2's pieces, see above).
    :raises ValueError: an unknown ``told``, or a ``"tdmpc2"`` ``latent_dim`` that is not a multiple of 8.

    ``q_names`` are the attribute names of the Q heads, in order (``("q1", "q2")``, or ``("q1", ..., "q5")``).
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        latent_dim: int = 50,
        encoder_dim: int = 256,
        hidden_dim: int = 512,
        termination: bool = False,
        told: TOLDName = "paper",
        intervention: bool = False,
    ):
        super().__init__()
        check_told_name(told)
        if told == "tdmpc2" and latent_dim % SIMNORM_GROUP:
            raise ValueError(
                f"told='tdmpc2' SimNorm-s the latent in groups of {SIMNORM_GROUP}: latent_dim must be a multiple of "
                f"{SIMNORM_GROUP}, got {latent_dim}."
            )
        self.latent_dim, self.action_dim, self.told = latent_dim, action_dim, told
        paper, za_dim, hidden = told == "paper", latent_dim + action_dim, [hidden_dim, hidden_dim]

        def net(in_dim: int, widths: list[int], out_dim: int) -> nn.Sequential:
            """The variant's MLP: ELU hidden layers (TD-MPC), or Linear → LayerNorm → Mish (TD-MPC2)."""
            return mlp(in_dim, widths, out_dim, ELU) if paper else mlp(in_dim, widths, out_dim, nn.Mish, norm=True)

        def latent_net(in_dim: int, widths: list[int]) -> nn.Sequential:
            """An MLP onto ``z``: a plain Linear output (TD-MPC), or Linear → LayerNorm → SimNorm (TD-MPC2)."""
            out = net(in_dim, widths, latent_dim)
            return out if paper else nn.Sequential(*out, nn.LayerNorm(latent_dim), SimNorm(SIMNORM_GROUP))

        self.encoder = latent_net(obs_dim, [encoder_dim])
        self.dynamics = latent_net(za_dim, hidden)
        self.reward = net(za_dim, hidden, 1)
        self.pi = net(latent_dim, hidden, action_dim)
        self.q_names = tuple(f"q{i}" for i in range(1, (2 if paper else TDMPC2_NUM_Q) + 1))
        for name in self.q_names:
            self.add_module(name, q_network(za_dim, hidden_dim) if paper else net(za_dim, hidden, 1))
        self.termination = net(za_dim, hidden, 1) if termination else None
        self.intervention = net(za_dim, hidden, 1) if intervention else None
        self.apply(orthogonal_init)
        for head in (self.reward, *self.q_heads):
            zero_last_layer(head)
        if self.termination is not None:
            zero_last_layer(self.termination, INITIAL_TERMINATION_LOGIT)
        if self.intervention is not None:
            zero_last_layer(self.intervention, INITIAL_INTERVENTION_LOGIT)

    @property
    def q_heads(self) -> list[nn.Sequential]:
        """The Q heads, in the order of :attr:`q_names`."""
        return [getattr(self, name) for name in self.q_names]

    @property
    def num_q(self) -> int:
        """The number of Q heads: 2 (``"paper"``) or 5 (``"tdmpc2"``)."""
        return len(self.q_names)

    def encode(self, obs: th.Tensor) -> th.Tensor:
        """Representation ``z = h(s)``."""
        return self.encoder(obs)

    def next(self, z: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """Latent dynamics and reward: ``(d(z, a), R(z, a))``; the reward has shape ``(..., 1)``."""
        za = th.cat([z, action], dim=-1)
        return self.dynamics(za), self.reward(za)

    def next_latent(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Latent dynamics ``d(z, a)`` alone."""
        return self.dynamics(th.cat([z, action], dim=-1))

    def predicted_reward(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Reward ``R(z, a)`` of shape ``(..., 1)``."""
        return self.reward(th.cat([z, action], dim=-1))

    def termination_logit(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Logit of ``P(the step (z, a) ends the episode of M̃)``, shape ``(..., 1)``; needs the termination head."""
        assert self.termination is not None, "TOLD was built without a termination head"
        return self.termination(th.cat([z, action], dim=-1))

    def continuation(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """``1 - P(termination)`` of shape ``(...,)``: ones without a termination head (TD-MPC)."""
        if self.termination is None:
            return th.ones(z.shape[:-1], dtype=z.dtype, device=z.device)
        return th.sigmoid(-self.termination_logit(z, action)).squeeze(-1)

    def intervention_probability(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """``P(the shield rejects the proposal a in z)`` of shape ``(...,)``: zeros without an intervention head."""
        if self.intervention is None:
            return th.zeros(z.shape[:-1], dtype=z.dtype, device=z.device)
        return th.sigmoid(self.intervention(th.cat([z, action], dim=-1))).squeeze(-1)

    def policy(self, z: th.Tensor, std: float = 0.0, noise: th.Tensor | None = None) -> th.Tensor:
        """``π(z)`` squashed to [-1, 1]; with ``std > 0`` adds clipped Gaussian exploration noise (TD-MPC).

        :param noise: standard normal draws of the action's shape; drawn here when not given. Passing them makes the
            result a pure function of the inputs (what compiled and eager code must agree on).
        """
        action = th.tanh(self.pi(z))
        if std > 0:
            noise = th.randn_like(action) if noise is None else noise
            action = (action + (noise * std).clamp(-0.3, 0.3)).clamp(-1.0, 1.0)
        return action

    def q(self, z: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, ...]:
        """The state-action values of every head, ``(Q1(z, a), Q2(z, a)[, ..., Q5(z, a)])``, each of shape ``(..., 1)``."""
        za = th.cat([z, action], dim=-1)
        return tuple(getattr(self, name)(za) for name in self.q_names)

    def min_q(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        """The value the planner (eq. 10's terminal value) and the policy loss use, shape ``(..., 1)``.

        ``"paper"``: ``min(Q1, Q2)``, TD-MPC's pessimistic twin value. ``"tdmpc2"``: the mean of the five heads
        (deterministic; TD-MPC2 averages two random heads there); the pessimistic min of two random heads is only in
        the TD target (:func:`~sppo_sb3.sppo.topo.td_target`).
        """
        heads = self.q(z, action)
        if self.told == "paper":
            return th.min(heads[0], heads[1])
        return th.stack(heads).mean(dim=0)
