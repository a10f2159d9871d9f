"""Training throughput: env steps per second of SPPO, compiled and eager, against SB3's SAC on the same env, in one run.

All three learn the same number of env steps after the same warm-up (SPPO's ``learning_starts`` of its yml entry),
one gradient step per env step, on the same device and threads. SPPO plans with MPPI at every step and updates its
TOLD model with TOPO; SAC samples its policy and updates an actor and twin critics. Throughput is measured after the
warm-up, when both are updating; the time SPPO spends compiling new graphs in that window (the planner's horizon
schedule, the first update) is reported apart and left out of its steps/s.

Default envs: ``Pendulum-v1`` and ``SafePointCircle-v0`` with the small configuration of ``hyperparams/sppo.yml``,
and ``HalfCheetah-v5`` at TD-MPC size (the class defaults).

    python scripts/bench_training.py                                    # all three envs
    python scripts/bench_training.py --envs Pendulum-v1 --steps 1000    # a quick look
    python scripts/bench_training.py --envs Pendulum-v1 SafePointCircle-v0 --torch-adam

``--torch-adam`` adds SPPO compiled with PyTorch's own Adam (``capturable=True``, traced into the compiled update, with
and without ``foreach``) in place of ``sppo_sb3/sppo/optim.py``'s tensor-code step: the measurement that module rests on.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

import sppo_sb3.sppo.topo as topo
from sppo_sb3 import SPPO
from sppo_sb3.zoo import constructor_kwargs

HYPERPARAMS = Path(__file__).resolve().parents[1] / "hyperparams" / "sppo.yml"
DEFAULT_STEPS = {"Pendulum-v1": 2000, "SafePointCircle-v0": 2000, "HalfCheetah-v5": 150}


def compile_seconds(model: BaseAlgorithm) -> float:
    return model.compile_stats["seconds"] if isinstance(model, SPPO) else 0.0


class UpdatePhaseTimer(BaseCallback):
    """Wall-clock time, compile time and env steps from the first step after ``learning_starts`` to the end."""

    def __init__(self, learning_starts: int) -> None:
        super().__init__()
        self.learning_starts = learning_starts
        self.start_time: float | None = None
        self.start_steps, self.start_compile = 0, 0.0

    def _on_step(self) -> bool:
        if self.start_time is None and self.num_timesteps > self.learning_starts:
            self.start_time, self.start_steps = time.perf_counter(), self.num_timesteps
            self.start_compile = compile_seconds(self.model)
        return True

    def result(self) -> tuple[float, float]:
        """Env steps per second without the compile time, and the compile time, in the timed window."""
        if self.start_time is None:
            raise ValueError("learn() ended before learning started: raise --steps above learning_starts")
        compiling = compile_seconds(self.model) - self.start_compile
        elapsed = time.perf_counter() - self.start_time - compiling
        return (self.num_timesteps - self.start_steps) / elapsed, compiling


def sppo_kwargs(env_id: str) -> dict[str, Any]:
    """SPPO's hyperparameters for ``env_id`` from ``hyperparams/sppo.yml`` (without the policy and the zoo-only keys)."""
    try:
        kwargs = constructor_kwargs(HYPERPARAMS, env_id)
    except KeyError as error:
        raise SystemExit(error.args[0]) from None
    kwargs.pop("policy", None)
    return kwargs


def measure(model: BaseAlgorithm, steps: int, learning_starts: int) -> tuple[float, float]:
    timer = UpdatePhaseTimer(learning_starts)
    model.learn(learning_starts + steps, callback=timer)
    return timer.result()


def torch_adam_step(optimizer: th.optim.Optimizer, grads: Sequence[th.Tensor], lr: th.Tensor) -> None:
    """PyTorch's own ``optimizer.step()`` on ``grads``, in place of the tensor-code step of ``sppo/optim.py``."""
    params = [p for group in optimizer.param_groups for p in group["params"]]
    for param, grad in zip(params, grads):
        param.grad = grad
    optimizer.step()
    for param in params:
        param.grad = None


@contextlib.contextmanager
def torch_adam_in_update() -> Iterator[None]:
    """TOPO's update steps its optimisers with :func:`torch_adam_step` for a while."""
    original = topo.apply_gradients
    topo.apply_gradients = torch_adam_step
    try:
        yield
    finally:
        topo.apply_gradients = original


def torch_adam_rows(env_id: str, kwargs: dict[str, Any], steps: int, starts: int, device: str) -> list[tuple[str, float]]:
    """Env steps/s of SPPO compiled with PyTorch's Adam (``capturable=True``), without and with ``foreach``."""
    rows = []
    for foreach in (False, True):
        policy_kwargs = {**(kwargs.get("policy_kwargs") or {}), "optimizer_kwargs": dict(capturable=True, foreach=foreach)}
        settings = {**kwargs, "policy_kwargs": policy_kwargs}
        with torch_adam_in_update():
            model = SPPO("TOLDPolicy", env_id, seed=0, device=device, compile=True, **settings)
            rows.append((f"torch Adam, foreach={foreach}", measure(model, steps, starts)[0]))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_STEPS))
    parser.add_argument("--steps", type=int, default=None, help="timed env steps after the warm-up (default: per env)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: all cores)")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--torch-adam", action="store_true", help="also SPPO compiled with PyTorch's Adam (capturable)")
    args = parser.parse_args()
    if args.threads:
        th.set_num_threads(args.threads)
    print(f"torch {th.__version__}, {th.get_num_threads()} CPU threads, device {args.device}")
    header = ("SAC", "SPPO eager", "SPPO compiled", "compiled/SAC", "eager/SAC", "compile s")
    print(f"{'env':20} {'steps':>6} " + " ".join(f"{h:>13}" for h in header) + "   (env steps/s)")
    for env_id in args.envs:
        kwargs, steps = sppo_kwargs(env_id), args.steps or DEFAULT_STEPS.get(env_id, 1000)
        starts = int(kwargs.get("learning_starts", 5000))
        sac, _ = measure(SAC("MlpPolicy", env_id, seed=0, device=args.device, learning_starts=starts), steps, starts)
        eager, _ = measure(SPPO("TOLDPolicy", env_id, seed=0, device=args.device, compile=False, **kwargs), steps, starts)
        compiled_model = SPPO("TOLDPolicy", env_id, seed=0, device=args.device, compile=True, **kwargs)
        compiled, _ = measure(compiled_model, steps, starts)
        total_compile = compiled_model.compile_stats["seconds"]
        figures = (sac, eager, compiled, compiled / sac, eager / sac, total_compile)
        print(f"{env_id:20} {steps:6d} " + " ".join(f"{x:13.2f}" for x in figures), flush=True)
        if args.torch_adam:
            for name, rate in torch_adam_rows(env_id, kwargs, steps, starts, args.device):
                print(f"{'':20} {name}: {rate:.2f} env steps/s ({rate / compiled:.2f}x SPPO compiled)", flush=True)


if __name__ == "__main__":
    main()
