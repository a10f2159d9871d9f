"""Policy-guided MPPI in TOLD's latent space (eqs. 2, 3, 10, 11; Alg. 2 lines 2–15), batched over all envs.

Shapes: ``E`` envs, ``N`` Gaussian samples, ``P`` policy samples, ``H`` horizon, ``A`` action dims, ``J`` iterations.
Every tensor carries all envs at once; the only Python loops run over the ``H`` model steps and the ``J`` iterations.

:func:`mppi` is a pure function of the observations, the warm start and the noise drawn for it (:class:`PlanNoise`),
so it compiles into one graph per (horizon, n_envs) and repeats exactly given the same inputs. The warm start is the
planner's state: :class:`MPPIPlanner` draws the noise and keeps no state of its own; the caller owns the warm start
(SPPO keeps training's, ``SPPO.predict`` takes and returns it as SB3's recurrent ``state``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import NamedTuple

import torch as th
from torch import nn

from sppo_sb3.sppo.compile import CompiledFunction
from sppo_sb3.sppo.world_model import TOLD


def linear_schedule(start: float, end: float, duration: int, step: int) -> float:
    """Linear interpolation from ``start`` to ``end`` over ``duration`` steps, then constant at ``end``."""
    frac = min(max(step, 0) / duration, 1.0) if duration > 0 else 1.0
    return start + frac * (end - start)


@dataclass
class MPPIConfig:
    """Planner settings (TD-MPC defaults).

    :param num_samples: ``N``, trajectories sampled from ``N(μ, σ²)`` per iteration.
    :param num_elites: ``k``, the top-k trajectories that refit ``μ, σ``.
    :param iterations: ``J``, refits per planned action.
    :param horizon: final planning horizon ``H``.
    :param horizon_warmup: steps over which ``H`` grows linearly from 1 to ``horizon``.
    :param policy_fraction: ``N_π / N``, share of trajectories proposed by ``π`` (TD-MPC's mixture coefficient).
    :param temperature: ``τ`` of the elite weights ``Ω = exp(τ(Φ - max Φ))``.
    :param momentum: weight of the previous mean in ``μ ← m·μ + (1 - m)·μ_new``.
    :param min_std_start: ``ε`` of eq. 11 at step 0.
    :param min_std_end: ``ε`` after ``min_std_decay`` steps.
    :param min_std_decay: steps of the linear decay of ``ε``.
    :param max_std: upper clamp of ``σ`` (and its initial value).
    :param policy_std: std of the clipped noise on ``π``'s actions inside the planner.
    :param num_candidates: actions :func:`mppi` proposes per env, best first: ``μ_J``'s (the plan), then the first
        actions of the ``num_candidates - 1`` best trajectories of the first iteration, whose samples spread widest.
        A shield executes the first it accepts (SPPO's collection and ``predict``), so that where it rejects the plan
        the executed step is another of the planner's own choices rather than the backup's. 1: the plan alone, the
        paper's eq. 12.
    :param max_rows: trajectories scored per network call: the ``E·N`` samples of many envs are cut into equal
        blocks of at most this many rows, so each block's activations stay in cache (64 envs × 512 samples of 512-wide
        activations are 64 MB; the unblocked batch is slower per action: ``scripts/bench_planner.py``).
    :param dtype: ``"float32"`` or ``"bfloat16"``: precision of the planner's hidden layers. bf16 runs on AMX
        (recent Xeon CPUs) and tensor cores faster (``scripts/bench_planner.py``); reward and value heads stay fp32, so
        returns and elite weights keep fp32 precision.
    """

    num_samples: int = 512
    num_elites: int = 64
    iterations: int = 6
    horizon: int = 5
    horizon_warmup: int = 25_000
    policy_fraction: float = 0.05
    temperature: float = 0.5
    momentum: float = 0.1
    min_std_start: float = 0.5
    min_std_end: float = 0.05
    min_std_decay: int = 25_000
    max_std: float = 2.0
    policy_std: float = 0.05
    num_candidates: int = 1
    max_rows: int = 2048
    dtype: str = "float32"

    def __post_init__(self) -> None:
        if self.iterations < 1 or not 1 <= self.num_elites <= self.num_samples + self.num_policy_samples:
            raise ValueError(
                "MPPI needs iterations >= 1 and 1 <= num_elites <= the trajectories it scores (num_samples plus "
                f"policy_fraction of them); got iterations={self.iterations}, num_elites={self.num_elites}, "
                f"num_samples={self.num_samples}."
            )
        if not 1 <= self.num_candidates <= self.num_elites + 1:
            raise ValueError(
                f"num_candidates is the plan plus up to num_elites ({self.num_elites}) alternatives, so 1 to "
                f"{self.num_elites + 1}; got {self.num_candidates}."
            )

    def horizon_at(self, step: int) -> int:
        return max(1, round(linear_schedule(1, self.horizon, self.horizon_warmup, step)))

    def min_std_at(self, step: int) -> float:
        return linear_schedule(self.min_std_start, self.min_std_end, self.min_std_decay, step)

    @property
    def num_policy_samples(self) -> int:
        return int(self.policy_fraction * self.num_samples)


class _Cast(nn.Module):
    def __init__(self, dtype: th.dtype) -> None:
        super().__init__()
        self.dtype = dtype

    def forward(self, x: th.Tensor) -> th.Tensor:
        return x.to(self.dtype)


def low_precision_copy(model: TOLD, dtype: th.dtype) -> TOLD:
    """A copy of ``model`` with hidden layers in ``dtype`` and the last layer of the reward, value (every head of the
    ensemble) and termination heads in fp32."""
    shadow = copy.deepcopy(model).to(dtype)
    for name in ("reward", *shadow.q_names, "termination"):
        head: nn.Sequential | None = getattr(shadow, name)
        if head is None:
            continue
        layers = list(head)
        setattr(shadow, name, nn.Sequential(*layers[:-1], _Cast(th.float32), layers[-1].float()))
    return shadow


class PlanNoise(NamedTuple):
    """Standard normal draws for one call of :func:`mppi`.

    :param samples: ``(J, E, N, H, A)`` for the Gaussian action sequences.
    :param terminal: ``(J, E·N, A)`` for the policy noise on ``π(z_H)`` of those sequences (eq. 10).
    :param policy: ``(H + 1, E·P, A)`` for the policy noise along the ``π`` rollouts.
    :param action: ``(E, A)`` for the executed sample of ``N(μ_J, σ_J²)`` (zeros: deterministic).
    """

    samples: th.Tensor
    terminal: th.Tensor
    policy: th.Tensor
    action: th.Tensor


def draw_noise(
    cfg: MPPIConfig,
    n_envs: int,
    horizon: int,
    action_dim: int,
    deterministic: bool,
    generator: th.Generator | None,
    device: th.device,
) -> PlanNoise:
    """All the randomness of one plan, drawn on ``device`` with ``generator`` (torch's global RNG if None)."""
    shapes = (
        (cfg.iterations, n_envs, cfg.num_samples, horizon, action_dim),
        (cfg.iterations, n_envs * cfg.num_samples, action_dim),
        (horizon + 1, n_envs * cfg.num_policy_samples, action_dim),
    )
    samples, terminal, policy = (th.randn(shape, generator=generator, device=device) for shape in shapes)
    action = th.zeros(n_envs, action_dim, device=device)
    if not deterministic:
        action.normal_(generator=generator)
    return PlanNoise(samples, terminal, policy, action)


def trajectory_return(
    model: TOLD,
    z: th.Tensor,
    actions: th.Tensor,
    gamma: float,
    policy_std: float,
    terminal_noise: th.Tensor,
    penalty: th.Tensor | None = None,
) -> th.Tensor:
    """``Φ = Σ_{t<H} γ^t c_t R(z_t, a_t) + γ^H c_H Q(z_H, π(z_H))`` (eq. 10) for a flat batch, with ``Q``
    :meth:`TOLD.min_q` (the min of the twin heads; the mean of the five for the ``"tdmpc2"`` TOLD).

    ``c_t`` is the probability that the imagined episode of ``M̃`` is still running at step ``t`` (the product of
    :meth:`TOLD.continuation` before ``t``): after a predicted absorbing step ``s†`` adds no reward and no value
    (eq. 7). Without a termination head ``c_t = 1``, TD-MPC's return. With an intervention head and a ``penalty``,
    each step also pays ``penalty · P(I | z_t, a_t)``, its predicted intervention priced (not in the paper).

    :param z: ``(B, latent)`` start latents.
    :param actions: ``(H, B, A)`` action sequences.
    :param terminal_noise: ``(B, A)`` standard normal draws for the policy noise on ``π(z_H)``.
    :param penalty: the price of an intervention (0-d tensor; None: none).
    :return: ``(B,)`` returns.
    """
    value = th.zeros(z.shape[0], device=z.device)
    alive = th.ones(z.shape[0], device=z.device)
    for t in range(actions.shape[0]):
        z, alive = step_return(model, z, actions[t], alive, gamma**t, value, penalty)
    terminal = model.min_q(z, model.policy(z, policy_std, terminal_noise.to(z.dtype))).squeeze(-1)
    return value + gamma ** actions.shape[0] * alive * terminal


def step_return(
    model: TOLD,
    z: th.Tensor,
    action: th.Tensor,
    alive: th.Tensor,
    discount: float,
    value: th.Tensor,
    penalty: th.Tensor | None = None,
) -> tuple[th.Tensor, th.Tensor]:
    """One imagined step of eq. 10: adds ``discount · c_t · (R(z_t, a_t) - penalty · P(I | z_t, a_t))`` to ``value`` in
    place (the second term only with an intervention head and a ``penalty``).

    :return: the next latent and ``c_(t+1) = c_t · (1 - P(termination))``.
    """
    next_z, reward = model.next(z, action)
    reward = reward.squeeze(-1).float()
    if penalty is not None and model.intervention is not None:
        reward = reward - penalty * model.intervention_probability(z, action).float()
    value += discount * alive * reward
    if model.termination is not None:
        alive = alive * model.continuation(z, action).float()
    return next_z, alive


def blocked_returns(
    model: TOLD,
    z: th.Tensor,
    actions: th.Tensor,
    terminal_noise: th.Tensor,
    cfg: MPPIConfig,
    gamma: float,
    block_rows: int,
    penalty: th.Tensor | None = None,
) -> th.Tensor:
    """Eq. 10 for ``(B, latent)`` starts and ``(H, B, A)`` actions, in row blocks whose activations stay in cache."""
    blocks = zip(z.split(block_rows), actions.split(block_rows, dim=1), terminal_noise.split(block_rows))
    return th.cat([trajectory_return(model, zb, ab, gamma, cfg.policy_std, nb, penalty) for zb, ab, nb in blocks])


def policy_rollout(
    model: TOLD,
    z: th.Tensor,
    horizon: int,
    gamma: float,
    policy_std: float,
    noise: th.Tensor,
    penalty: th.Tensor | None = None,
) -> tuple[th.Tensor, th.Tensor]:
    """Roll ``π`` through ``d`` (Alg. 2 line 5) and score it by eq. 10 in the same pass.

    :param noise: ``(H + 1, B, A)`` standard normal draws for the policy noise.
    :return: actions ``(H, B, A)`` and returns ``(B,)``.
    """
    noise = noise.to(z.dtype)
    actions, value = [], th.zeros(z.shape[0], device=z.device)
    alive = th.ones(z.shape[0], device=z.device)
    for t in range(horizon):
        actions.append(model.policy(z, policy_std, noise[t]))
        z, alive = step_return(model, z, actions[-1], alive, gamma**t, value, penalty)
    value += gamma**horizon * alive * model.min_q(z, model.policy(z, policy_std, noise[horizon])).squeeze(-1)
    return th.stack(actions), value


def refit_gaussian(elites: th.Tensor, elite_returns: th.Tensor, temperature: float) -> tuple[th.Tensor, th.Tensor]:
    """Weighted elite mean and std (eqs. 2 and 3) with ``Ω_i = exp(τ(Φ_i - max Φ))``.

    :param elites: ``(E, k, H, A)`` elite action sequences.
    :param elite_returns: ``(E, k)`` their returns.
    :return: ``μ`` and ``σ``, each ``(E, H, A)``.
    """
    omega = th.exp(temperature * (elite_returns - elite_returns.max(dim=1, keepdim=True).values))
    weights = (omega / omega.sum(dim=1, keepdim=True))[:, :, None, None]
    mean = (weights * elites).sum(dim=1)
    std = th.sqrt((weights * (elites - mean.unsqueeze(1)) ** 2).sum(dim=1))
    return mean, std


def mppi(
    model: TOLD,
    obs: th.Tensor,
    warm_mean: th.Tensor,
    noise: PlanNoise,
    min_std: th.Tensor,
    cfg: MPPIConfig,
    gamma: float,
    penalty: th.Tensor | None = None,
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Plan one action per env (Alg. 2 lines 2–15).

    :param model: the TOLD model (in the planning precision).
    :param obs: ``(E, obs_dim)`` observations.
    :param warm_mean: ``(E, H, A)`` the initial mean ``μ_0`` (the warm start); ``H`` is this plan's horizon.
    :param noise: the plan's standard normal draws.
    :param min_std: ``ε`` of eq. 11 (0-d tensor).
    :param cfg: the planner's settings.
    :param gamma: the discount of eq. 10 (SPPO's ``gamma``).
    :param penalty: the price of a predicted intervention in eq. 10 (0-d tensor; None: none, the paper's return).
    :return: actions ``(E, A)`` in [-1, 1] — ``μ_J``'s first step plus ``σ_J`` times ``noise.action`` —, ``μ_J``
        and the alternatives ``(E, num_candidates - 1, A)``: the first actions of the first iteration's best
        trajectories, best first.
    """
    n_envs, horizon, adim = warm_mean.shape
    n, p = cfg.num_samples, cfg.num_policy_samples
    z = model.encode(obs.to(next(model.parameters()).dtype))
    pi_actions, pi_returns = policy_rollout(
        model, z.repeat_interleave(p, 0), horizon, gamma, cfg.policy_std, noise.policy, penalty
    )
    pi_actions = pi_actions.view(horizon, n_envs, p, adim).permute(1, 2, 0, 3).float()
    pi_returns = pi_returns.view(n_envs, p)
    z_samples = z.repeat_interleave(n, 0)
    block_rows = math.ceil(len(z_samples) / math.ceil(len(z_samples) / cfg.max_rows))  # equal blocks, no small tail
    mean, std = warm_mean, th.full_like(warm_mean, cfg.max_std)
    for j in range(cfg.iterations):
        samples = (mean.unsqueeze(1) + std.unsqueeze(1) * noise.samples[j]).clamp(-1.0, 1.0)
        flat = samples.permute(2, 0, 1, 3).reshape(horizon, n_envs * n, adim).to(z.dtype)
        returns = blocked_returns(model, z_samples, flat, noise.terminal[j], cfg, gamma, block_rows, penalty).view(n_envs, n)
        all_actions, all_returns = th.cat([samples, pi_actions], 1), th.cat([returns, pi_returns], 1)
        elite_returns, elite_idx = all_returns.topk(cfg.num_elites, dim=1)
        elites = all_actions.gather(1, elite_idx[:, :, None, None].expand(-1, -1, horizon, adim))
        if j == 0:  # topk sorts: the best first
            alternatives = elites[:, : cfg.num_candidates - 1, 0]
        new_mean, new_std = refit_gaussian(elites, elite_returns, cfg.temperature)
        mean = cfg.momentum * mean + (1.0 - cfg.momentum) * new_mean
        std = th.maximum(new_std, min_std).clamp(max=cfg.max_std)  # eq. 11: σ ≥ ε
    action = (mean[:, 0] + std[:, 0] * noise.action).clamp(-1.0, 1.0)
    return action, mean, alternatives


class Plan(NamedTuple):
    """What :meth:`MPPIPlanner.plan` returns.

    :param action: ``(E, A)`` the planned actions in [-1, 1].
    :param mean: ``(E, H_max, A)`` the new plan mean, the next call's ``prev_mean``.
    :param candidates: ``(E, num_candidates, A)`` the planned action, then the alternatives of :func:`mppi`, best first.
    """

    action: th.Tensor
    mean: th.Tensor
    candidates: th.Tensor


def warm_start(prev_mean: th.Tensor, horizon: int) -> th.Tensor:
    """The previous plan's ``(E, H_max, A)`` mean shifted by one step (its last step padded with 0), cut to ``horizon``."""
    shifted = th.zeros_like(prev_mean)
    shifted[:, :-1] = prev_mean[:, 1:]
    return shifted[:, :horizon]


class MPPIPlanner:
    """Policy-guided MPPI: draws the noise, keeps the planning-precision copy of the model and the compiled plan.

    The warm start is not kept here: :meth:`plan` takes the previous plan's mean and returns the new one.

    :param config: planner settings.
    :param action_dim: action size.
    :param gamma: the discount of eq. 10 (SPPO's ``gamma``, the one its update's TD target uses).
    :param device: torch device of the model.
    :param compile: compile :func:`mppi` (one graph per horizon and number of envs).
    """

    def __init__(
        self, config: MPPIConfig, action_dim: int, gamma: float, device: th.device | str = "cpu", compile: bool = False
    ) -> None:
        self.config, self.action_dim, self.gamma = config, action_dim, gamma
        self.device = th.device(device)
        self.dtype = getattr(th, config.dtype)
        self._shadow: TOLD | None = None
        self._shadow_stale = True
        self.function = CompiledFunction(mppi, compile, self.device, "planner")

    @property
    def compiled(self) -> bool:
        """Whether plans run the compiled graph."""
        return self.function.compiled

    def initial_mean(self, n_envs: int) -> th.Tensor:
        """The cold start: a zero ``(E, H_max, A)`` mean."""
        return th.zeros(n_envs, self.config.horizon, self.action_dim, device=self.device)

    def mark_stale(self) -> None:
        """Tell a reduced-precision planner that the model's weights changed (call after each update)."""
        self._shadow_stale = True

    @th.no_grad()
    def _planning_model(self, model: TOLD) -> TOLD:
        if self.dtype == th.float32:
            return model
        if self._shadow is None:
            self._shadow = low_precision_copy(model, self.dtype)
        elif self._shadow_stale:
            for mine, theirs in zip(self._shadow.parameters(), model.parameters()):
                mine.copy_(theirs)
        self._shadow_stale = False
        return self._shadow

    @th.no_grad()
    def plan(
        self,
        model: TOLD,
        obs: th.Tensor,
        prev_mean: th.Tensor,
        step: int,
        deterministic: bool = False,
        generator: th.Generator | None = None,
        penalty: float | None = None,
    ) -> Plan:
        """Plan one action per env from the previous plan's mean, shifted (Alg. 2 lines 2–15).

        :param obs: ``(E, obs_dim)`` observations.
        :param prev_mean: ``(E, H_max, A)`` the previous plan's mean (zeros where an episode starts).
        :param step: training step, for the horizon and ``ε`` schedules.
        :param deterministic: return ``μ_J``'s first action instead of a sample from ``N(μ_J, σ_J²)``.
        :param generator: where the noise comes from (torch's global RNG on the model's device if None); a CPU
            generator gives the same plan on every device.
        :param penalty: the price of a predicted intervention (SPPO's multiplier; None: none).
        :return: the actions, the new mean and the candidates (:class:`Plan`).
        """
        cfg, n_envs = self.config, obs.shape[0]
        if prev_mean.shape != (n_envs, cfg.horizon, self.action_dim):
            raise ValueError(
                f"The planner's state must have shape {(n_envs, cfg.horizon, self.action_dim)} (n_envs, horizon, "
                f"action dims) for {n_envs} observations, got {tuple(prev_mean.shape)}."
            )
        horizon = cfg.horizon_at(step)
        noise_device = generator.device if generator is not None else self.device
        noise = draw_noise(cfg, n_envs, horizon, self.action_dim, deterministic, generator, noise_device)
        noise = PlanNoise(*(x.to(self.device) for x in noise))
        min_std = th.tensor(cfg.min_std_at(step), device=self.device)
        warm = warm_start(prev_mean.to(self.device), horizon)
        price = None if penalty is None else th.tensor(penalty, device=self.device)
        action, mean, alternatives = self.function(
            self._planning_model(model), obs.to(self.device), warm, noise, min_std, cfg, self.gamma, price
        )
        new_mean = th.zeros_like(prev_mean, device=self.device)
        new_mean[:, :horizon] = mean
        return Plan(action.clone(), new_mean, th.cat([action.unsqueeze(1), alternatives.float()], dim=1))
