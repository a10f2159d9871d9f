"""SAILR: the shield decides every executed action; the absorbing MDP's learning data; save/load; n_envs."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from recording import RecordExecuted
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv
from tiny_hyperparams import TINY_SAILR

import sppo_sb3  # noqa: F401  (registers the tasks)
from sppo_sb3.sailr import SAILR
from sppo_sb3.shield import PointCircleShieldingRule, ShieldWrapper


class GrabRollout(BaseCallback):
    """Keeps the infos of every step and the rollout buffer's learning data (before it is flattened)."""

    def __init__(self, extra: tuple[str, ...] = ()) -> None:
        super().__init__()
        self.keys = ("rewards", "masks", "episode_starts", "advantages", "values", *extra)
        self.infos: list[list[dict]] = []
        self.dones: list[np.ndarray] = []
        self.rollouts: list[dict[str, np.ndarray]] = []

    def _on_step(self) -> bool:
        self.infos.append(self.locals["infos"])
        self.dones.append(self.locals["dones"].copy())
        return True

    def _on_rollout_end(self) -> None:
        buf = self.model.rollout_buffer
        self.rollouts.append({k: getattr(buf, k).copy() for k in self.keys})


def test_no_intervened_action_is_ever_executed() -> None:
    recorder = RecordExecuted(gym.make("SafePointCircle-v0"))
    model = SAILR("MlpPolicy", recorder, seed=0, **TINY_SAILR)
    grab = GrabRollout()
    model.learn(512, callback=grab)
    rule = PointCircleShieldingRule()
    obs = np.stack([o for o, _ in recorder.log])
    executed = np.stack([a for _, a in recorder.log])
    intervened = np.array([info[0]["shield_intervened"] for info in grab.infos])
    assert intervened.any(), "the test needs interventions to be meaningful"
    # every executed action is outside the shielding set I (Proposition 1 for the backup actions)
    assert not rule.shield(obs, executed).intervened.any()
    # where the shield intervened, the env received the backup action, not the proposal
    np.testing.assert_allclose(executed[intervened], rule.backup_action(obs[intervened]), atol=1e-6)
    proposals = np.stack([info[0]["proposed_action"] for info in grab.infos])
    np.testing.assert_allclose(executed[~intervened], proposals[~intervened], atol=1e-6)
    assert model.safety_metrics.violations == 0
    assert model.safety_metrics.interventions == intervened.sum()


def test_backup_keeps_control_after_the_first_intervention_of_an_episode() -> None:
    model = SAILR("MlpPolicy", "SafePointCircle-v0", seed=1, **TINY_SAILR)
    grab = GrabRollout()
    model.learn(1024, callback=grab)
    intervened = np.array([info[0]["shield_intervened"] for info in grab.infos])
    dones = np.concatenate(grab.dones)
    episode_ends = np.flatnonzero(dones)
    checked = 0
    for start, stop in zip(np.r_[0, episode_ends[:-1] + 1], episode_ends + 1):
        first = np.flatnonzero(intervened[start:stop])
        if first.size:
            assert intervened[start + first[0] : stop].all()  # SAILR's code: ζ runs the rest of the episode
            checked += 1
    assert checked > 0, "the test needs interventions to be meaningful"


def test_absorbing_transition_and_post_intervention_mask() -> None:
    model = SAILR("MlpPolicy", "SafePointCircle-v0", seed=1, **{**TINY_SAILR, "n_steps": 256, "batch_size": 64, "n_epochs": 1})
    grab = GrabRollout(extra=("costs", "cost_advantages", "cost_values"))
    model.learn(1024, callback=grab)
    absorbing_cost = 1.0 / (1.0 - model.gamma)
    assert model.absorbing_cost == pytest.approx(absorbing_cost)
    intervened = np.array([info[0]["shield_intervened"] for info in grab.infos])
    dones = np.concatenate(grab.dones)
    data = {k: np.concatenate([r[k][:, 0] for r in grab.rollouts]) for k in grab.rollouts[0]}
    rewards, costs, masks, starts = data["rewards"], data["costs"], data["masks"], data["episode_starts"]
    # expected learning data, step by step: first intervention → absorbing, then masked until the episode ends
    post, first_seen = False, 0
    for t in range(len(intervened)):
        assert masks[t] == (0.0 if post else 1.0), t
        if not post and intervened[t]:
            first_seen += 1
            assert rewards[t] == 0.0 and costs[t] == pytest.approx(absorbing_cost)
            # absorbing: A = r - V(s_t) and A_C = 1/(1-γ) - V_C(s_t), no bootstrap (also at the end of a rollout)
            assert data["advantages"][t] == pytest.approx(-data["values"][t], abs=1e-5)
            assert data["cost_advantages"][t] == pytest.approx(absorbing_cost - data["cost_values"][t], abs=1e-4)
            if t + 1 < len(starts) and (t + 1) % 256:
                assert starts[t + 1] == 1.0  # terminal for learning: GAE does not bootstrap through it
            post = not dones[t]
        else:
            assert post or costs[t] == 0.0  # the env's own costs are not learned from
            if dones[t]:
                post = False
    assert first_seen > 0 and (masks == 0).any()


def test_policy_follows_the_penalised_advantage(monkeypatch: pytest.MonkeyPatch) -> None:
    model = SAILR("MlpPolicy", "SafePointCircle-v0", seed=2, penalty=2.0, **TINY_SAILR)
    seen: list[np.ndarray] = []
    monkeypatch.setattr(PPO, "train", lambda self: seen.append(self.rollout_buffer.advantages.copy()))
    grab = GrabRollout(extra=("cost_advantages",))
    model.learn(TINY_SAILR["n_steps"], callback=grab)
    rollout = grab.rollouts[0]
    expected = (rollout["advantages"] - 2.0 * rollout["cost_advantages"]) / 3.0
    np.testing.assert_allclose(seen[0], expected, rtol=1e-5, atol=1e-6)


def test_sailr_train_skips_fully_masked_rollout() -> None:
    model = SAILR("MlpPolicy", "SafePointCircle-v0", seed=0, **TINY_SAILR)
    model.learn(64)
    model.rollout_buffer.masks[:] = 0.0  # a rollout made only of post-intervention steps
    model.rollout_buffer.generator_ready = False
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.train()
    assert all((a == b).all() for a, b in zip(before, model.policy.parameters()))


def test_sailr_smoke_save_load_predict(tmp_path) -> None:
    model = SAILR("MlpPolicy", "SafePointCircle-v0", seed=0, tensorboard_log=str(tmp_path / "tb"), **TINY_SAILR)
    model.learn(256, progress_bar=True)
    assert model.safety_metrics.steps == 256
    model.save(tmp_path / "sailr")
    loaded = SAILR.load(tmp_path / "sailr", env=make_vec_env("SafePointCircle-v0", n_envs=1))
    assert isinstance(loaded.shield_rule, PointCircleShieldingRule)
    assert all(loaded.get_env().env_is_wrapped(ShieldWrapper))  # the loaded model shields its new env too
    obs = np.random.default_rng(0).uniform(-2, 2, size=(16, 4)).astype(np.float32)
    np.testing.assert_allclose(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    np.testing.assert_equal(loaded.safety_metrics.summary(), model.safety_metrics.summary())  # NaN-aware
    loaded.learn(64, reset_num_timesteps=False)
    assert loaded.safety_metrics.steps == 320


def test_sailr_n_envs_and_user_rule() -> None:
    env = make_vec_env("SafePointCircle-v0", n_envs=2, seed=0)
    rule = PointCircleShieldingRule()
    model = SAILR("MlpPolicy", env, shield=rule, seed=0, **TINY_SAILR)
    assert model.shield_rule is rule
    assert all(env.env_is_wrapped(ShieldWrapper))
    model.learn(256)
    assert model.safety_metrics.steps == 256 and model.safety_metrics.violations == 0
    rewards, masks = model.rollout_buffer.rewards, model.rollout_buffer.masks
    assert rewards.shape == (64, 2) and set(np.unique(masks.ravel())) <= {0.0, 1.0}


def test_sailr_shield_errors() -> None:
    with pytest.raises(ValueError, match="No shielding rule is registered"):
        SAILR("MlpPolicy", "Pendulum-v1", **TINY_SAILR)
    with pytest.raises(ValueError, match="SAILR's penalty is what an intervention costs the learner, a number >= 0"):
        SAILR("MlpPolicy", "SafePointCircle-v0", penalty=-1.0, **TINY_SAILR)
    with pytest.raises(ValueError, match=r"SAILR cannot implement on_intervention='continue'.*takes 'takeover'"):
        SAILR("MlpPolicy", "SafePointCircle-v0", on_intervention="continue", **TINY_SAILR)
    env = make_vec_env("SafePointCircle-v0", n_envs=1, vec_env_cls=SubprocVecEnv, vec_env_kwargs=dict(start_method="fork"))
    try:
        with pytest.raises(TypeError, match="wrapper_class"):
            SAILR("MlpPolicy", env, **TINY_SAILR)
    finally:
        env.close()


def test_sailr_accepts_prewrapped_envs() -> None:
    rule = PointCircleShieldingRule()
    env = DummyVecEnv([lambda: ShieldWrapper(gym.make("SafePointCircle-v0"), rule)])
    model = SAILR("MlpPolicy", env, shield=None, **TINY_SAILR)
    assert model.shield_rule is rule
    model.learn(64)
