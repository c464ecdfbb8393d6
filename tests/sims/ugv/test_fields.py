"""ugv-fields: the procedural family's split, determinism, expert filter and names."""

from __future__ import annotations

import numpy as np
import pytest

import sims
from core.descriptor import ScenarioNameError
from sims.ugv import fields
from sims.ugv.env import UGVEnv
from sims.ugv.fields import (
    SPLIT_SIZE,
    FieldSelection,
    candidate_field,
    expert_solves,
    field,
    field_draw,
    field_seed,
    parse_field_name,
)
from sims.ugv.scenario import parse_scenario
from studies.envs import env_factory


def test_a_field_is_the_same_given_split_and_index() -> None:
    first = field("test", 2).model_dump()
    field_draw.cache_clear()
    assert field("test", 2).model_dump() == first
    assert field("test", 3).model_dump() != first


def test_train_and_test_draw_from_disjoint_seed_ranges() -> None:
    train = {field_seed("train", i) for i in (0, 1, SPLIT_SIZE - 1)}
    test = {field_seed("test", i) for i in (0, 1, SPLIT_SIZE - 1)}
    assert max(train) < min(test)
    assert field("train", 2).model_dump(exclude={"name"}) != field("test", 2).model_dump(exclude={"name"})
    with pytest.raises(ValueError, match="outside"):
        field_seed("train", SPLIT_SIZE)


def test_every_field_of_a_small_sample_is_solved_by_the_expert_alone() -> None:
    for split in ("train", "test"):
        for index in range(3):
            assert expert_solves(field(split, index))


def test_a_candidate_the_expert_fails_is_redrawn(monkeypatch: pytest.MonkeyPatch) -> None:
    verdicts = iter([False, False, True])
    monkeypatch.setattr(fields, "expert_solves", lambda scenario: next(verdicts))
    field_draw.cache_clear()
    try:
        draw = field_draw("train", 7)
        assert draw.candidate == 2
        rng = np.random.default_rng([fields.FAMILY_SALT, draw.seed, 2])
        data, _ = candidate_field(rng, "ugv-fields:train:7")
        assert draw.scenario.model_dump() == parse_scenario(data).model_dump()
    finally:
        field_draw.cache_clear()


def test_candidates_hold_zero_to_three_movers_and_validate() -> None:
    counts = set()
    for j in range(30):
        data, behaviours = candidate_field(np.random.default_rng([1, j]), "x")
        counts.add(len(data["movers"]))
        assert len(behaviours) == len(data["movers"]) <= 3
        assert set(behaviours) <= set(fields.BEHAVIOURS)
    assert counts == {0, 1, 2, 3}


def test_names_resolve_where_the_cli_resolves_scenario_names() -> None:
    descriptor = sims.descriptor("ugv")
    assert descriptor.scenario_kwargs("ugv-fields:test") == {"scenario": FieldSelection("test")}
    assert descriptor.scenario_kwargs(" UGV-Fields:Train:5 ") == {"scenario": FieldSelection("train", 5)}
    assert FieldSelection("train", 5).name == "ugv-fields:train:5"
    assert descriptor.scenario_kwargs("ugv-fields:test:2+") == {"scenario": FieldSelection("test", min_movers=2)}
    assert FieldSelection("test", min_movers=2).name == "ugv-fields:test:2+"
    for bad in ("ugv-fields:valid", "ugv-fields:test:-1", "ugv-fields:test:x", "ugv-fields", "ugv-fields:test:4+"):
        with pytest.raises(ScenarioNameError, match="ugv-fields:train, ugv-fields:test"):
            descriptor.scenario_kwargs(bad)
    assert parse_field_name("sims/ugv/scenarios/traffic.yaml") is None


def test_a_split_plays_the_field_its_episode_seed_draws() -> None:
    env = env_factory("ugv")("ugv-fields:test")
    try:
        names = []
        for seed in (11, 12, 11):
            env.reset(seed=seed)
            names.append(env.unwrapped.layout.name)
        assert names[0] == names[2] != names[1]
        assert all(name.startswith("ugv-fields:test:") for name in names)
    finally:
        env.close()
    crowded = UGVEnv(FieldSelection("test", min_movers=2))
    for seed in (11, 12):
        crowded.reset(seed=seed)
        assert len(crowded.layout.movers) >= 2
    one = UGVEnv(parse_field_name("ugv-fields:test:4"))
    for seed in (1, 2):
        one.reset(seed=seed)
        assert one.layout.name == "ugv-fields:test:4"
        assert one.field_index == 4
