"""Planner benchmark: ms per planned action and achieved GFLOP/s against this machine's matmul peak.

Runs, in one process and on the same model weights:

- ``peak``: the best square matmul throughput of the device (the reference "100%"), in fp32 and bf16;
- ``reference``: a straightforward TD-MPC-style planner — one env at a time, every iteration re-scoring all
  ``N + N_π`` trajectories with plain ``nn.Module`` calls;
- ``sppo``: the package's batched planner (:class:`sppo_sb3.sppo.planner.MPPIPlanner`), fp32 and bf16, eager and
  compiled (``torch.compile``; its compile time is printed apart and not in the figures);
- ``gemm floor``: the planner's own matmuls alone — the same shapes and counts, without bias, activations or Python —
  the fastest any planner of this network can be with this machine's GEMM kernels. Its ``% peak`` is the ceiling for
  the planners' ``% peak``, and ``% floor`` says how close a planner comes to it.

Sizes: TD-MPC, the class default (N=512+25 policy samples, k=64, J=6, H=5, hidden 512, latent 50), and the small
configuration of ``hyperparams/sppo.yml`` for low-dimensional tasks.

    python scripts/bench_planner.py                    # CPU (and CUDA when present), n_envs 1, 8, 64
    python scripts/bench_planner.py --quick            # a short run: n_envs 1 and 8, fewer repeats
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import Any

import torch as th
from torch import nn

from sppo_sb3.sppo.planner import MPPIConfig, MPPIPlanner
from sppo_sb3.sppo.world_model import TOLD

OBS_DIM, ACTION_DIM = 17, 6  # Half-Cheetah sizes
GAMMA = 0.99  # the paper's discount
SIZES: dict[str, dict[str, Any]] = {
    # the class defaults (TD-MPC): N=512 (+25 policy samples), k=64, J=6, H=5, hidden 512, latent 50
    "td-mpc": dict(latent_dim=50, encoder_dim=256, hidden_dim=512, config=MPPIConfig()),
    # hyperparams/sppo.yml's low-dimensional tasks (Point Robot, Pendulum)
    "small": dict(
        latent_dim=32,
        encoder_dim=64,
        hidden_dim=128,
        config=MPPIConfig(num_samples=64, num_elites=8, iterations=3, horizon=3, policy_fraction=0.1),
    ),
}


def synchronize(device: th.device) -> None:
    if device.type == "cuda":
        th.cuda.synchronize()


def timed(fn: Callable[[], object], device: th.device, repeats: int) -> float:
    """Best wall time of ``repeats`` calls after one warm-up call, in seconds."""
    fn()
    synchronize(device)
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        synchronize(device)
        best = min(best, time.perf_counter() - start)
    return best


def matmul_peak(device: th.device, dtype: th.dtype) -> float:
    """Best GFLOP/s of square matmuls of a few sizes on ``device``."""
    best = 0.0
    for n in (1024, 1536, 2048):
        a, b = th.randn(n, n, device=device, dtype=dtype), th.randn(n, n, device=device, dtype=dtype)
        seconds = timed(partial(th.matmul, a, b), device, repeats=10)
        best = max(best, 2 * n**3 / seconds / 1e9)
    return best


def linear_flops(net: nn.Module) -> int:
    """Multiply-add FLOPs of one sample through every Linear layer of ``net``."""
    return sum(2 * m.in_features * m.out_features for m in net.modules() if isinstance(m, nn.Linear))


def linear_layers(net: nn.Module) -> list[nn.Linear]:
    return [m for m in net.modules() if isinstance(m, nn.Linear)]


def gemm_floor(model: TOLD, cfg: MPPIConfig, n_envs: int, device: th.device, repeats: int) -> tuple[float, int]:
    """Seconds and FLOPs of the scoring matmuls of one ``plan`` call alone (eq. 10 for ``J`` iterations, in the
    planner's row blocks): every Linear of ``d`` and ``R`` ``H`` times, of ``π``, ``Q1`` and ``Q2`` once, per block."""
    rows = n_envs * cfg.num_samples
    n_blocks = math.ceil(rows / cfg.max_rows)
    block_rows = math.ceil(rows / n_blocks)
    step = linear_layers(model.dynamics) + linear_layers(model.reward)
    terminal = linear_layers(model.pi) + linear_layers(model.q1) + linear_layers(model.q2)
    seconds, flops = 0.0, 0
    for layer, calls in [(m, cfg.horizon) for m in step] + [(m, 1) for m in terminal]:
        x = th.randn(block_rows, layer.in_features, device=device)
        seconds += calls * timed(partial(th.mm, x, layer.weight.detach().t()), device, repeats)
        flops += calls * 2 * block_rows * layer.in_features * layer.out_features
    return seconds * n_blocks * cfg.iterations, flops * n_blocks * cfg.iterations


def planner_flops(model: TOLD, cfg: MPPIConfig, n_envs: int, rescore_policy: bool) -> int:
    """FLOPs of one planned action per env: the encoder, the policy rollout, and ``J`` iterations of eq. 10."""
    step = linear_flops(model.dynamics) + linear_flops(model.reward)
    terminal = linear_flops(model.pi) + linear_flops(model.q1) + linear_flops(model.q2)
    rollout = cfg.horizon * step + terminal
    n, p = cfg.num_samples, cfg.num_policy_samples
    policy = p * (rollout + cfg.horizon * linear_flops(model.pi))
    per_iteration = (n + p if rescore_policy else n) * rollout
    return n_envs * (linear_flops(model.encoder) + policy + cfg.iterations * per_iteration)


@th.inference_mode()
def reference_plan(model: TOLD, obs: th.Tensor, cfg: MPPIConfig) -> th.Tensor:
    """A straightforward planner: one env at a time, all ``N + N_π`` trajectories re-scored every iteration."""
    actions = []
    for env_obs in obs:
        z = model.encode(env_obs[None])
        p, n, h = cfg.num_policy_samples, cfg.num_samples, cfg.horizon
        pi_actions, zp = [], z.repeat(p, 1)
        for _ in range(h):
            pi_actions.append(model.policy(zp, cfg.policy_std))
            zp, _ = model.next(zp, pi_actions[-1])
        pi_seq = th.stack(pi_actions)  # (H, P, A)
        mean, std = th.zeros(h, ACTION_DIM, device=obs.device), th.full((h, ACTION_DIM), cfg.max_std, device=obs.device)
        for _ in range(cfg.iterations):
            samples = (mean[:, None] + std[:, None] * th.randn(h, n, ACTION_DIM, device=obs.device)).clamp(-1, 1)
            seq = th.cat([samples, pi_seq], dim=1)
            zs, value = z.repeat(n + p, 1), th.zeros(n + p, 1, device=obs.device)
            for t in range(h):
                zs, reward = model.next(zs, seq[t])
                value += GAMMA**t * reward
            value += GAMMA**h * model.min_q(zs, model.policy(zs, cfg.policy_std))
            elite_value, idx = value.squeeze(1).topk(cfg.num_elites)
            elites = seq[:, idx]
            score = th.exp(cfg.temperature * (elite_value - elite_value.max()))
            score = score / score.sum()
            new_mean = (score[None, :, None] * elites).sum(1)
            std = th.sqrt((score[None, :, None] * (elites - new_mean[:, None]) ** 2).sum(1)).clamp(cfg.min_std_end, 2)
            mean = cfg.momentum * mean + (1 - cfg.momentum) * new_mean
        actions.append(mean[0])
    return th.stack(actions)


def run(device: th.device, n_envs_list: list[int], repeats: int, sizes: list[str]) -> list[dict]:
    results = []
    peak32, peak16 = matmul_peak(device, th.float32), matmul_peak(device, th.bfloat16)
    print(f"\n[{device}] matmul peak: fp32 {peak32:.1f} GFLOP/s, bf16 {peak16:.1f} GFLOP/s")
    columns = ("ms/action", "GFLOP/s", "% peak", "% floor", "speed-up")
    print(f"{'size':8} {'n_envs':>6} {'planner':>20} " + " ".join(f"{c:>9}" for c in columns))
    for size in sizes:
        spec = SIZES[size]
        cfg = replace(spec["config"], horizon_warmup=0, min_std_decay=0)  # full horizon, final ε
        model = TOLD(OBS_DIM, ACTION_DIM, spec["latent_dim"], spec["encoder_dim"], spec["hidden_dim"]).to(device)
        for n_envs in n_envs_list:
            obs = th.randn(n_envs, OBS_DIM, device=device)
            ref_reps = 1 if n_envs > 8 else repeats
            ref_s = timed(partial(reference_plan, model, obs, cfg), device, ref_reps)
            ref_flops = planner_flops(model, cfg, n_envs, rescore_policy=True)
            sppo_flops = planner_flops(model, cfg, n_envs, rescore_policy=False)
            rows = [("reference fp32", ref_s, ref_flops, peak32)]
            for name, variant, peak in [("fp32", cfg, peak32), ("bf16", replace(cfg, dtype="bfloat16"), peak16)]:
                for compiled in (False, True):
                    planner = MPPIPlanner(variant, ACTION_DIM, GAMMA, device, compile=compiled)
                    plan = partial(planner.plan, model, obs, planner.initial_mean(n_envs), 10**9)
                    if compiled:
                        start = time.perf_counter()
                        plan()
                        print(f"  (compiling the {name} planner for {n_envs} envs took {time.perf_counter() - start:.1f} s)")
                    label = f"sppo {name}{' compiled' if compiled else ''}"
                    rows.append((label, timed(plan, device, repeats), sppo_flops, peak))
            floor_s, floor_flops = gemm_floor(model, cfg, n_envs, device, repeats)
            rows.append(("gemm floor fp32", floor_s, floor_flops, peak32))
            for name, seconds, flops, peak in rows:
                gflops = flops / seconds / 1e9
                row = dict(device=str(device), size=size, n_envs=n_envs, planner=name, ms_per_action=1e3 * seconds / n_envs,
                           gflops=gflops, pct_peak=100 * gflops / peak, pct_floor=100 * floor_s / seconds,
                           speedup=ref_s / seconds)  # fmt: skip
                results.append(row)
                print(f"{size:8} {n_envs:6d} {name:>20} {row['ms_per_action']:9.2f} {gflops:9.1f} {row['pct_peak']:8.0f}% "
                      f"{row['pct_floor']:8.0f}% {row['speedup']:8.2f}x")  # fmt: skip
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="n_envs 1 and 8, one repeat")
    parser.add_argument("--n-envs", type=int, nargs="+", default=None)
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES))
    parser.add_argument("--devices", nargs="+", default=None, help="e.g. cuda (default: cpu, and cuda when present)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: all cores)")
    parser.add_argument("--json", type=str, default=None, help="also write the rows to this JSON file")
    args = parser.parse_args()
    if args.threads:
        th.set_num_threads(args.threads)
    n_envs_list = args.n_envs or ([1, 8] if args.quick else [1, 8, 64])
    repeats = 1 if args.quick else 3
    devices = [th.device(d) for d in args.devices] if args.devices else [th.device("cpu")]
    devices += [] if args.devices or not th.cuda.is_available() else [th.device("cuda")]
    print(f"torch {th.__version__}, {th.get_num_threads()} CPU threads")
    results = [row for device in devices for row in run(device, n_envs_list, repeats, args.sizes)]
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
