"""Task-oriented parameter optimisation, TOPO (eqs. 13–17; Alg. 3) on sequences of ``B̃``.

Only the first state of a sequence is encoded; the rest is rolled in latent space by ``d``. Masked steps (past an
episode end) contribute nothing. Only the latent roll is sequential: rewards, values and TD targets of all ``H`` steps
are computed in one batched call each. The whole update — both losses, both gradients, clipping, both Adam steps and
the EMA target — is tensor code without host syncs, so that :class:`~sppo_sb3.sppo.compile.CompiledFunction` can
compile it into one graph; its eager run is the reference.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch as th

from sppo_sb3.sppo.buffers import SequenceSamples
from sppo_sb3.sppo.optim import apply_gradients, clip_by_total_norm, ema_update
from sppo_sb3.sppo.world_model import TOLD


@dataclass
class TOPOConfig:
    """Loss weights and optimisation settings (TD-MPC defaults).

    :param reward_coef: ``c1`` of eq. 14.
    :param value_coef: ``c2`` of eq. 14.
    :param consistency_coef: ``c3`` of eq. 14.
    :param termination_coef: weight of the termination head's loss (binary cross-entropy on ``B̃``'s terminal flags;
        used only when TOLD has the head).
    :param intervention_coef: weight of the intervention head's loss (binary cross-entropy of ``I(z, proposal)`` on
        ``B̃``'s intervention flags; used only when TOLD has the head).
    :param rho: ``λ`` of eq. 13, the per-step decay of the loss weight.
    :param grad_clip: max gradient norm.
    :param policy_std: std of the clipped noise on ``π(z')`` in the TD target.
    """

    reward_coef: float = 0.5
    value_coef: float = 0.1
    consistency_coef: float = 2.0
    termination_coef: float = 1.0
    intervention_coef: float = 1.0
    rho: float = 0.5
    grad_clip: float = 10.0
    policy_std: float = 0.05


TOPO_STATS = ("loss", "pi_loss", "grad_norm", "reward", "value", "consistency", "termination", "intervention")
"""Names of the entries of the statistics vector that :func:`topo_update` returns."""


def reward_loss(predicted: th.Tensor, reward: th.Tensor) -> th.Tensor:
    """``L_r = ‖R(z_i, a_i) - r_i‖²`` (eq. 15), per sample."""
    return (predicted.squeeze(-1) - reward) ** 2


TD_TARGET_HEADS = 2
"""How many of the ``"tdmpc2"`` TOLD's Q heads the TD target takes the min of (TD-MPC2's)."""


def draw_target_heads(model: TOLD, device: th.device | str = "cpu") -> th.Tensor | None:
    """The Q heads :func:`td_target` takes the min of in one update: ``None`` (all: both twin heads) for the
    ``"paper"`` TOLD, which draws nothing; for ``"tdmpc2"`` :data:`TD_TARGET_HEADS` distinct heads drawn at random
    with torch's global RNG, as a tensor of indices, drawn outside the (compiled) update and passed in."""
    if model.told == "paper":
        return None
    return th.randperm(model.num_q, device=device)[:TD_TARGET_HEADS]


@th.no_grad()
def td_target(
    model: TOLD,
    target: TOLD,
    next_obs: th.Tensor,
    reward: th.Tensor,
    terminal: th.Tensor,
    noise: th.Tensor,
    cfg: TOPOConfig,
    gamma: float,
    heads: th.Tensor | None = None,
) -> th.Tensor:
    """``r + γ (1 - done) min_k Q⁻_k(z', π(z'))`` with ``z' = h(s')`` — the target of eq. 16.

    The min runs over the target network's heads ``heads``: all of them when None (the ``"paper"`` TOLD: its twin
    heads, TD-MPC's target), or the two that :func:`draw_target_heads` drew for this update (``"tdmpc2"``).

    :param noise: standard normal draws for the exploration noise on ``π(z')``, shaped like the actions.
    :param gamma: ``γ`` (SPPO's ``gamma``, the one its planner uses).
    :param heads: indices of the target's Q heads to take the min of (a 1-d integer tensor), or None for all.
    """
    next_z = model.encode(next_obs)
    values = th.stack(target.q(next_z, model.policy(next_z, cfg.policy_std, noise)))
    if heads is not None:
        values = values.index_select(0, heads)
    return reward + gamma * (1.0 - terminal) * values.amin(dim=0).squeeze(-1)


def value_loss(qs: Sequence[th.Tensor], target: th.Tensor) -> th.Tensor:
    """``L_v = ‖Q(z_i, a_i) - target‖²`` summed over all Q heads (eq. 16), per sample."""
    loss = (qs[0].squeeze(-1) - target) ** 2
    for q in qs[1:]:
        loss = loss + (q.squeeze(-1) - target) ** 2
    return loss


def consistency_loss(predicted_z: th.Tensor, target_z: th.Tensor) -> th.Tensor:
    """``L_c = ‖d(z_i, a_i) - h⁻(s_(i+1))‖²`` (eq. 17), averaged over latent dims, per sample."""
    return ((predicted_z - target_z) ** 2).mean(dim=-1)


def termination_loss(logits: th.Tensor, terminals: th.Tensor) -> th.Tensor:
    """Binary cross-entropy of the termination head against ``B̃``'s terminal flags, per sample.

    The flags are those of the TD target (eq. 16): absorbing interventions and real terminations, not time-limit
    truncations.
    """
    return th.nn.functional.binary_cross_entropy_with_logits(logits.squeeze(-1), terminals, reduction="none")


def rho_weights(cfg: TOPOConfig, horizon: int, device: th.device) -> th.Tensor:
    """``λ^i`` for ``i < H`` (eq. 13)."""
    return cfg.rho ** th.arange(horizon, device=device, dtype=th.float32)


def roll_latents(model: TOLD, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """``z_0 = h(s_t)``, ``z_(i+1) = d(z_i, a_i)``: the ``(H + 1, B, latent)`` latents of a sequence."""
    latents = [model.encode(obs)]
    for action in actions:
        latents.append(model.next_latent(latents[-1], action))
    return th.stack(latents)


def model_loss(
    model: TOLD,
    target: TOLD,
    batch: SequenceSamples,
    noise: th.Tensor,
    cfg: TOPOConfig,
    gamma: float,
    heads: th.Tensor | None = None,
) -> tuple[th.Tensor, ...]:
    """``J = Σ_i λ^i (c1 L_r + c2 L_v + c3 L_c + c_T L_T)`` (eqs. 13, 14) over a batch of sequences, scaled by ``1/H``.

    ``L_T``, the termination head's cross-entropy, is not in the paper's eq. 14; it is 0 without the head. Nor is
    ``c_I L_I``, the intervention head's cross-entropy on the proposals the shield judged (0 without the head).

    :param noise: ``(H, B, A)`` standard normal draws for the TD targets' policy noise.
    :param gamma: the TD target's discount.
    :param heads: the target heads of the TD target's min (:func:`td_target`; None: all).
    :return: the loss, the rolled latents ``z_0 .. z_(H-1)`` (detached, for the policy loss) and the weighted
        reward, value, consistency, termination and intervention terms.
    """
    horizon = batch.actions.shape[0]
    with th.no_grad():
        target_z = target.encode(batch.next_observations)
        target_q = td_target(model, target, batch.next_observations, batch.rewards, batch.terminals, noise, cfg, gamma, heads)
    latents = roll_latents(model, batch.observations, batch.actions)
    qs = model.q(latents[:-1], batch.actions)
    predicted_reward = model.predicted_reward(latents[:-1], batch.actions)
    weights = rho_weights(cfg, horizon, latents.device)
    reward = (weights * (reward_loss(predicted_reward, batch.rewards) * batch.mask).mean(dim=1)).sum()
    value = (weights * (value_loss(qs, target_q) * batch.mask).mean(dim=1)).sum()
    consistency = (weights * (consistency_loss(latents[1:], target_z) * batch.consistency_mask).mean(dim=1)).sum()
    total = cfg.reward_coef * reward + cfg.value_coef * value + cfg.consistency_coef * consistency
    termination = th.zeros((), device=latents.device)
    if model.termination is not None:
        logits = model.termination_logit(latents[:-1], batch.actions)
        termination = (weights * (termination_loss(logits, batch.terminals) * batch.mask).mean(dim=1)).sum()
        total = total + cfg.termination_coef * termination
    intervention = th.zeros((), device=latents.device)
    if model.intervention is not None and batch.proposals is not None and batch.intervened is not None:
        logits = model.intervention(th.cat([latents[:-1], batch.proposals], dim=-1))
        intervention = (weights * (termination_loss(logits, batch.intervened) * batch.mask).mean(dim=1)).sum()
        total = total + cfg.intervention_coef * intervention
    return total / horizon, latents[:-1].detach(), reward, value, consistency, termination, intervention


def policy_loss(
    model: TOLD, latents: th.Tensor, mask: th.Tensor, cfg: TOPOConfig, penalty: th.Tensor | None = None
) -> th.Tensor:
    """``-Σ_i λ^i Q(z_i, π(z_i))`` over the rolled (detached) ``(H, B, latent)`` latents — TD-MPC's policy objective,
    with ``Q`` :meth:`TOLD.min_q` (``"paper"``: the min of the twin heads; ``"tdmpc2"``: the mean of the five).

    :param penalty: the price of an intervention (0-d tensor): with TOLD's intervention head, the prior also learns
        away from what the shield rejects, ``-Σ_i λ^i (Q(z_i, π(z_i)) - penalty · P(I | z_i, π(z_i)))``.
    """
    action = model.policy(latents)
    values = model.min_q(latents, action).squeeze(-1)
    if penalty is not None:
        values = values - penalty * model.intervention_probability(latents, action)
    weights = rho_weights(cfg, latents.shape[0], latents.device)
    return -(weights * (values * mask).mean(dim=1)).sum() / latents.shape[0]


def topo_update(
    model: TOLD,
    target: TOLD,
    optimizer: th.optim.Optimizer,
    pi_optimizer: th.optim.Optimizer,
    batch: SequenceSamples,
    noise: th.Tensor,
    lr: th.Tensor,
    ema_weight: th.Tensor,
    cfg: TOPOConfig,
    gamma: float,
    heads: th.Tensor | None = None,
    penalty: th.Tensor | None = None,
) -> th.Tensor:
    """One TOPO update (Alg. 3 lines 3–13): a model step on ``J``, a policy step on the updated ``Q``, the EMA target.

    The policy's gradient is taken with respect to ``π``'s parameters alone, so ``Q`` stays fixed in that step.
    Adam's state must exist before the call (:func:`~sppo_sb3.sppo.optim.init_optimizer_state`).

    :param noise: ``(H, B, A)`` standard normal draws for the TD targets' policy noise.
    :param lr: learning rate of both optimisers (0-d tensor).
    :param ema_weight: ``τ`` on the updates that refresh the target network, else 0 (0-d tensor).
    :param gamma: the TD target's discount (SPPO's ``gamma``).
    :param heads: the target's Q heads whose min is the TD target (:func:`draw_target_heads`: None for the
        ``"paper"`` TOLD, two random indices for ``"tdmpc2"``); an input, so that compiled and eager updates agree.
    :param penalty: the price of an intervention in the policy loss (:func:`policy_loss`; None: none).
    :return: the statistics named by :data:`TOPO_STATS`, as one detached tensor (read it when logging, not per step).
    """
    model_params = [p for group in optimizer.param_groups for p in group["params"]]
    pi_params = [p for group in pi_optimizer.param_groups for p in group["params"]]
    loss, latents, reward, value, consistency, termination, intervention = model_loss(
        model, target, batch, noise, cfg, gamma, heads
    )
    grads, grad_norm = clip_by_total_norm(th.autograd.grad(loss, model_params), cfg.grad_clip)
    apply_gradients(optimizer, grads, lr)
    pi_loss = policy_loss(model, latents, batch.mask, cfg, penalty)
    pi_grads, _ = clip_by_total_norm(th.autograd.grad(pi_loss, pi_params), cfg.grad_clip)
    apply_gradients(pi_optimizer, pi_grads, lr)
    ema_update(model, target, ema_weight)
    return th.stack([loss, pi_loss, grad_norm, reward, value, consistency, termination, intervention]).detach()
