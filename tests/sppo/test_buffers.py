"""ShieldedReplayBuffer: B holds every real step; B̃ relabels the first intervention and stops (eqs. 7, 8)."""

import numpy as np
import pytest
from gymnasium import spaces

from sppo_sb3.common.keys import INTERVENED_KEY, PROPOSED_ACTION_KEY
from sppo_sb3.sppo.buffers import ShieldedReplayBuffer

OBS = spaces.Box(-10, 10, (1,), np.float32)
ACT = spaces.Box(-2, 2, (1,), np.float32)


def fill(buffer: ShieldedReplayBuffer, episodes: list[list[bool]]) -> None:
    """Add episodes; each step's obs is its global index, reward 1, the executed action 0.5 (env units 1.0)."""
    t = 0
    for interventions in episodes:
        for i, shielded in enumerate(interventions):
            done = i == len(interventions) - 1
            info = {"cost": 0.0, INTERVENED_KEY: shielded, PROPOSED_ACTION_KEY: np.array([2.0])}
            buffer.add(np.array([[t]]), np.array([[t + 1]]), np.array([[0.5]]), np.array([1.0]), np.array([done]), [info])
            t += 1


def test_absorbing_relabel_terminates_at_first_intervention():
    buffer = ShieldedReplayBuffer(100, OBS, ACT, device="cpu", penalty=1.0, on_intervention="terminate")
    fill(buffer, [[False, False, True, False, True, False], [False, False]])
    # B holds every real step
    assert buffer.size() == 8
    assert np.all(buffer.actions[:8] == 0.5)
    # B̃ holds the steps up to and including T = 2, then nothing more of that episode, then the next episode
    assert buffer.relabel_valid[:8, 0].tolist() == [True, True, True, False, False, False, True, True]
    batch = buffer.sample_sequences(256, 4)
    first = batch.observations[:, 0].numpy().astype(int)
    assert set(first) <= {0, 1, 2, 6, 7}
    for j, start in enumerate(first):
        steps = batch.mask[:, j].numpy().astype(bool)
        idx = start + np.flatnonzero(steps)
        assert set(idx) <= {0, 1, 2, 6, 7}
        for k, t in enumerate(idx):
            if t == 2:  # the absorbing transition: proposed action (scaled 2.0 -> 1.0), R̃, terminal
                assert batch.actions[k, j, 0].item() == pytest.approx(1.0)
                assert batch.rewards[k, j].item() == -1.0
                assert batch.terminals[k, j].item() == 1.0
                assert batch.consistency_mask[k, j].item() == 0.0
            else:
                assert batch.actions[k, j, 0].item() == pytest.approx(0.5)
                assert batch.rewards[k, j].item() == 1.0


def test_restart_mode_keeps_learning_after_an_intervention():
    buffer = ShieldedReplayBuffer(100, OBS, ACT, device="cpu", on_intervention="restart")
    fill(buffer, [[False, True, False, False]])
    assert buffer.relabel_valid[:4, 0].all()
    batch = buffer.sample_sequences(128, 3)
    starts = batch.observations[:, 0].numpy().astype(int)
    for j in np.flatnonzero(starts == 0):  # a sequence from step 0 ends at the intervention (step 1)
        assert batch.mask[:, j].tolist() == [1.0, 1.0, 0.0]


def test_sequences_never_cross_episode_ends_or_the_write_head():
    rng = np.random.default_rng(0)
    buffer = ShieldedReplayBuffer(50, OBS, ACT, device="cpu", on_intervention="terminate")
    lengths = rng.integers(1, 7, size=30)
    fill(buffer, [[False] * int(n) for n in lengths])  # wraps the 50-step buffer several times
    episode_of = np.repeat(np.arange(len(lengths)), lengths)
    batch = buffer.sample_sequences(512, 5)
    for j in range(512):
        start = int(batch.observations[j, 0])
        steps = start + np.flatnonzero(batch.mask[:, j].numpy())
        assert steps[0] == start and np.all(np.diff(steps) == 1)  # contiguous from the start
        assert len(set(episode_of[steps])) == 1  # one episode only
        assert steps[-1] < len(episode_of)  # never past the newest step
        assert start >= len(episode_of) - 50  # never overwritten data


def test_sampling_an_empty_buffer_is_a_clear_error():
    buffer = ShieldedReplayBuffer(10, OBS, ACT, device="cpu")
    with pytest.raises(RuntimeError, match="collect some steps"):
        buffer.sample_sequences(4, 2)


def sequences_from(buffer: ShieldedReplayBuffer, start: int, length: int) -> dict[str, np.ndarray]:
    """The fields of the sampled sequences that start at step ``start`` (one of them; every draw is the same)."""
    batch = buffer.sample_sequences(256, length)
    j = int(np.flatnonzero(batch.observations[:, 0].numpy().astype(int) == start)[0])
    fields = ("actions", "rewards", "terminals", "mask", "consistency_mask")
    return {name: getattr(batch, name)[:, j].numpy().squeeze() for name in fields}


def test_continue_mode_penalises_the_proposal_without_a_terminal():
    """Where a violation does not end the episode, the rejected proposal costs the penalty and its value bootstraps
    from s'."""
    buffer = ShieldedReplayBuffer(100, OBS, ACT, device="cpu", penalty=3.0, on_intervention="continue")
    fill(buffer, [[False, True, False, False]])
    assert buffer.relabel_valid[:4, 0].all()
    seq = sequences_from(buffer, 0, 3)
    np.testing.assert_array_equal(seq["mask"], [1, 1, 0])  # TOLD's roll stops: s' did not follow the proposal
    np.testing.assert_allclose(seq["actions"][:2], [0.5, 1.0])  # the proposal (2.0 scaled to 1.0) at the intervention
    np.testing.assert_allclose(seq["rewards"][:2], [1.0, 1.0 - 3.0])  # its reward less the penalty
    np.testing.assert_array_equal(seq["terminals"][:2], [0, 0])  # not a death: the TD target bootstraps from s'
    np.testing.assert_array_equal(seq["consistency_mask"], [1, 0, 0])
    after = sequences_from(buffer, 2, 2)  # and learning goes on from the next real state
    np.testing.assert_array_equal(after["mask"], [1, 1])


def test_none_mode_learns_the_executed_steps_as_they_were():
    buffer = ShieldedReplayBuffer(100, OBS, ACT, device="cpu", penalty=3.0, on_intervention="none")
    fill(buffer, [[False, True, False, False]])
    seq = sequences_from(buffer, 0, 3)
    np.testing.assert_allclose(seq["actions"], [0.5, 0.5, 0.5])  # the executed (backup) action, env units 1.0
    np.testing.assert_allclose(seq["rewards"], [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(seq["terminals"], [0, 0, 0])
    np.testing.assert_array_equal(seq["mask"], [1, 1, 1])  # a real transition: the roll goes on through it
    np.testing.assert_array_equal(seq["consistency_mask"], [1, 1, 1])


def test_an_unknown_mode_is_a_clear_error():
    with pytest.raises(ValueError, match="takes 'terminate', 'restart', 'continue', 'none'"):
        ShieldedReplayBuffer(10, OBS, ACT, device="cpu", on_intervention="stop")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="cannot implement on_intervention='takeover'"):
        ShieldedReplayBuffer(10, OBS, ACT, device="cpu", on_intervention="takeover")


def test_a_negative_penalty_is_a_clear_error():
    """One sign convention: a penalty is what an intervention costs, >= 0 (R̃ = -penalty)."""
    with pytest.raises(ValueError, match=r"a number >= 0.*got -1\.0"):
        ShieldedReplayBuffer(10, OBS, ACT, device="cpu", penalty=-1.0)
