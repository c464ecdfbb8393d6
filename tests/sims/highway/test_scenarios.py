"""The scenario pool: a fixed 400/100 split, and a scenario is the same every time it is loaded by its id."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sims
from sims.highway import scenarios
from sims.highway.scenarios import N_SCENARIOS, load_log, record_log, scenario_ids, scenario_spec

QUICK_ID = 149
"""A test-split scenario with light traffic (11 vehicles): cheap to record again."""


def test_split_is_fixed_disjoint_and_covers_the_pool() -> None:
    train, test = scenario_ids("train"), scenario_ids("test")
    assert len(train) == 400 and len(test) == 100
    assert not set(train) & set(test)
    assert sorted(train + test) == list(range(N_SCENARIOS))
    assert scenario_ids("test") == test  # a second call gives the same split
    with pytest.raises(ValueError, match="unknown split"):
        scenario_ids("validation")  # type: ignore[arg-type]


def test_specs_are_a_function_of_the_id_and_vary_across_the_pool() -> None:
    assert scenario_spec(7) == scenario_spec(7)
    specs = [scenario_spec(i) for i in range(60)]
    assert len({s.seed for s in specs}) == 60
    assert {s.layout.kind for s in specs} == {"highway", "merge"}
    assert {s.layout.lanes for s in specs} >= {2, 3, 4}
    spacings = [s.spacing for s in specs]
    assert max(spacings) - min(spacings) > 20  # densities differ
    assert any(s.behaviour_mix[1] > 0.25 for s in specs) and any(s.behaviour_mix[2] > 0.25 for s in specs)
    with pytest.raises(ValueError, match="outside the pool"):
        scenario_spec(N_SCENARIOS)


def test_recording_twice_gives_identical_logs_and_the_cached_log_is_the_recorded_one() -> None:
    spec = scenario_spec(QUICK_ID)
    first, second = record_log(spec), record_log(spec)
    cached = load_log(QUICK_ID)
    for name, array in first.arrays().items():
        assert np.array_equal(array, second.arrays()[name]), name
        assert np.array_equal(array, cached.arrays()[name]), name
    assert first.route_length == cached.route_length and first.time_limit == cached.time_limit
    assert first.vehicles >= 5 and first.frames * first.dt >= first.time_limit


def test_cache_roundtrip_and_a_damaged_file_is_recorded_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log = load_log(QUICK_ID)
    monkeypatch.setenv("SAGE_HIGHWAY_CACHE", str(tmp_path))
    scenarios.clear_memory_cache()
    try:
        scenarios._save(log, scenarios.cache_dir() / f"scenario_{QUICK_ID:04d}.npz")
        loaded = load_log(QUICK_ID)
        assert loaded is not log and np.array_equal(loaded.y, log.y) and loaded.spec == log.spec
        files = list(tmp_path.rglob("*.npz"))
        assert [f.name for f in files] == [f"scenario_{QUICK_ID:04d}.npz"]
        files[0].write_bytes(b"not an npz file")
        scenarios.clear_memory_cache()
        again = load_log(QUICK_ID)
        assert np.array_equal(again.x, log.x) and np.array_equal(again.ego_ref, log.ego_ref)
        assert files[0].stat().st_size > 1000  # rewritten
        assert scenarios.warm_cache([QUICK_ID]) == 0  # nothing left to record
    finally:
        scenarios.clear_memory_cache()


def test_an_episode_of_a_scenario_is_the_same_every_time_it_is_loaded() -> None:
    def run() -> tuple[np.ndarray, np.ndarray]:
        env = sims.make("highway", scenario_id=QUICK_ID)
        obs, _ = env.reset(seed=0)
        trace = [obs]
        xs = []
        for k in range(40):
            obs, *_ = env.step(np.array([0.05 * np.sin(k / 5), 0.2], np.float32))
            trace.append(obs)
            xs.append(env.unwrapped.world.traffic.x.copy())
        return np.array(trace), np.array(xs)

    first, second = run(), run()
    assert np.array_equal(first[0], second[0]) and np.array_equal(first[1], second[1])


def test_reset_without_an_id_samples_the_split_deterministically() -> None:
    env = sims.make("highway", split="test")
    picked = []
    for seed in (0, 1, 2, 0):
        _, info = env.reset(seed=seed)
        picked.append(info["scenario_id"])
    assert picked[0] == picked[3]
    assert len(set(picked)) > 1
    assert set(picked) <= set(scenario_ids("test"))
    _, info = env.reset(seed=5, options={"scenario_id": QUICK_ID})
    assert info["scenario_id"] == QUICK_ID
    with pytest.raises(ValueError, match="outside the pool"):
        env.reset(options={"scenario_id": 10_000})
