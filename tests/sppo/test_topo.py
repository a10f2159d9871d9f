"""TOPO's targets pinned to the paper's equations, on networks whose outputs are set by hand: a bug shared by the eager
and the compiled update (which ``tests/sppo/test_compile.py`` compares with each other) fails here.

- the TD target of eq. 16 is ``r + γ (1 - d) min Q⁻(z', π(z'))``: the *target* network's twin heads, their minimum, no
  bootstrap after a terminal;
- the consistency loss of eq. 17 compares ``d(z, a)`` with the *target* encoder's ``h⁻(s')``;
- the policy step moves ``π`` alone: ``Q``, ``d``, ``R`` and ``h`` are unchanged by it.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch as th

from sppo_sb3.sppo.buffers import SequenceSamples
from sppo_sb3.sppo.compile import CompiledFunction
from sppo_sb3.sppo.optim import init_optimizer_state
from sppo_sb3.sppo.topo import TOPO_STATS, TOPOConfig, model_loss, td_target, topo_update
from sppo_sb3.sppo.world_model import TOLD, zero_last_layer

OBS, ACT, H, B = 3, 2, 3, 5


def models() -> tuple[TOLD, TOLD]:
    th.manual_seed(0)
    model = TOLD(OBS, ACT, latent_dim=4, encoder_dim=8, hidden_dim=8)
    return model, copy.deepcopy(model)


def batch(terminals: th.Tensor | None = None) -> SequenceSamples:
    g = th.Generator().manual_seed(1)
    ones = th.ones(H, B)
    return SequenceSamples(
        observations=th.randn(B, OBS, generator=g),
        actions=th.rand(H, B, ACT, generator=g) * 2 - 1,
        rewards=th.randn(H, B, generator=g),
        next_observations=th.randn(H, B, OBS, generator=g),
        terminals=th.zeros(H, B) if terminals is None else terminals,
        mask=ones,
        consistency_mask=ones,
    )


def test_td_target_is_reward_plus_discounted_min_of_the_target_twin_q() -> None:
    model, target = models()
    zero_last_layer(target.q1, 3.0)  # the target's heads: Q1⁻ ≡ 3, Q2⁻ ≡ 5
    zero_last_layer(target.q2, 5.0)
    zero_last_layer(model.q1, 100.0)  # the online heads, which the target must not use
    zero_last_layer(model.q2, 100.0)
    cfg = TOPOConfig()
    terminals = th.zeros(H, B)
    terminals[1, 2] = 1.0
    data = batch(terminals)
    target_q = td_target(model, target, data.next_observations, data.rewards, data.terminals, th.zeros(H, B, ACT), cfg, 0.9)
    expected = data.rewards + 0.9 * (1.0 - terminals) * 3.0
    th.testing.assert_close(target_q, expected)
    assert target_q[1, 2] == data.rewards[1, 2]  # no bootstrap after a terminal


def test_consistency_loss_is_against_the_target_encoder() -> None:
    model, target = models()
    zero_last_layer(target.encoder, 0.25)  # h⁻(s') ≡ 0.25 in every latent dimension
    cfg = TOPOConfig(rho=0.5)
    data = batch()
    _, _, _, _, consistency, *_ = model_loss(model, target, data, th.zeros(H, B, ACT), cfg, 0.99)
    with th.no_grad():
        z = model.encode(data.observations)
        expected = th.zeros(())
        for i in range(H):
            z = model.next_latent(z, data.actions[i])
            expected += 0.5**i * ((z - 0.25) ** 2).mean()
    th.testing.assert_close(consistency, expected)
    with th.no_grad():  # against the online encoder instead, the loss would differ
        online = model.encode(data.next_observations[0])
    assert not th.allclose(online, th.full_like(online, 0.25))


@pytest.mark.parametrize("termination", [False, True])
def test_policy_step_moves_pi_alone(termination: bool) -> None:
    """With the model loss switched off (all its weights 0, so its Adam step is 0), an update changes ``π`` only."""
    th.manual_seed(0)
    model = TOLD(OBS, ACT, latent_dim=4, encoder_dim=8, hidden_dim=8, termination=termination)
    zero_last_layer(model.q1, 0.0)
    for layer in model.q1, model.q2:  # non-zero heads, so that the policy's objective has a gradient
        last = [m for m in layer.modules() if isinstance(m, th.nn.Linear)][-1]
        th.nn.init.normal_(last.weight)
    target = copy.deepcopy(model)
    optimizer = th.optim.Adam([p for name, p in model.named_parameters() if not name.startswith("pi.")], lr=1e-2)
    pi_optimizer = th.optim.Adam(model.pi.parameters(), lr=1e-2)
    for opt in optimizer, pi_optimizer:
        init_optimizer_state(opt)
    before = {name: p.detach().clone() for name, p in model.named_parameters()}
    cfg = TOPOConfig(reward_coef=0.0, value_coef=0.0, consistency_coef=0.0, termination_coef=0.0)
    topo_update(
        model, target, optimizer, pi_optimizer, batch(), th.zeros(H, B, ACT), th.tensor(1e-2), th.tensor(0.0), cfg, 0.99
    )
    changed = {name for name, p in model.named_parameters() if not th.equal(p, before[name])}
    assert changed and all(name.startswith("pi.") for name in changed)
    for name, p in target.named_parameters():  # EMA weight 0: the target is untouched too
        np.testing.assert_array_equal(p.detach().numpy(), before[name].numpy())


@pytest.mark.parametrize("path", ["eager", "compiled"])
def test_update_logs_the_hand_computed_terms_and_steps_pi_alone(path: str) -> None:
    """The whole update, eager and compiled: its reward, value and consistency terms equal eqs. 14–17 computed by hand
    (TD target from the *target* twin heads' minimum, no bootstrap after a terminal, consistency against the *target*
    encoder), and with the model loss switched off the step moves ``π`` alone."""
    th.manual_seed(0)
    model = TOLD(OBS, ACT, latent_dim=4, encoder_dim=8, hidden_dim=8)
    for layer in model.q1, model.q2, model.reward:  # non-zero online heads: a gradient for π, terms that are not 0
        th.nn.init.normal_([m for m in layer.modules() if isinstance(m, th.nn.Linear)][-1].weight)
    target = copy.deepcopy(model)
    zero_last_layer(target.q1, 3.0)
    zero_last_layer(target.q2, 5.0)
    zero_last_layer(target.encoder, 0.25)
    terminals = th.zeros(H, B)
    terminals[1, 2] = terminals[2, 0] = 1.0
    data = batch(terminals)
    cfg = TOPOConfig(rho=0.5, reward_coef=0.0, value_coef=0.0, consistency_coef=0.0, termination_coef=0.0)

    with th.no_grad():  # eqs. 14–17 by hand
        z, reward, value, consistency = model.encode(data.observations), 0.0, 0.0, 0.0
        for i in range(H):
            target_q = data.rewards[i] + 0.9 * (1.0 - terminals[i]) * 3.0
            q1, q2 = (head.squeeze(-1) for head in model.q(z, data.actions[i]))
            reward += 0.5**i * ((model.predicted_reward(z, data.actions[i]).squeeze(-1) - data.rewards[i]) ** 2).mean()
            value += 0.5**i * ((q1 - target_q) ** 2 + (q2 - target_q) ** 2).mean()
            z = model.next_latent(z, data.actions[i])
            consistency += 0.5**i * ((z - 0.25) ** 2).mean()

    optimizer = th.optim.Adam([p for name, p in model.named_parameters() if not name.startswith("pi.")], lr=1e-2)
    pi_optimizer = th.optim.Adam(model.pi.parameters(), lr=1e-2)
    for opt in optimizer, pi_optimizer:
        init_optimizer_state(opt)
    before = {name: p.detach().clone() for name, p in model.named_parameters()}
    update = CompiledFunction(topo_update, path == "compiled", th.device("cpu"), "TOPO update")
    stats = update(
        model, target, optimizer, pi_optimizer, data, th.zeros(H, B, ACT), th.tensor(1e-2), th.tensor(0.0), cfg, 0.9
    )
    assert update.compiled == (path == "compiled")
    logged = dict(zip(TOPO_STATS, stats.tolist(), strict=True))
    assert logged["reward"] == pytest.approx(float(reward), rel=1e-5)
    assert logged["value"] == pytest.approx(float(value), rel=1e-5)
    assert logged["consistency"] == pytest.approx(float(consistency), rel=1e-5)
    changed = {name for name, p in model.named_parameters() if not th.equal(p, before[name])}
    assert changed and all(name.startswith("pi.") for name in changed)
