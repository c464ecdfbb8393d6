"""Replay buffers: the real buffer keeps Ξ and both actions; rings wrap; virtual transitions are sampled."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from core.loop import StepRecord
from core.prior import SharedReplayBuffer
from core.replay import ReplayBuffer, VirtualBuffer


def record(i: int, takeover: bool, violation: bool = False, terminated: bool = False) -> StepRecord:
    obs = np.full(3, i, np.float32)
    a_rl = np.array([0.1 * i, 0.0], np.float32)
    a_expert = np.array([-1.0, 1.0], np.float32) if takeover else None
    return StepRecord(
        episode=0,
        t=i,
        obs=obs,
        a_rl=a_rl,
        a_expert=a_expert,
        action=a_expert if takeover else a_rl,
        takeover=takeover,
        gate_fired=takeover,
        actor="expert" if takeover else "agent",
        fear=0.1,
        threshold=0.5,
        curiosity=0.2,
        reward=float(i),
        cost=0.25,
        violation=violation,
        terminated=terminated,
        truncated=False,
        next_obs=obs + 1,
        wall_time=0.0,
    )


def test_records_keep_takeover_flag_and_both_actions() -> None:
    buffer = ReplayBuffer(3, 2, 10)
    for i in range(6):
        buffer.add_record(record(i, takeover=i % 3 == 0))
    assert len(buffer) == 6 and buffer.takeover_count() == 2
    batch = buffer.sample_takeovers(16, np.random.default_rng(0))
    assert batch is not None and bool((batch.takeover == 1).all())
    assert np.allclose(batch.a_expert.numpy(), [-1.0, 1.0])
    assert np.allclose(batch.action.numpy(), batch.a_expert.numpy())
    assert all(np.isclose(x, 0.0) or np.isclose(x, 0.3) for x in batch.a_rl[:, 0].numpy())  # rows 0 and 3
    assert np.allclose(batch.next_obs.numpy(), batch.obs.numpy() + 1)


def test_a_coached_row_is_imitated_with_its_label_and_keeps_the_agents_executed_action() -> None:
    import dataclasses

    buffer = ReplayBuffer(3, 2, 10)
    label = np.array([0.5, -0.5], np.float32)
    buffer.add_record(record(0, takeover=False))
    # the gate judged this step dangerous (fear over τ) but nobody took over: a coached row is never "refused"
    buffer.add_record(dataclasses.replace(record(1, takeover=False), a_expert=label, coached=True, fear=0.9))
    buffer.add_record(dataclasses.replace(record(2, takeover=False), coached=True))  # no label: nothing to imitate
    assert buffer.takeover.tolist()[:3] == [False, True, False] and buffer.coached.tolist()[:3] == [False, True, False]
    assert buffer.refused_count() == 0
    batch = buffer.sample_takeovers(8, np.random.default_rng(0))
    assert batch is not None
    np.testing.assert_allclose(batch.a_expert.numpy(), np.tile(label, (8, 1)))
    np.testing.assert_allclose(batch.action.numpy(), np.tile([0.1, 0.0], (8, 1)), rtol=1e-6)  # what the agent ran


def test_no_takeovers_means_no_imitation_batch() -> None:
    buffer = ReplayBuffer(3, 2, 10)
    buffer.add_record(record(0, takeover=False))
    assert buffer.sample_takeovers(4, np.random.default_rng(0)) is None


def test_violation_is_terminal_for_learning_and_counts_as_full_cost() -> None:
    buffer = ReplayBuffer(3, 2, 10)
    buffer.add_record(record(0, takeover=False, violation=True))
    buffer.add_record(record(1, takeover=False))
    assert buffer.terminated[0] == 1.0 and buffer.terminated[1] == 0.0
    assert buffer.arrays()["cost"].tolist() == [1.0, 0.25]


def test_ring_wraps_and_keeps_the_latest() -> None:
    buffer = ReplayBuffer(3, 2, 4)
    for i in range(10):
        buffer.add_record(record(i, takeover=False, terminated=i == 9))
    assert len(buffer) == 4 and buffer.total == 10
    assert sorted(buffer.obs[:, 0].tolist()) == [6.0, 7.0, 8.0, 9.0]
    assert buffer.reward_bounds() == (6.0, 8.0)  # the terminal row's reward is not a per-step rate


def test_bad_input_is_refused_clearly() -> None:
    buffer = ReplayBuffer(3, 2, 4)
    with pytest.raises(ValueError, match="3"):
        buffer.add(np.zeros(5), np.zeros(2), 0.0, np.zeros(5), False)
    with pytest.raises(ValueError, match="empty"):
        buffer.sample(2, np.random.default_rng(0))
    with pytest.raises(ValueError, match="capacity"):
        ReplayBuffer(3, 2, 0)


def test_virtual_buffer_wraps_and_samples_states() -> None:
    virtual = VirtualBuffer(3, 2, 5)
    with pytest.raises(ValueError, match="empty"):
        virtual.sample_obs(1, np.random.default_rng(0))
    for start in (0, 4):
        obs = np.arange(start, start + 4, dtype=np.float32)[:, None].repeat(3, 1)
        virtual.add_batch(obs, np.zeros((4, 2)), obs + 1, np.zeros(4))
    assert len(virtual) == 5
    assert sorted(virtual.obs[:, 0].tolist()) == [3.0, 4.0, 5.0, 6.0, 7.0]
    assert set(virtual.sample_obs(50, np.random.default_rng(0))[:, 0].tolist()) <= {3.0, 4.0, 5.0, 6.0, 7.0}
    big = np.arange(12, dtype=np.float32)[:, None].repeat(3, 1)
    virtual.add_batch(big, np.zeros((12, 2)), big, np.zeros(12))
    assert sorted(virtual.obs[:, 0].tolist()) == [7.0, 8.0, 9.0, 10.0, 11.0]


def test_previous_deltas_follow_episodes_through_the_ring() -> None:
    buffer = ReplayBuffer(1, 1, capacity=4)
    states = [0.0, 1.0, 3.0, 6.0]  # one episode: 0 -> 1 -> 3 -> 6, then a new one from 10
    for s, s1 in itertools.pairwise(states):
        buffer.add(np.array([s]), np.zeros(1), 0.0, np.array([s1]), False)
    buffer.add(np.array([10.0]), np.zeros(1), 0.0, np.array([11.0]), False)
    buffer.add(np.array([11.0]), np.zeros(1), 0.0, np.array([13.0]), False)  # overwrites the first row
    deltas = buffer.previous_deltas()[:, 0]
    by_state = dict(zip(buffer.obs[: buffer.size, 0].tolist(), deltas.tolist(), strict=True))
    assert by_state == {1.0: 0.0, 3.0: 2.0, 10.0: 0.0, 11.0: 1.0}  # 1.0's predecessor was overwritten


def test_previous_deltas_over_a_lag_are_the_mean_change_since_k_steps_back() -> None:
    """(s_t - s_{t-k}) / k, over fewer steps where the episode began less than k steps before, zero at its start."""
    buffer = ReplayBuffer(1, 1, capacity=8)
    for s, s1 in itertools.pairwise([0.0, 1.0, 3.0, 6.0, 10.0]):
        buffer.add(np.array([s]), np.zeros(1), 0.0, np.array([s1]), False)
    buffer.add(np.array([20.0]), np.zeros(1), 0.0, np.array([22.0]), False)  # another episode
    buffer.add(np.array([22.0]), np.zeros(1), 0.0, np.array([25.0]), True)
    deltas = buffer.previous_deltas(lag=2)[:, 0]
    by_state = dict(zip(buffer.obs[: buffer.size, 0].tolist(), deltas.tolist(), strict=True))
    assert by_state == {0.0: 0.0, 1.0: 1.0, 3.0: 1.5, 6.0: 2.5, 20.0: 0.0, 22.0: 2.0}
    assert buffer.previous_deltas(lag=1)[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 0.0, 2.0]


def test_the_simulators_conflict_flag_is_kept_beside_the_violation() -> None:
    """info["conflict"] (a near miss the simulator reports) is stored per row; a step without one stores 0."""
    buffer = ReplayBuffer(3, 2, 10)
    for i in range(4):
        step = record(i, takeover=False)
        if i == 2:
            step.info["conflict"] = True
        buffer.add_record(step)
    data = buffer.arrays()
    assert data["conflict"].tolist() == [0.0, 0.0, 1.0, 0.0]
    assert data["violation"].sum() == 0 and data["cost"].tolist() == [0.25] * 4


def test_conflicts_ahead_are_marked_back_to_their_episodes_start_through_the_ring() -> None:
    """conflict_soon(k): 1 where a conflict is reported at this row or within the next k - 1 rows of the same episode;
    a conflict in the next episode marks nothing before it, and the ring's order is the episodes' own."""
    buffer = ReplayBuffer(1, 1, capacity=6)
    # episode A: 0 -> 1 -> 2 -> 3 (a conflict on its last row); episode B: 10 -> 11 -> 12 (one on its first)
    rows = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 1.0), (10.0, 1.0), (11.0, 0.0)]
    for s, conflict in rows:
        buffer.add(np.array([s]), np.zeros(1), 0.0, np.array([s + 1.0]), False, conflict=conflict)
    buffer.add(np.array([12.0]), np.zeros(1), 0.0, np.array([13.0]), False)  # overwrites the row of state 0
    by_state = dict(zip(buffer.obs[: buffer.size, 0].tolist(), buffer.conflict_soon(2).tolist(), strict=True))
    assert by_state == {1.0: 0.0, 2.0: 1.0, 3.0: 1.0, 10.0: 1.0, 11.0: 0.0, 12.0: 0.0}
    assert buffer.conflict_soon(1).tolist() == buffer.conflict[: buffer.size].tolist()
    with pytest.raises(ValueError, match="flag_soon"):
        buffer.flag_soon(np.zeros(2, bool), 3)


@pytest.mark.parametrize(
    ("takeover", "fear", "threshold", "refused"),
    [
        (True, 0.6, 0.5, True),  # the gate judged a_RL dangerous and the expert drove
        (True, 0.4, 0.5, False),  # the hold counting down: a_RL was not judged dangerous here
        (False, 0.6, 0.5, False),  # the agent drove: nothing was refused
        (True, float("nan"), 0.5, False),  # no judgement recorded
        (True, 0.6, float("inf"), False),
    ],
)
def test_a_row_is_refused_only_where_the_gate_judged_the_agents_proposal_and_the_expert_drove(
    takeover: bool, fear: float, threshold: float, refused: bool
) -> None:
    import dataclasses

    buf = ReplayBuffer(3, 2, 8)
    buf.add_record(dataclasses.replace(record(1, takeover), fear=fear, threshold=threshold))
    assert bool(buf.refused[0]) is refused
    assert buf.refused_count() == int(refused)
    sampled = buf.sample_refused(4, np.random.default_rng(0))
    assert (sampled is not None) is refused
    if sampled is not None:  # the refused row's own proposal, not the executed (expert's) action
        np.testing.assert_allclose(sampled.a_rl.numpy(), np.tile([0.1, 0.0], (4, 1)), rtol=1e-6)
        np.testing.assert_allclose(sampled.action.numpy(), np.tile([-1.0, 1.0], (4, 1)))


def test_lookback_labels_the_agents_steps_before_an_onset_with_the_experts_onset_action() -> None:
    """``learner.lookback_labels=3``: at a takeover onset the agent's last three steps of the same episode become
    imitation rows with the expert's onset action; steps further back, of another episode, or driven by the expert
    keep what they were; with 0 nothing changes."""
    import dataclasses

    from core.learners import make_learner
    from core.sage.config import for_method

    def run(lookback: int) -> ReplayBuffer:
        cfg = for_method("sac", hidden=8, batch_size=4, lookback_labels=lookback)
        learner = make_learner("sac", cfg, 3, 2, seed=0)
        steps = [record(i, takeover=i in (6, 7)) for i in range(10)]  # the agent drives t 0-5 and 8-9
        steps[6] = dataclasses.replace(steps[6], a_expert=np.array([-0.5, 0.25], np.float32))
        other = dataclasses.replace(record(5, takeover=False), episode=1)  # t 5, but of another episode
        for step in [other, *steps]:
            learner.store(step)
        return learner.buffer

    plain, looked = run(0), run(3)
    np.testing.assert_array_equal(plain.takeover[:11], [False] * 7 + [True, True, False, False])
    # rows: 0 is the other episode's, 1 + t the steps t = 0..9; the onset is t = 6 (row 7)
    np.testing.assert_array_equal(looked.takeover[:11], [False] * 4 + [True] * 5 + [False, False])
    np.testing.assert_allclose(looked.a_expert[4:7], np.tile([-0.5, 0.25], (3, 1)))
    np.testing.assert_allclose(looked.action[4:7], plain.action[4:7])  # what was executed stays
    np.testing.assert_array_equal(looked.a_expert[:4], plain.a_expert[:4])
    with pytest.raises(ValueError, match="lookback_labels"):
        for_method("sage", lookback_labels=-1)


def scanned(buffer: ReplayBuffer) -> dict[str, object]:
    """What the buffer's kept indices and bounds must equal: the scans they replace."""
    n = buffer.size
    live = buffer.terminated[:n] < 0.5
    return {
        "takeovers": np.flatnonzero(buffer.takeover[:n]).tolist(),
        "refused": np.flatnonzero(buffer.refused[:n]).tolist(),
        "magnitude": float(np.abs(buffer.reward[:n]).max()) if n else 0.0,
        "bounds": (float(buffer.reward[:n][live].min()), float(buffer.reward[:n][live].max())) if live.any() else None,
    }


def kept(buffer: ReplayBuffer) -> dict[str, object]:
    return {
        "takeovers": buffer.takeover_rows().tolist(),
        "refused": buffer.refused_rows().tolist(),
        "magnitude": buffer.reward_magnitude(),
        "bounds": buffer.reward_bounds(),
    }


@pytest.mark.parametrize("seed", range(6))
def test_kept_indices_and_reward_bounds_equal_a_scan_through_writes_labels_and_wrapping(seed: int) -> None:
    rng = np.random.default_rng(seed)
    buffer = ReplayBuffer(2, 1, int(rng.integers(3, 40)))
    for step in range(400):
        op = rng.random()
        if op < 0.75 or buffer.size == 0:
            takeover = bool(rng.random() < 0.3)
            buffer.add(
                np.zeros(2), np.zeros(1), float(rng.choice([rng.normal(), 5.0, -5.0, 0.0])), np.zeros(2),
                bool(rng.random() < 0.1), takeover=takeover, a_expert=np.ones(1) if takeover else None,
                refused=bool(rng.random() < 0.5), coached=bool(rng.random() < 0.1),
            )  # fmt: skip
        elif op < 0.85:
            buffer.label(int(rng.integers(buffer.size)), np.full(1, 0.5))
        elif op < 0.93:
            buffer.unlabel(rng.integers(buffer.size, size=int(rng.integers(1, 4))))
        else:
            row = int(rng.integers(buffer.size))
            buffer.set_rewards(row, float(rng.normal(scale=10)), terminated=bool(rng.random() < 0.2))
        # read now and then, so that kept values are carried through later writes, not recomputed each time
        if rng.random() < 0.3:
            assert kept(buffer) == scanned(buffer), step
    assert kept(buffer) == scanned(buffer)


def test_a_nan_reward_shows_in_the_bounds_as_a_scan_shows_it_until_it_is_overwritten() -> None:
    buffer = ReplayBuffer(2, 1, 3)
    for reward in (1.0, math.nan, 2.0):
        buffer.add(np.zeros(2), np.zeros(1), reward, np.zeros(2), False)
        buffer.reward_bounds()
    assert math.isnan(buffer.reward_magnitude()) and math.isnan(buffer.reward_bounds()[0])
    buffer.add(np.zeros(2), np.zeros(1), 3.0, np.zeros(2), False)  # overwrites row 0 (1.0): NaN stays
    assert math.isnan(buffer.reward_bounds()[1])
    buffer.add(np.zeros(2), np.zeros(1), 4.0, np.zeros(2), False)  # overwrites the NaN
    assert buffer.reward_bounds() == (2.0, 4.0) and buffer.reward_magnitude() == 4.0


def test_columns_the_kept_indices_depend_on_cannot_be_written_around_them() -> None:
    buffer = ReplayBuffer(2, 1, 4)
    buffer.add(np.zeros(2), np.zeros(1), 1.0, np.zeros(2), False)
    for column in (buffer.takeover, buffer.refused, buffer.reward, buffer.terminated):
        with pytest.raises(ValueError, match="read-only"):
            column[0] = 1


def test_a_shared_buffers_prior_and_own_rows_equal_a_scan_and_draw_the_same_batches() -> None:
    rng = np.random.default_rng(3)
    buffer = SharedReplayBuffer(2, 1, 25, prior_share=0.5)
    for step in range(120):
        buffer.adding_prior = bool(rng.random() < 0.4)
        buffer.add(np.full(2, step), np.zeros(1), 0.0, np.zeros(2), False)
        prior = np.flatnonzero(buffer.prior[: buffer.size])
        assert buffer.prior_count() == len(prior)
        drawn = buffer.sample(16, np.random.default_rng(step)).obs[:, 0].numpy()
        # the draw the scans gave: prior rows first, then the session's own
        own = np.flatnonzero(~buffer.prior[: buffer.size])
        draw = np.random.default_rng(step)
        if len(prior) and len(own):
            rows = np.concatenate([prior[draw.integers(0, len(prior), 8)], own[draw.integers(0, len(own), 8)]])
        else:
            rows = draw.integers(0, buffer.size, 16)
        assert drawn.tolist() == buffer.obs[rows, 0].tolist(), step


def test_discounted_sums_ahead_follow_each_episode_through_the_ring_and_stop_where_it_ends() -> None:
    buffer = ReplayBuffer(1, 1, 4)
    for step in range(6):  # one episode of six steps in a ring of four: rows hold steps 4, 5, 2, 3
        buffer.add(np.full(1, step), np.zeros(1), float(step), np.full(1, step + 1), False)
    assert buffer.discounted_ahead(buffer.reward[:4], 0.5).tolist() == [4 + 0.5 * 5, 5.0, 2 + 0.5 * 6.25, 3 + 0.5 * 6.5]
    buffer = ReplayBuffer(1, 1, 8)
    for step, (obs, terminal) in enumerate([(0, False), (1, True), (5, False), (6, False)]):
        buffer.add(np.full(1, obs), np.zeros(1), float(step + 1), np.full(1, obs + 1), terminal)
    # the first episode ends at its terminal row; the second is cut where the buffer ends
    assert buffer.discounted_ahead(buffer.reward[:4], 0.5).tolist() == [1 + 0.5 * 2, 2.0, 3 + 0.5 * 4, 4.0]
    with pytest.raises(ValueError, match="3 values for 4 stored rows"):
        buffer.discounted_ahead(np.zeros(3), 0.5)
