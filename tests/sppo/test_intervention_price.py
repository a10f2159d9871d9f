"""Planning for the shield (``intervention_target``): TOLD's intervention head, eq. 10 and the prior priced by a PID
Lagrange multiplier that holds the intervention rate at its target."""

from __future__ import annotations

import itertools

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from tiny_hyperparams import TINY_SPPO, TINY_TOLD
from trainable_told import trainable_told

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3 import SPPO
from sppo_sb3.common.lagrange import PIDLagrangian
from sppo_sb3.shield import ShieldingRule
from sppo_sb3.sppo.buffers import SequenceSamples
from sppo_sb3.sppo.planner import MPPIConfig, MPPIPlanner
from sppo_sb3.sppo.topo import TOPO_STATS, TOPOConfig, topo_update
from sppo_sb3.sppo.world_model import TOLD

GAMMA = 0.99


def test_pid_multiplier_rises_above_the_target_and_falls_to_zero_below() -> None:
    pid = PIDLagrangian(target=0.02)
    rising = [pid.update(0.2) for _ in range(100)]
    assert all(b > a for a, b in itertools.pairwise(rising))  # the integral keeps pushing while the rate is too high
    assert pid.multiplier == pytest.approx(1.0 * 0.18 + 0.01 * 100 * 0.18)
    for _ in range(1000):
        pid.update(0.0)
    assert pid.multiplier == 0.0 and pid.integral == 0.0  # never negative: the price of an intervention is >= 0
    with pytest.raises(ValueError, match="target and gains >= 0"):
        PIDLagrangian(target=-0.1)


def priced_model() -> TOLD:
    """One action, reward ``1.6 (a + 1)`` (higher for larger a) and ``P(intervention) = sigmoid(20 a)``: the shield
    rejects whatever pushes a above 0, where the reward is."""
    th.manual_seed(0)
    model = TOLD(3, 1, **TINY_TOLD, intervention=True)
    hidden = TINY_TOLD["hidden_dim"]
    with th.no_grad():
        for net in (model.reward, model.q1, model.q2, model.dynamics, model.intervention):
            for p in net.parameters():
                p.zero_()
        for net, scale, bias in ((model.reward, 0.1, 0.0), (model.intervention, 20.0 / hidden, -20.0)):
            net[0].weight[:, -1] = 1.0  # the action's input column: hidden = a + 1 >= 0 passes both ELUs unchanged
            net[0].bias.fill_(1.0)
            net[2].weight.copy_(th.eye(hidden))
            net[-1].weight.fill_(scale)
            net[-1].bias.fill_(bias)
    return model


@pytest.mark.parametrize("penalty, planned_sign", [(None, 1.0), (10.0, -1.0)])
def test_priced_interventions_steer_the_plan_off_what_the_shield_rejects(penalty, planned_sign) -> None:
    model = priced_model()
    planner = MPPIPlanner(MPPIConfig(num_samples=64, num_elites=8, iterations=4, horizon=2, horizon_warmup=0), 1, GAMMA)
    th.manual_seed(0)
    plan = planner.plan(model, th.zeros(1, 3), planner.initial_mean(1), 10**6, deterministic=True, penalty=penalty)
    assert plan.action.item() * planned_sign > 0.1


def test_intervention_head_learns_which_proposals_the_shield_rejects() -> None:
    """TOPO's cross-entropy teaches the head the shield's decisions on the *proposals* (here: rejected where
    proposal_0 > 0), whatever the executed actions were."""
    model, target, optimizer, pi_optimizer = trainable_told(intervention=True)
    lr, ema, price = th.tensor(3e-3), th.tensor(0.0), th.tensor(1.0)
    for _ in range(300):
        obs, proposals = th.randn(64, 3), th.rand(1, 64, 2) * 2 - 1
        rejected = (proposals[..., 0] > 0).float()
        executed = th.where(rejected[..., None] > 0, th.zeros_like(proposals), proposals)  # the backup's action
        ones, zeros = th.ones(1, 64), th.zeros(1, 64)
        batch = SequenceSamples(obs, executed, zeros, th.randn(1, 64, 3), zeros, ones, ones, proposals, rejected)
        stats = topo_update(
            model, target, optimizer, pi_optimizer, batch, th.zeros(1, 64, 2), lr, ema, TOPOConfig(), GAMMA, None, price
        )
    obs, actions = th.randn(256, 3), th.rand(256, 2) * 2 - 1
    with th.no_grad():
        predicted = model.intervention_probability(model.encode(obs), actions) > 0.5
    assert (predicted == (actions[:, 0] > 0)).float().mean().item() > 0.9
    assert stats[TOPO_STATS.index("intervention")].item() > 0.0


class RejectsMostRule(ShieldingRule):
    """Rejects every proposal with a push above 0.1 on either control; the backup stands still."""

    gamma = 0.99

    def cost_value(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return 10.0 * np.clip(np.abs(actions).max(axis=1) - 0.1, 0.0, None)

    def backup_action(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 2))


def test_sppo_prices_interventions_above_its_target_and_keeps_the_price_on_save(tmp_path) -> None:
    env = gym.make("SafePointCircle-v0")
    rule = RejectsMostRule()
    model = SPPO(
        "TOLDPolicy", env, shield=rule, intervention_target=0.02, penalty=0.3, on_intervention="continue", compile=False,
        seed=0, **TINY_SPPO,
    )  # fmt: skip
    assert model.policy.model.intervention is not None
    assert model.intervention_price is not None and model.intervention_price.multiplier == 0.3  # starts at penalty
    model.learn(150)
    assert model.intervention_rate > 0.02
    assert model.intervention_price.multiplier > 0.3  # above its target, the price rises
    assert model.replay_buffer.penalty == model.intervention_price.multiplier  # and B̃'s relabel pays it
    model.save(tmp_path / "priced.zip")
    loaded = SPPO.load(tmp_path / "priced.zip", custom_objects={"shield_rule": RejectsMostRule()})
    assert loaded.policy.model.intervention is not None
    assert loaded.intervention_price == model.intervention_price
    assert SPPO("TOLDPolicy", env, shield=None, compile=False, **TINY_SPPO).policy.model.intervention is None


@pytest.mark.parametrize("target", [-0.1, 1.0])
def test_intervention_target_is_a_share_of_steps(target) -> None:
    with pytest.raises(ValueError, match="share of env steps"):
        SPPO("TOLDPolicy", "SafePointCircle-v0", intervention_target=target, **TINY_SPPO)
