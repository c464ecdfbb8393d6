"""pedestrian-shift: the crossing with ranges inside (train) and outside (test) the training ones."""

from __future__ import annotations

import pytest

import sims
from core.descriptor import ScenarioNameError
from sims.pedestrian.config import PedestrianConfig
from sims.pedestrian.families import SPLITS


def _disjoint(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[1] < b[0] or b[1] < a[0]


def test_the_test_ranges_do_not_overlap_the_training_ones() -> None:
    trained, test = PedestrianConfig(), SPLITS["test"]
    assert test["truck_length"] > trained.truck_length and test["truck_width"] > trained.truck_width
    for name in ("pedestrian_speed", "pedestrian_ahead", "trigger_distance"):
        assert _disjoint(test[name], getattr(trained, name)), name


def test_names_resolve_through_the_descriptor() -> None:
    descriptor = sims.descriptor("pedestrian")
    assert descriptor.scenario_kwargs("Pedestrian-Shift:Test")["truck_length"] == SPLITS["test"]["truck_length"]
    assert descriptor.scenario_kwargs("pedestrian-shift:train")["pedestrian_probability"] == 1.0
    for bad in ("pedestrian-shift:val", "pedestrian-shift", "nope"):
        with pytest.raises(ScenarioNameError, match="pedestrian-shift:train or pedestrian-shift:test"):
            descriptor.scenario_kwargs(bad)


@pytest.mark.parametrize("split", ["train", "test"])
def test_the_scripted_expert_alone_avoids_the_pedestrian_on_both_splits(split: str) -> None:
    env = sims.descriptor("pedestrian").make(f"pedestrian-shift:{split}")
    unwrapped = env.unwrapped
    try:
        for seed in range(3_000_000, 3_000_010):
            env.reset(seed=seed)
            assert unwrapped.pedestrian is not None
            done = False
            while not done:
                _, _, terminated, truncated, info = env.step(unwrapped.expert_action())
                done = terminated or truncated
            assert not info["violation"], f"seed {seed}"
    finally:
        env.close()
