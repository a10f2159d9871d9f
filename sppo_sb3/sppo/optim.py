"""Optimiser steps written as tensor code, so that TOPO's whole update (Alg. 3) compiles into one graph.

``torch.optim.Adam.step`` reads its step counter with ``.item()`` on CPU and calls ``loss.backward()``'s ``.grad``
fields, both of which break a ``torch.compile`` graph. These functions do the same arithmetic on the optimiser's own
state (``exp_avg``, ``exp_avg_sq``, ``step``), so ``state_dict``/``load_state_dict`` and SB3's learning-rate updates
keep working, and the eager path runs the very same code. PyTorch's own Adam with ``capturable=True`` also traces into
the compiled update, but trains slower (``scripts/bench_training.py --torch-adam`` measures it).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch as th


def supports_tensor_step(optimizer: th.optim.Optimizer) -> bool:
    """Whether :func:`apply_gradients` can step ``optimizer`` as tensor code (plain Adam, one parameter group)."""
    if type(optimizer) is not th.optim.Adam or len(optimizer.param_groups) != 1:
        return False
    group = optimizer.param_groups[0]
    return not (group["amsgrad"] or group["maximize"] or group.get("decoupled_weight_decay", False))


def init_optimizer_state(optimizer: th.optim.Optimizer) -> None:
    """Create Adam's state where it is missing and keep its step counters on the parameters' device.

    ``torch.optim.Adam`` creates its state lazily inside ``step`` and keeps ``step`` on the CPU; a compiled (or
    CUDA-graphed) update needs every state tensor to exist, on the parameters' device, before it runs.
    """
    if not supports_tensor_step(optimizer):
        return
    for p in optimizer.param_groups[0]["params"]:
        state = optimizer.state[p]
        if not state:
            state["step"] = th.zeros((), dtype=th.float32, device=p.device)
            state["exp_avg"] = th.zeros_like(p, memory_format=th.preserve_format)
            state["exp_avg_sq"] = th.zeros_like(p, memory_format=th.preserve_format)
        elif state["step"].device != p.device:
            state["step"] = state["step"].to(p.device)
        if p.device.type == "cuda":  # CUDA graphs update the state in place, at fixed addresses
            for tensor in state.values():
                th._dynamo.mark_static_address(tensor)


def clip_by_total_norm(grads: Sequence[th.Tensor], max_norm: float) -> tuple[list[th.Tensor], th.Tensor]:
    """``torch.nn.utils.clip_grad_norm_`` on a list of gradients: returns the clipped ones and the pre-clip norm."""
    norm = th.linalg.vector_norm(th.stack([th.linalg.vector_norm(g) for g in grads]))
    scale = (max_norm / (norm + 1e-6)).clamp(max=1.0)
    return [g * scale for g in grads], norm


@th.no_grad()
def adam_step(optimizer: th.optim.Adam, grads: Sequence[th.Tensor], lr: th.Tensor) -> None:
    """One step of ``optimizer`` (Adam, Kingma & Ba 2015) on ``grads``, as ``torch.optim.Adam`` computes it.

    :param lr: the learning rate as a 0-d tensor, so that a schedule does not recompile the graph.
    """
    group = optimizer.param_groups[0]
    beta1, beta2 = group["betas"]
    for param, grad in zip(group["params"], grads):
        state = optimizer.state[param]
        if group["weight_decay"]:
            grad = grad.add(param, alpha=group["weight_decay"])
        step = state["step"]
        step.add_(1.0)
        state["exp_avg"].lerp_(grad, 1.0 - beta1)
        state["exp_avg_sq"].mul_(beta2).addcmul_(grad, grad, value=1.0 - beta2)
        denom = (state["exp_avg_sq"].sqrt() / (1.0 - beta2**step).sqrt()).add_(group["eps"])
        param.sub_(lr / (1.0 - beta1**step) * state["exp_avg"] / denom)


def apply_gradients(optimizer: th.optim.Optimizer, grads: Sequence[th.Tensor], lr: th.Tensor) -> None:
    """Step ``optimizer`` on ``grads``: as tensor code for Adam, through ``optimizer.step()`` for any other (eager only)."""
    if supports_tensor_step(optimizer):
        adam_step(optimizer, grads, lr)  # type: ignore[arg-type]
        return
    params = [p for group in optimizer.param_groups for p in group["params"]]
    for param, grad in zip(params, grads):
        param.grad = grad
    optimizer.step()
    optimizer.zero_grad(set_to_none=True)


@th.no_grad()
def ema_update(online: th.nn.Module, target: th.nn.Module, weight: th.Tensor) -> None:
    """``θ⁻ ← θ⁻ + w (θ - θ⁻)`` (Alg. 3 line 13); ``w = 0`` leaves the target as it is."""
    for target_param, param in zip(target.parameters(), online.parameters()):
        target_param.lerp_(param, weight)
