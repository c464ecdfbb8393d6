"""sumo-shift: an unseen route with unseen special vehicles (test) against phase C2 (train)."""

from __future__ import annotations

import pytest

import sims
from core.descriptor import ScenarioNameError
from sims.sumo.config import SumoConfig


def test_names_resolve_through_the_descriptor() -> None:
    descriptor = sims.descriptor("sumo")
    assert descriptor.scenario_kwargs("Sumo-Shift:Test") == {"route": 3, "special_vehicles": True}
    assert descriptor.scenario_kwargs("sumo-shift:train") == descriptor.scenario_kwargs("c2")
    for bad in ("sumo-shift:val", "sumo-shift", "nope"):
        with pytest.raises(ScenarioNameError, match="sumo-shift:train or sumo-shift:test"):
            descriptor.scenario_kwargs(bad)


def test_the_test_split_loads_its_own_route_and_special_vehicles() -> None:
    test, c2 = SumoConfig(route=3, special_vehicles=True), SumoConfig(route=2, special_vehicles=True)
    assert [p.name for p in test.route_paths()] == ["common.rou.xml", "route3.rou.xml", "special3.rou.xml"]
    assert [p.name for p in c2.route_paths()][-1] == "special.rou.xml"
    assert all(p.is_file() for p in test.route_paths())


def test_the_scripted_expert_drives_the_unseen_route_to_the_exit() -> None:
    pytest.importorskip("libsumo")
    env = sims.descriptor("sumo").make("sumo-shift:test")
    unwrapped = env.unwrapped
    try:
        env.reset(seed=3_000_000)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(unwrapped.expert_action())
            done = terminated or truncated
        metrics = unwrapped.metrics()
        assert metrics["success"] == 1.0 and metrics["collision"] == 0.0
    finally:
        env.close()
