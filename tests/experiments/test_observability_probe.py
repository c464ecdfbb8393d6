"""The observability probe's students see what they are said to see, and its rows count every episode."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from experiments.observability_probe import RANGES, ProbeConfig, features, report, run


def test_the_velocity_cue_is_the_change_of_the_ranges_and_zero_at_an_episodes_start() -> None:
    obs = np.linspace(0.0, 1.0, 58, dtype=np.float32)
    previous = obs - 0.01
    assert features(obs, previous, cue=False).shape == (58,)
    cued = features(obs, previous, cue=True)
    np.testing.assert_allclose(cued[58:], np.full(RANGES, 0.01), atol=1e-6)
    np.testing.assert_array_equal(features(obs, None, cue=True)[58:], np.zeros(RANGES))


def test_a_tiny_probe_counts_every_alone_episode_and_aggregates_its_labels() -> None:
    cfg = ProbeConfig(expert_episodes=1, iterations=1, episodes_per_iteration=1, eval_episodes=2, updates=5)
    rows = run(cfg, cue=True)
    assert [r["iteration"] for r in rows] == [0, 1]
    assert all(r["success"] + r["collision"] + r["timeout"] == 2 for r in rows)
    assert rows[1]["samples"] > rows[0]["samples"] > 0  # the student's own states were labelled and added
    text = report(cfg, {"scan+change, seed 0": rows}, 1.0, "abc1234")
    assert text.count("| scan+change, seed 0 |") == 2


def test_students_learn_on_one_family_are_judged_on_another_and_may_be_wider(monkeypatch) -> None:
    import experiments.observability_probe as probe

    made: list[str] = []
    real = probe.descriptor

    class Spy:
        def __init__(self, name: str) -> None:
            self.inner = real(name)

        def make(self, scenario: str) -> Any:
            made.append(scenario)
            return self.inner.make(scenario)

    monkeypatch.setattr(probe, "descriptor", Spy)
    cfg = ProbeConfig(
        scenario="ugv-fields:train", eval_scenario="ugv-fields:test:2+", hidden=(16, 16, 16),
        expert_episodes=1, iterations=1, episodes_per_iteration=1, eval_episodes=1, updates=2, max_steps=30,
    )  # fmt: skip
    rows = run(cfg, cue=False)
    assert all(r["success"] + r["collision"] + r["timeout"] == 1 for r in rows)
    # the expert's and the student's labelled drives on the training family; every alone drive on the test family
    assert made == ["ugv-fields:train", "ugv-fields:test:2+", "ugv-fields:train", "ugv-fields:test:2+"]
    text = report(cfg, {"scan, seed 0": rows}, 1.0, "abc1234")
    assert "judged on ugv-fields:test:2+" in text and "16 x 16 x 16" in text


def test_a_tracked_student_sees_the_nearest_movers_in_the_robots_frame() -> None:
    from experiments.observability_probe import TRACKED, mover_tracks
    from sims import descriptor

    env = descriptor("ugv").make("3")
    try:
        env.reset(seed=0)
        sim: Any = env.unwrapped
        for _ in range(20):  # the crossing mover sets off after a few steps
            env.step(np.zeros(2, np.float32))
        tracks = mover_tracks(sim)
        present = int(tracks[0::5].sum())
        assert tracks.shape == (TRACKED * 5,) and present == min(len(sim.layout.movers), TRACKED) > 0
        world, (x, y, _) = sim.world, sim._pose
        nearest = min(np.hypot(*(world.mover_poses[i, world.k, 0:2] - (x, y))) for i in range(len(sim.layout.movers)))
        assert 10 * np.hypot(tracks[1], tracks[2]) == pytest.approx(nearest, rel=1e-5)  # the first slot is the nearest
        assert np.abs(tracks[3:5]).sum() > 0  # the crossing mover moves
    finally:
        env.close()
    rows = run(ProbeConfig(expert_episodes=1, iterations=0, eval_episodes=1, updates=2, max_steps=20), False, True)
    assert rows[0]["success"] + rows[0]["collision"] + rows[0]["timeout"] == 1


def test_a_planner_can_be_the_teacher_and_its_actions_are_the_labels() -> None:
    cfg = ProbeConfig(teacher="teb", expert_episodes=1, iterations=0, eval_episodes=1, updates=2, max_steps=15)
    rows = run(cfg, cue=False)
    assert rows[0]["samples"] == 15 and rows[0]["success"] + rows[0]["collision"] + rows[0]["timeout"] == 1
    assert "Teacher: teb." in report(cfg, {"scan, seed 0": rows}, 1.0, "abc1234")
