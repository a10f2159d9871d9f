"""Task-oriented parameter optimisation, TOPO (eqs. 13–17; Alg. 3) on sequences of ``B̃``.

Only the first state of a sequence is encoded; the rest is rolled in latent space by ``d``. Masked steps (past an
episode end) contribute nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch as th
from torch import nn

from sppo_sb3.sppo.buffers import SequenceSamples
from sppo_sb3.sppo.policies import TOLD


@dataclass
class TOPOConfig:
    """Loss weights and optimisation settings (TD-MPC defaults).

    :param reward_coef: ``c1`` of eq. 14.
    :param value_coef: ``c2`` of eq. 14.
    :param consistency_coef: ``c3`` of eq. 14.
    :param rho: ``λ`` of eq. 13, the per-step decay of the loss weight.
    :param gamma: discount of the TD target (eq. 16).
    :param grad_clip: max gradient norm.
    :param policy_std: std of the clipped noise on ``π(z')`` in the TD target.
    """

    reward_coef: float = 0.5
    value_coef: float = 0.1
    consistency_coef: float = 2.0
    rho: float = 0.5
    gamma: float = 0.99
    grad_clip: float = 10.0
    policy_std: float = 0.05


def reward_loss(predicted: th.Tensor, reward: th.Tensor) -> th.Tensor:
    """``L_r = ‖R(z_i, a_i) - r_i‖²`` (eq. 15), per sample."""
    return (predicted.squeeze(-1) - reward) ** 2


@th.no_grad()
def td_target(
    model: TOLD, target: TOLD, next_obs: th.Tensor, reward: th.Tensor, terminal: th.Tensor, cfg: TOPOConfig
) -> th.Tensor:
    """``r + γ (1 - done) min Q⁻(z', π(z'))`` with ``z' = h(s')`` — the target of eq. 16 (twin-Q, TD-MPC)."""
    next_z = model.encode(next_obs)
    next_q = target.min_q(next_z, model.policy(next_z, cfg.policy_std)).squeeze(-1)
    return reward + cfg.gamma * (1.0 - terminal) * next_q


def value_loss(q1: th.Tensor, q2: th.Tensor, target: th.Tensor) -> th.Tensor:
    """``L_v = ‖Q(z_i, a_i) - target‖²`` for both heads (eq. 16), per sample."""
    return (q1.squeeze(-1) - target) ** 2 + (q2.squeeze(-1) - target) ** 2


def consistency_loss(predicted_z: th.Tensor, target_z: th.Tensor) -> th.Tensor:
    """``L_c = ‖d(z_i, a_i) - h⁻(s_(i+1))‖²`` (eq. 17), averaged over latent dims, per sample."""
    return ((predicted_z - target_z) ** 2).mean(dim=-1)


def model_loss(model: TOLD, target: TOLD, batch: SequenceSamples, cfg: TOPOConfig) -> tuple[th.Tensor, list[th.Tensor], dict]:
    """``J = Σ_i λ^i (c1 L_r + c2 L_v + c3 L_c)`` (eqs. 13, 14) over a batch of sequences, scaled by ``1/H``.

    :return: the loss, the rolled latents ``z_0 .. z_(H-1)`` (detached, for the policy loss) and the loss terms.
    """
    horizon = batch.actions.shape[0]
    z = model.encode(batch.observations)
    latents, terms = [], {"reward": 0.0, "value": 0.0, "consistency": 0.0}
    total = th.zeros((), device=z.device)
    for i in range(horizon):
        latents.append(z.detach())
        q1, q2 = model.q(z, batch.actions[i])
        z, predicted_reward = model.next(z, batch.actions[i])
        with th.no_grad():
            target_z = target.encode(batch.next_observations[i])
        weight, mask = cfg.rho**i, batch.mask[i]
        target_q = td_target(model, target, batch.next_observations[i], batch.rewards[i], batch.terminals[i], cfg)
        step = {
            "reward": (reward_loss(predicted_reward, batch.rewards[i]) * mask).mean(),
            "value": (value_loss(q1, q2, target_q) * mask).mean(),
            "consistency": (consistency_loss(z, target_z) * batch.consistency_mask[i]).mean(),
        }
        total = total + weight * (
            cfg.reward_coef * step["reward"] + cfg.value_coef * step["value"] + cfg.consistency_coef * step["consistency"]
        )
        for key, value in step.items():
            terms[key] += weight * value.item()
    return total / horizon, latents, terms


def policy_loss(model: TOLD, latents: list[th.Tensor], mask: th.Tensor, cfg: TOPOConfig) -> th.Tensor:
    """``-Σ_i λ^i min Q(z_i, π(z_i))`` over the rolled (detached) latents — TD-MPC's policy objective."""
    total = th.zeros((), device=mask.device)
    for i, z in enumerate(latents):
        total = total - cfg.rho**i * (model.min_q(z, model.policy(z)).squeeze(-1) * mask[i]).mean()
    return total / len(latents)


def clipped_step(optimizer: th.optim.Optimizer, loss: th.Tensor, params: list[nn.Parameter], max_norm: float) -> float:
    """Backpropagate, clip the gradient norm, step; returns the pre-clip gradient norm."""
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    norm = nn.utils.clip_grad_norm_(params, max_norm)
    optimizer.step()
    return float(norm)


def topo_update(
    model: TOLD,
    target: TOLD,
    optimizer: th.optim.Optimizer,
    pi_optimizer: th.optim.Optimizer,
    batch: SequenceSamples,
    cfg: TOPOConfig,
) -> dict[str, float]:
    """One TOPO update (Alg. 3 lines 3–12): model step on ``J``, then a policy step with ``Q`` frozen."""
    loss, latents, terms = model_loss(model, target, batch, cfg)
    model_params = [p for group in optimizer.param_groups for p in group["params"]]
    grad_norm = clipped_step(optimizer, loss, model_params, cfg.grad_clip)
    q_params = [*model.q1.parameters(), *model.q2.parameters()]
    for p in q_params:
        p.requires_grad_(False)
    pi_loss = policy_loss(model, latents, batch.mask, cfg)
    clipped_step(pi_optimizer, pi_loss, list(model.pi.parameters()), cfg.grad_clip)
    for p in q_params:
        p.requires_grad_(True)
    return {"loss": loss.item(), "pi_loss": pi_loss.item(), "grad_norm": grad_norm, **terms}
