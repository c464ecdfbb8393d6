"""highway-shift: a seeded train/test split of traffic specs, the test split outside the pool's ranges."""

from __future__ import annotations

import pytest

import sims
from core.descriptor import ScenarioNameError
from sims.highway.families import (
    RANGES,
    SPLIT_SIZE,
    SpecSelection,
    candidate_spec,
    expert_drives,
    family_spec,
    parse_family_name,
    spec_seed,
)


def test_a_spec_is_the_same_given_split_and_index_and_splits_use_disjoint_seeds() -> None:
    first = family_spec("test", 4)
    family_spec.cache_clear()
    assert family_spec("test", 4) == first != family_spec("test", 5)
    assert expert_drives(first)
    assert spec_seed("train", SPLIT_SIZE - 1) < spec_seed("test", 0)
    ids = {candidate_spec(split, spec_seed(split, i), 0).scenario_id for split in ("train", "test") for i in range(20)}
    assert len(ids) == 40 and min(ids) >= 500  # never a pool id


def test_the_test_split_lies_outside_the_training_ranges() -> None:
    train, test = RANGES["train"], RANGES["test"]
    assert test.speed_limit[0] > train.speed_limit[1] and test.spacing[1] < train.spacing[0]
    assert test.aggressive[0] > train.aggressive[1]
    for i in range(20):
        spec = candidate_spec("test", spec_seed("test", i), i % 3)
        assert spec.layout.speed_limit > train.speed_limit[1] and spec.spacing < train.spacing[0]
        assert spec.behaviour_mix[1] > train.aggressive[1] and sum(spec.behaviour_mix) == pytest.approx(1.0)
        inside = candidate_spec("train", spec_seed("train", i), i % 3)
        assert train.spacing[0] <= inside.spacing <= train.spacing[1]


def test_names_resolve_through_the_descriptor() -> None:
    descriptor = sims.descriptor("highway")
    assert descriptor.scenario_kwargs("highway-shift:train") == {
        "spec_source": SpecSelection("train"),
        "mode": "normal",
    }
    test = descriptor.scenario_kwargs("Highway-Shift:Test:3")
    assert test == {"spec_source": SpecSelection("test", 3), "mode": "normal"}
    assert parse_family_name("17") is None
    for bad in ("highway-shift:val", "highway-shift:test:x", "highway-shift"):
        with pytest.raises(ScenarioNameError, match="highway-shift:train"):
            descriptor.scenario_kwargs(bad)


def test_an_env_plays_the_spec_its_episode_seed_draws() -> None:
    env = sims.descriptor("highway").make("highway-shift:test")
    try:
        env.reset(seed=1)
        first = env.unwrapped.log.spec
        assert first == family_spec("test", env.unwrapped.source_index)
        env.reset(seed=1)
        assert env.unwrapped.log.spec == first
    finally:
        env.close()
