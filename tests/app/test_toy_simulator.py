"""Adding a simulator is one descriptor: a toy simulator registered at run time is listed and served live."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

import sims
from app.server import ServerSettings
from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor
from tests.app.conftest import start_server, stop_server
from tests.app.test_server import until, ws

TOY = SimDescriptor(
    name="toyrobot",
    title="toy robot (a test's simulator)",
    env_id="sage-test/ToyRobot-v0",
    entry_point="tests.app.fakesim:ToyRobotEnv",
    dt=0.1,
    scenarios=(ScenarioSpec("one", "one obstacle", {"scenario": 1}), ScenarioSpec("two", "two", {"scenario": 2})),
    default_scenario="one",
    input_mapping=InputMapping(throttle_index=0, steer_index=1),
    metric_columns=("success", "collision"),
    safe_action=(0.0, 0.0),
)


@pytest.fixture
def toy_registered() -> Iterator[None]:
    sims.register(TOY)
    try:
        yield
    finally:
        sims.unregister(TOY.name)


def test_a_toy_simulator_is_served_live_through_its_descriptor_alone(toy_registered: None, tmp_path: Path) -> None:
    # nothing toy-specific is passed: the server's own env factory, catalogue and policy loader are used
    settings = ServerSettings(sim="toyrobot", policy="scripted", sessions=tmp_path / "sessions", port=0, finetune=False)
    live, thread = start_server(settings)
    try:
        state = live.state()
        assert state["config"]["sim"] == "toyrobot" and state["config"]["scenario"] == "one"
        catalogue = live.dash.catalogue()
        assert [s["id"] for s in catalogue["toyrobot"]["scenarios"]] == ["one", "two"]
        with ws(live) as conn:
            welcome = until(conn, lambda m: m["type"] == "welcome")
            assert "toyrobot" in welcome["options"]["sims"] or "toyrobot" in str(welcome["options"])
            steps = [until(conn, lambda m: m["type"] == "step") for _ in range(5)]
        assert [s["t"] for s in steps] == sorted(s["t"] for s in steps)
        assert live.dash.live.world.dt == 0.1  # the clock reads the descriptor's control period
    finally:
        stop_server(live, thread)
