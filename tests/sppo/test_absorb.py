"""The absorbing MDP end to end: termination-aware planning, Definition 2's scale, β, Theorem 1, deployment safety."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from recording import RecordExecuted
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from tiny_hyperparams import TINIEST_MPPI, TINIEST_TOLD, TINY_ROLLOUT
from trainable_told import trainable_told

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3 import PDO, SPPO
from sppo_sb3.envs.point_circle import PointParams, point_is_unsafe, point_step
from sppo_sb3.shield import LearnedCostCriticRule, PointCircleShieldingRule, ShieldWrapper
from sppo_sb3.shield.analysis.bounds import adoptability_gap, discounted_violation, theorem1_bound
from sppo_sb3.shield.evaluation import evaluate_deployment
from sppo_sb3.sppo.buffers import SequenceSamples
from sppo_sb3.sppo.planner import policy_rollout, trajectory_return
from sppo_sb3.sppo.policies import TOLDPolicy
from sppo_sb3.sppo.topo import TOPO_STATS, TOPOConfig, topo_update
from sppo_sb3.sppo.world_model import TOLD

GAMMA = 0.9


def tiny_told(termination: bool) -> TOLD:
    th.manual_seed(0)
    return TOLD(obs_dim=3, action_dim=2, **TINIEST_TOLD, termination=termination)


def set_termination_logit(model: TOLD, logit: float) -> None:
    """Make the termination head a constant: ``P(termination) = sigmoid(logit)`` for every ``(z, a)``."""
    assert model.termination is not None
    last = model.termination[-1]
    with th.no_grad():
        last.weight.zero_()
        last.bias.fill_(logit)


def manual_return(model: TOLD, z: th.Tensor, actions: th.Tensor, noise: th.Tensor, alive_per_step: float) -> th.Tensor:
    """Eq. 10 written out step by step, with a constant continuation probability per step."""
    value, alive = th.zeros(z.shape[0]), 1.0
    for t in range(actions.shape[0]):
        z, reward = model.next(z, actions[t])
        value += GAMMA**t * alive * reward.squeeze(-1)
        alive *= alive_per_step
    return value + GAMMA ** actions.shape[0] * alive * model.min_q(z, model.policy(z, 0.0, noise)).squeeze(-1)


def randomise_heads(model: TOLD) -> None:
    """Non-zero reward and value heads (they start at exactly 0), so that returns differ."""
    with th.no_grad():
        for net in (model.reward, model.q1, model.q2):
            net[-1].weight.normal_()
            net[-1].bias.normal_()


@pytest.mark.parametrize("termination", [False, True])
def test_planner_return_stops_after_a_predicted_termination(termination: bool) -> None:
    model = tiny_told(termination)
    randomise_heads(model)
    z, actions, noise = th.randn(5, 4), th.rand(3, 5, 2) * 2 - 1, th.zeros(5, 2)
    with th.no_grad():
        if termination:
            set_termination_logit(model, 50.0)  # the first step surely ends the episode: only R(z_0, a_0) counts
            first_reward = model.predicted_reward(z, actions[0]).squeeze(-1)
            th.testing.assert_close(trajectory_return(model, z, actions, GAMMA, 0.0, noise), first_reward)
            set_termination_logit(model, 0.0)  # each step ends it with probability 1/2
            expected = manual_return(model, z, actions, noise, 0.5)
        else:
            expected = manual_return(model, z, actions, noise, 1.0)  # TD-MPC's return: no episode ever ends
        th.testing.assert_close(trajectory_return(model, z, actions, GAMMA, 0.0, noise), expected)


def test_policy_rollout_scores_with_the_termination_head() -> None:
    model = tiny_told(termination=True)
    randomise_heads(model)
    set_termination_logit(model, 50.0)
    z = th.randn(4, 4)
    with th.no_grad():
        actions, value = policy_rollout(model, z, 3, GAMMA, 0.0, th.zeros(4, 4, 2))
        th.testing.assert_close(value, model.predicted_reward(z, actions[0]).squeeze(-1))


def test_termination_head_learns_the_absorbing_flags() -> None:
    """TOPO's cross-entropy teaches the head which (s, a) end the episode of M̃ (here: a_0 > 0)."""
    model, target, optimizer, pi_optimizer = trainable_told(termination=True)
    lr, ema = th.tensor(3e-3), th.tensor(0.0)
    for _ in range(300):
        obs, actions = th.randn(64, 3), th.rand(1, 64, 2) * 2 - 1
        terminals = (actions[..., 0] > 0).float()
        ones = th.ones(1, 64)
        batch = SequenceSamples(obs, actions, -terminals, th.randn(1, 64, 3), terminals, ones, ones - terminals)
        stats = topo_update(model, target, optimizer, pi_optimizer, batch, th.zeros(1, 64, 2), lr, ema, TOPOConfig(), GAMMA)
    obs, actions = th.randn(256, 3), th.rand(256, 2) * 2 - 1
    with th.no_grad():
        predicted_end = model.continuation(model.encode(obs), actions) < 0.5
    accuracy = (predicted_end == (actions[:, 0] > 0)).float().mean().item()
    assert accuracy > 0.9
    assert stats[TOPO_STATS.index("termination")].item() > 0.0


def test_termination_model_switch(tmp_path) -> None:
    kwargs = dict(policy_kwargs=TINIEST_TOLD, learning_starts=10, compile=False, seed=0)
    tdmpc = SPPO("TOLDPolicy", "SafePointCircle-v0", **kwargs)  # the default: TD-MPC's model
    assert tdmpc.policy.model.termination is None
    model = SPPO("TOLDPolicy", "SafePointCircle-v0", termination_model=True, **kwargs)
    assert model.policy.model.termination is not None
    model.save(tmp_path / "m.zip")
    assert SPPO.load(tmp_path / "m.zip").policy.model.termination is not None
    space = gym.make("SafePointCircle-v0")
    with pytest.raises(TypeError, match="termination"):  # no default: a saved policy always says which model it is
        TOLDPolicy(space.observation_space, space.action_space, lambda _: 1e-3)


# ---------------------------------------------------------------------------- Definition 2, β and Theorem 1
def sample_point_states(n: int, rng: np.random.Generator) -> np.ndarray:
    """Safe Point states, many of them near the unsafe set and fast."""
    x = rng.uniform(-2.5, 2.5, n)
    y = rng.uniform(-6.0, 6.0, n)
    v = rng.uniform(-2.0, 2.0, (n, 2))
    speed = np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(speed > 2.0, 2.0 * v / speed, v)
    return np.column_stack([x, y, v])


def test_definition2_scale_keeps_every_decision() -> None:
    rng = np.random.default_rng(0)
    rule = PointCircleShieldingRule(eta=0.3)
    obs, actions = sample_point_states(4000, rng), rng.uniform(-1.0, 1.0, (4000, 2))
    q = rule.definition2_value(obs, actions)
    assert q.min() >= 0.0 and q.max() <= rule.gamma + 1e-12  # Definition 2: Q̄ ∈ [0, γ]
    assert q.max() > 0.5  # the sample reaches the unsafe set
    np.testing.assert_allclose(q, (1 - rule.gamma) * rule.cost_value(obs, actions))
    backup = rule.backup_action(obs)
    advantage_d2 = q - rule.definition2_value(obs, backup)
    assert np.array_equal(advantage_d2 > rule.definition2_eta, rule.shield(obs, actions).intervened)


def test_point_rule_is_adoptable() -> None:
    """Proposition 2.1: Q̄ of the braking backup on the true dynamics is adoptable: β = 0 (up to rounding)."""
    rng = np.random.default_rng(1)
    rule, params = PointCircleShieldingRule(), PointParams()
    obs, actions = sample_point_states(20_000, rng), rng.uniform(-1.0, 1.0, (20_000, 2))
    next_obs = point_step(obs, actions, params)
    beta = adoptability_gap(rule, obs, actions, next_obs, point_is_unsafe(next_obs, params))
    assert beta < 1e-9


def first_violation_steps(env: gym.Env, episodes: int, seed: int) -> list[int | None]:
    """Random proposals (the worst a planner can do) for whole episodes: the step of each episode's first violation."""
    rng, steps = np.random.default_rng(seed), []
    env.reset(seed=seed)
    for _ in range(episodes):
        env.reset()
        first, t, done = None, 0, False
        while not done:
            _, _, terminated, truncated, info = env.step(rng.uniform(-1.0, 1.0, 2).astype(np.float32))
            t += 1
            if info["cost"] > 0 and first is None:
                first = t
            done = terminated or truncated
        steps.append(first)
    return steps


def test_theorem1_bound_holds_for_shielded_exploration() -> None:
    """V̄ of shielded random exploration, measured over 20 episodes, stays within Theorem 1's bound; unshielded not."""
    rule = PointCircleShieldingRule()
    env = gym.make("SafePointCircle-v0")
    start, _ = env.reset(seed=0)
    start = start[None].astype(np.float64)
    backup_value = float(rule.definition2_value(start, rule.backup_action(start))[0])
    rng, params = np.random.default_rng(2), PointParams()
    obs, actions = sample_point_states(20_000, rng), rng.uniform(-1.0, 1.0, (20_000, 2))
    next_obs = point_step(obs, actions, params)
    beta = adoptability_gap(rule, obs, actions, next_obs, point_is_unsafe(next_obs, params))
    bound = theorem1_bound(backup_value, beta, rule.definition2_eta, rule.gamma)
    shielded = discounted_violation(first_violation_steps(ShieldWrapper(env, rule), 20, seed=3), rule.gamma)
    assert shielded <= bound + 1e-9
    unshielded = discounted_violation(first_violation_steps(gym.make("SafePointCircle-v0"), 20, seed=3), rule.gamma)
    assert unshielded > bound  # the check can fail: without the shield random exploration violates


def test_evaluate_deployment_with_and_without_the_shield() -> None:
    model = SPPO(
        "TOLDPolicy",
        "SafePointCircle-v0",
        policy_kwargs=TINIEST_TOLD,
        planner_kwargs=TINIEST_MPPI,
        compile=False,
        seed=0,
    )
    make = lambda: gym.make("SafePointCircle-v0", max_episode_steps=50)  # noqa: E731
    shielded = evaluate_deployment(model, make, n_eval_episodes=2, shielded=True)
    unshielded = evaluate_deployment(model, make, n_eval_episodes=2, shielded=False)
    assert set(shielded) == set(unshielded) == {"mean_reward", "mean_violations", "safe_episode_rate", "mean_interventions"}
    assert unshielded["mean_interventions"] == 0.0
    assert shielded["mean_violations"] == 0.0 and shielded["safe_episode_rate"] == 100.0
    assert model.shield_at_predict  # restored after the evaluation
    with pytest.raises(ValueError, match="n_eval_episodes"):
        evaluate_deployment(model, make, n_eval_episodes=0)


def test_evaluate_deployment_normalises_the_policys_observations_only() -> None:
    """Under VecNormalize the policy sees normalised observations; the env and its shield keep the raw ones."""
    venv = VecNormalize(DummyVecEnv([lambda: gym.make("SafePointCircle-v0")]), norm_reward=False)
    venv.obs_rms.mean[:] = 1.0
    venv.obs_rms.var[:] = 4.0
    model = PDO("MlpPolicy", venv, **{**TINY_ROLLOUT, "batch_size": 64}, seed=0)
    seen_by_policy: list[np.ndarray] = []
    predict = model.predict

    def spy(obs, *args, **kwargs):  # type: ignore[no-untyped-def]
        seen_by_policy.append(np.array(obs))
        return predict(obs, *args, **kwargs)

    model.predict = spy  # type: ignore[method-assign]
    raw = RecordExecuted(gym.make("SafePointCircle-v0", max_episode_steps=5))
    evaluate_deployment(model, lambda: raw, n_eval_episodes=1, shielded=False, vec_normalize=venv)
    raw_obs = np.array([obs for obs, _ in raw.log])
    assert len(seen_by_policy) == len(raw_obs) == 5
    expected = np.clip((raw_obs - 1.0) / np.sqrt(4.0 + venv.epsilon), -venv.clip_obs, venv.clip_obs)
    np.testing.assert_allclose(np.array(seen_by_policy), expected, rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------------------- Alg. 1 line 12: refine_shield
def random_walk_pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Held-out (state, action) pairs: unshielded random actions from the task's resets, over many episodes."""
    env, rng = gym.make("SafePointCircle-v0"), np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    states, actions = [], []
    for _ in range(n):
        action = rng.uniform(-1.0, 1.0, 2)
        states.append(obs)
        actions.append(action)
        obs, _, terminated, truncated, _ = env.step(action.astype(np.float32))
        if terminated or truncated:
            obs, _ = env.reset()
    return np.array(states, dtype=np.float64), np.array(actions)


def test_refine_shield_fits_a_learned_rule_toward_the_point_rules_cost_value() -> None:
    """SPPO(refine_shield=True) fits a LearnedCostCriticRule on B (Alg. 1 line 12); compared with the model's Q̄.

    B: 3000 uniform random warm-up steps through the (still untrained, so permissive) learned shield. On 3000 held-out
    random-walk pairs after 500 refinement minibatches, the bounds are set with margin from the measured mean absolute
    error against the model rule's Q̄ (both on Definition 2's scale) and the gap between the mean learned Q̄ of
    dangerous pairs (model Q̄ > 0.5) and of harmless ones (model Q̄ = 0); the figures are in
    docs/results/appendix_learned_shields.md. The fit ranks danger but is coarse: the bootstrap reads Q̄(s', ζ(s')) at
    the backup's actions, which random data rarely holds.
    """
    env = gym.make("SafePointCircle-v0")
    model_rule = PointCircleShieldingRule()
    rule = LearnedCostCriticRule(env.observation_space, env.action_space, model_rule.backup_action, tau=0.05, seed=0)
    model = SPPO(
        "TOLDPolicy",
        env,
        shield=rule,
        refine_shield=True,
        learning_starts=3000,
        policy_kwargs=TINIEST_TOLD,
        horizon=2,
        compile=False,
        seed=0,
    )
    model.learn(3000)  # warm-up only: fills B without planning or training
    states, actions = random_walk_pairs(3000, seed=123)
    reference = model_rule.definition2_value(states, actions)
    dangerous, harmless = reference > 0.5, reference == 0.0
    untrained = rule.definition2_value(states, actions)
    assert np.all(untrained == untrained[0]) and untrained[0] < 1e-3  # untrained: Q̄ constant near 0
    model.train(gradient_steps=500, batch_size=256)
    learned = rule.definition2_value(states, actions)
    error, gap = np.abs(learned - reference).mean(), learned[dangerous].mean() - learned[harmless].mean()
    print(f"refine_shield on Point: MAE {error:.3f} (Q̄ ≡ 0 scores {reference.mean():.3f}), danger gap {gap:.3f}")
    assert error < 0.25
    assert gap > 0.02
    with pytest.raises(ValueError, match="refine_shield=True"):
        SPPO("TOLDPolicy", "SafePointCircle-v0", refine_shield=True, compile=False)


@pytest.mark.parametrize("refine", [True, False])
def test_refine_shield_warms_up_with_some_backup_actions(refine: bool) -> None:
    """With refine_shield, a share of the warm-up steps execute ζ(s), whose Q̄ every target reads; without, none."""
    env = gym.make("SafePointCircle-v0")
    brake = PointCircleShieldingRule().backup_action
    rule = LearnedCostCriticRule(env.observation_space, env.action_space, brake, seed=0)
    kwargs = dict(learning_starts=600, policy_kwargs=TINIEST_TOLD, horizon=2, compile=False, seed=0)
    model = SPPO("TOLDPolicy", env, shield=rule, refine_shield=refine, refine_backup_fraction=0.25, **kwargs)
    model.learn(600)
    buffer = model.replay_buffer
    obs, actions = buffer.observations[:600, 0].astype(np.float64), model.policy.unscale_action(buffer.actions[:600, 0])
    share = float(np.all(np.abs(actions - brake(obs)) < 1e-5, axis=1).mean())
    assert (0.17 < share < 0.33) if refine else share == 0.0
    with pytest.raises(ValueError, match="refine_backup_fraction"):
        SPPO("TOLDPolicy", env, shield=rule, refine_shield=True, refine_backup_fraction=1.5, **kwargs)


def test_refine_shield_auto_refines_exactly_the_learnable_rules() -> None:
    """The default: a learned rule is fitted on B (unrefined, it would never shield anything); a model rule is not."""
    env = gym.make("SafePointCircle-v0")
    learned = LearnedCostCriticRule(env.observation_space, env.action_space, PointCircleShieldingRule().backup_action)
    kwargs = dict(learning_starts=100, policy_kwargs=TINIEST_TOLD, horizon=2, compile=False, seed=0)
    assert SPPO("TOLDPolicy", env, shield=learned, **kwargs).shield_is_learned
    assert not SPPO("TOLDPolicy", env, shield=learned, refine_shield=False, **kwargs).shield_is_learned
    model = SPPO("TOLDPolicy", env, **kwargs)
    assert model.refine_shield == "auto" and not model.shield_is_learned  # the task's model rule: nothing to fit
    model.learn(150)
    assert "train/shield_loss" not in model.logger.name_to_value
    with pytest.raises(ValueError, match='True, False or "auto"'):
        SPPO("TOLDPolicy", env, refine_shield="always", **kwargs)
