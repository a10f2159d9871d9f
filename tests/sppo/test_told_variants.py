"""TOLD's variants: ``told="paper"`` (TD-MPC's model, the default) and ``told="tdmpc2"`` (TD-MPC2's LayerNorm + Mish
hidden layers, SimNorm latents and a five-head Q ensemble whose TD target is the min of two random heads).

That ``"paper"`` trains bit for bit as before the option is checked with ``scripts/training_fingerprints.py``.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator

import numpy as np
import pytest
import torch as th
from tiny_hyperparams import TINY_SPPO, TINY_TOLD
from torch import nn

from sppo_sb3 import SPPO
from sppo_sb3.sppo.buffers import SequenceSamples
from sppo_sb3.sppo.compile import CompiledFunction
from sppo_sb3.sppo.optim import init_optimizer_state
from sppo_sb3.sppo.planner import MPPIConfig, _Cast, draw_noise, low_precision_copy, mppi
from sppo_sb3.sppo.policies import TOLDPolicy
from sppo_sb3.sppo.topo import TOPO_STATS, TOPOConfig, draw_target_heads, td_target, topo_update, value_loss
from sppo_sb3.sppo.world_model import ELU, TOLD, SimNorm, zero_last_layer

OBS, ACT, H, B = 3, 2, 3, 5
TDMPC2_TOLD = {**TINY_TOLD, "latent_dim": 16}  # two SimNorm groups


def tdmpc2(termination: bool = False, seed: int = 0) -> TOLD:
    th.manual_seed(seed)
    return TOLD(OBS, ACT, **TDMPC2_TOLD, termination=termination, told="tdmpc2")


def batch() -> SequenceSamples:
    g = th.Generator().manual_seed(1)
    ones = th.ones(H, B)
    terminals = th.zeros(H, B)
    terminals[1, 2] = 1.0
    return SequenceSamples(
        observations=th.randn(B, OBS, generator=g),
        actions=th.rand(H, B, ACT, generator=g) * 2 - 1,
        rewards=th.randn(H, B, generator=g),
        next_observations=th.randn(H, B, OBS, generator=g),
        terminals=terminals,
        mask=ones,
        consistency_mask=ones,
    )


def layer_types(net: nn.Sequential) -> list[type[nn.Module]]:
    return [type(layer) for layer in net]


# ---------------------------------------------------------------------------- the networks
def test_tdmpc2_told_has_five_q_heads_and_layernorm_mish_hidden_layers() -> None:
    model = tdmpc2(termination=True)
    assert model.told == "tdmpc2" and model.num_q == 5 and model.q_names == ("q1", "q2", "q3", "q4", "q5")
    z, a = th.randn(7, model.latent_dim), th.rand(7, ACT)
    assert [q.shape for q in model.q(z, a)] == [(7, 1)] * 5
    hidden = [nn.Linear, nn.LayerNorm, nn.Mish]
    for net in (model.reward, model.pi, model.termination, *model.q_heads):
        assert isinstance(net, nn.Sequential)
        assert layer_types(net) == hidden * 2 + [nn.Linear]
    assert layer_types(model.encoder) == [*hidden, nn.Linear, nn.LayerNorm, SimNorm]
    assert layer_types(model.dynamics) == [*hidden, *hidden, nn.Linear, nn.LayerNorm, SimNorm]
    assert not any(isinstance(m, (nn.ELU, nn.Tanh)) for m in model.modules())
    for head in (model.reward, *model.q_heads):  # zero-initialised output layers, as the paper's TOLD
        assert not head(th.cat([z, a], -1)).any()


def test_paper_told_is_the_default_and_unchanged() -> None:
    model = TOLD(OBS, ACT, **TINY_TOLD)
    assert model.told == "paper" and model.q_names == ("q1", "q2")
    assert layer_types(model.q1) == [nn.Linear, nn.LayerNorm, nn.Tanh, nn.Linear, ELU, nn.Linear]
    assert layer_types(model.encoder) == [nn.Linear, ELU, nn.Linear]
    assert not any(isinstance(m, (nn.Mish, SimNorm)) for m in model.modules())


def test_tdmpc2_latents_are_simnormed_in_groups_of_eight() -> None:
    model = tdmpc2()
    with th.no_grad():
        z = model.encode(th.randn(6, OBS) * 5)
        next_z = model.next_latent(z, th.rand(6, ACT) * 2 - 1)
    for latent in (z, next_z):
        groups = latent.view(6, -1, 8)
        assert groups.shape[1] == 2
        assert (groups >= 0).all()
        th.testing.assert_close(groups.sum(-1), th.ones(6, 2))
    x = th.randn(2, 3, 16)
    th.testing.assert_close(SimNorm()(x), th.softmax(x.view(2, 3, 2, 8), -1).view(2, 3, 16))


def test_tdmpc2_rejects_a_latent_dim_not_a_multiple_of_eight() -> None:
    with pytest.raises(ValueError, match="latent_dim must be a multiple of 8, got 12"):
        TOLD(OBS, ACT, latent_dim=12, encoder_dim=8, hidden_dim=8, told="tdmpc2")
    TOLD(OBS, ACT, latent_dim=12, encoder_dim=8, hidden_dim=8)  # the paper's TOLD takes any size


def test_an_unknown_told_name_raises_naming_the_choices() -> None:
    with pytest.raises(ValueError, match=r"told='tdmpc3'.*'paper'.*'tdmpc2'"):
        TOLD(OBS, ACT, **TINY_TOLD, told="tdmpc3")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"told='v2'.*'paper'.*'tdmpc2'"):
        SPPO("TOLDPolicy", "SafePointCircle-v0", told="v2")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="SPPO's told argument"):
        SPPO("TOLDPolicy", "SafePointCircle-v0", policy_kwargs={**TINY_TOLD, "told": "tdmpc2"})


# ---------------------------------------------------------------------------- values: planner, policy, TD target
def test_min_q_is_the_twin_min_for_the_paper_and_the_ensemble_mean_for_tdmpc2() -> None:
    z, a = th.randn(4, 8), th.rand(4, ACT)
    paper = TOLD(OBS, ACT, **TINY_TOLD)
    zero_last_layer(paper.q1, 3.0)
    zero_last_layer(paper.q2, 5.0)
    th.testing.assert_close(paper.min_q(z, a), th.full((4, 1), 3.0))
    model = tdmpc2()
    for head, value in zip(model.q_heads, (3.0, 5.0, 7.0, 11.0, 14.0)):
        zero_last_layer(head, value)
    th.testing.assert_close(model.min_q(th.randn(4, 16), a), th.full((4, 1), 8.0))


@pytest.mark.parametrize(("heads", "value"), [([3, 1], 5.0), ([4, 2], 7.0), ([3, 4], 11.0), (None, 3.0)])
def test_td_target_takes_the_min_of_the_chosen_target_heads(heads: list[int] | None, value: float) -> None:
    model = tdmpc2()
    target = copy.deepcopy(model)
    for head, q in zip(target.q_heads, (3.0, 5.0, 7.0, 11.0, 13.0)):  # the target's heads: Q⁻_k constant
        zero_last_layer(head, q)
    for head in model.q_heads:  # the online heads, which the target must not use
        zero_last_layer(head, 100.0)
    cfg, data = TOPOConfig(), batch()
    index = None if heads is None else th.tensor(heads)
    target_q = td_target(
        model, target, data.next_observations, data.rewards, data.terminals, th.zeros(H, B, ACT), cfg, 0.9, index
    )
    th.testing.assert_close(target_q, data.rewards + 0.9 * (1.0 - data.terminals) * value)
    assert target_q[1, 2] == data.rewards[1, 2]  # no bootstrap after a terminal


def test_target_heads_are_two_random_distinct_heads_for_tdmpc2_and_none_for_the_paper() -> None:
    paper = TOLD(OBS, ACT, **TINY_TOLD)
    state = th.get_rng_state()
    assert draw_target_heads(paper) is None
    assert th.equal(th.get_rng_state(), state)  # the paper's TOLD draws nothing: its training stays bit for bit
    model, seen = tdmpc2(), set()
    for _ in range(50):
        heads = draw_target_heads(model)
        assert heads is not None and heads.shape == (2,) and heads.dtype == th.int64
        assert heads[0] != heads[1] and int(heads.min()) >= 0 and int(heads.max()) < 5
        seen.update(heads.tolist())
    assert seen == {0, 1, 2, 3, 4}


def test_the_value_loss_trains_all_five_heads_on_the_target() -> None:
    qs = tuple(th.full((2, 1), float(k)) for k in range(5))
    th.testing.assert_close(value_loss(qs, th.full((2,), 2.0)), th.full((2,), 4.0 + 1.0 + 0.0 + 1.0 + 4.0))
    model = tdmpc2()
    target = copy.deepcopy(model)
    optimizer = th.optim.Adam([p for n, p in model.named_parameters() if not n.startswith("pi.")], lr=1e-2)
    pi_optimizer = th.optim.Adam(model.pi.parameters(), lr=1e-2)
    for opt in (optimizer, pi_optimizer):
        init_optimizer_state(opt)
    before = [head[-1].weight.detach().clone() for head in model.q_heads]
    stats = topo_update(
        model,
        target,
        optimizer,
        pi_optimizer,
        batch(),
        th.zeros(H, B, ACT),
        th.tensor(1e-2),
        th.tensor(0.0),
        TOPOConfig(),
        0.99,
        th.tensor([0, 3]),
    )
    assert th.isfinite(stats).all() and stats[TOPO_STATS.index("value")] > 0
    for old, head in zip(before, model.q_heads):
        assert not th.equal(old, head[-1].weight)  # every head's output layer moved


def test_the_bf16_planner_keeps_every_ensemble_head_output_in_fp32() -> None:
    model = tdmpc2(termination=True)
    shadow = low_precision_copy(model, th.bfloat16)
    for name in ("reward", *shadow.q_names, "termination"):
        head = getattr(shadow, name)
        assert isinstance(head[-2], _Cast) and head[-1].weight.dtype == th.float32
        assert head[0].weight.dtype == th.bfloat16
    cfg = MPPIConfig(num_samples=16, num_elites=4, iterations=2, horizon=3)
    noise = draw_noise(cfg, 2, 3, ACT, True, th.Generator().manual_seed(0), th.device("cpu"))
    with th.no_grad():
        action, _, _ = mppi(shadow, th.randn(2, OBS), th.zeros(2, 3, ACT), noise, th.tensor(0.1), cfg, 0.99)
    assert action.dtype == th.float32 and th.isfinite(action).all()


# ---------------------------------------------------------------------------- compiled update
@pytest.fixture
def compilation_on() -> Iterator[None]:
    with th._dynamo.config.patch(disable=False):
        yield


def make_policy() -> TOLDPolicy:
    import gymnasium as gym

    th.manual_seed(0)
    space = gym.spaces.Box(-1, 1, (OBS,), np.float32)
    action_space = gym.spaces.Box(-1, 1, (ACT,), np.float32)
    policy = TOLDPolicy(space, action_space, lambda _: 1e-3, termination=False, told="tdmpc2", **TDMPC2_TOLD)
    init_optimizer_state(policy.optimizer)
    init_optimizer_state(policy.pi_optimizer)
    return policy


def test_compiled_tdmpc2_update_equals_eager_given_the_same_heads(compilation_on: None) -> None:
    eager_policy = make_policy()
    compiled_policy = copy.deepcopy(eager_policy)
    compiled = CompiledFunction(topo_update, True, th.device("cpu"), "TOPO update")
    data, cfg, noise = batch(), TOPOConfig(), th.randn(H, B, ACT, generator=th.Generator().manual_seed(2))
    for i, heads in enumerate(([0, 3], [4, 1], [2, 0])):
        ema, lr = th.tensor(0.01 if i % 2 else 0.0), th.tensor(1e-3)
        args = (data, noise, lr, ema, cfg, 0.99, th.tensor(heads))
        eager = topo_update(
            eager_policy.model, eager_policy.model_target, eager_policy.optimizer, eager_policy.pi_optimizer, *args
        )
        p = compiled_policy
        comp = compiled(p.model, p.model_target, p.optimizer, p.pi_optimizer, *args).clone()
        th.testing.assert_close(comp, eager, rtol=1e-5, atol=1e-6, msg=lambda m: f"{TOPO_STATS}: {m}")
    assert compiled.compiled, "compilation fell back to eager"
    for (name, a), b in zip(eager_policy.state_dict().items(), compiled_policy.state_dict().values()):
        th.testing.assert_close(b, a, rtol=1e-4, atol=1e-6, msg=lambda m, name=name: f"{name}: {m}")


# ---------------------------------------------------------------------------- SPPO
def test_sppo_with_the_tdmpc2_told_learns_saves_and_loads(tmp_path) -> None:
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", told="tdmpc2", seed=0, compile=False, **TINY_SPPO)
    assert model.policy.model.told == "tdmpc2" and model.policy.model_target.num_q == 5
    initial = copy.deepcopy(model.policy.model.q1.state_dict())
    model.learn(200)
    assert model._n_updates > 0
    assert not th.equal(initial["0.weight"], model.policy.model.q1.state_dict()["0.weight"])
    assert all(th.isfinite(p).all() for p in model.policy.parameters())
    model.save(tmp_path / "sppo")
    loaded = SPPO.load(tmp_path / "sppo", device="cpu")
    assert loaded.told == "tdmpc2" and loaded.policy.told == "tdmpc2" and loaded.policy.model.num_q == 5
    for a, b in zip(model.policy.state_dict().values(), loaded.policy.state_dict().values()):
        assert th.equal(a, b)
    obs = np.array([[0.2, -0.3, 0.5, 0.1], [0.0, 0.4, -0.1, 0.3]], dtype=np.float32)
    state = (np.zeros((2, model.planner_config.horizon, 2), dtype=np.float32),)
    np.testing.assert_array_equal(
        loaded.predict(obs, state, deterministic=True)[0], model.predict(obs, state, deterministic=True)[0]
    )
    with th.no_grad():
        obs_tensor = th.as_tensor(obs)
        np.testing.assert_array_equal(loaded.policy._predict(obs_tensor).numpy(), model.policy._predict(obs_tensor).numpy())
