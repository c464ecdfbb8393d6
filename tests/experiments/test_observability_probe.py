"""The observability probe's students see what they are said to see, and its rows count every episode."""

from __future__ import annotations

import numpy as np

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
