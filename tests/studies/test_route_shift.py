"""The route-shift hook: the schedule applied episode by episode, the expert handed over at the switch."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from studies.route_shift import RouteShift, phase_rows
from studies.training import prepare_training


class FakeRunner:
    """Records the reset options of each next episode, as core.loop.Runner would pass them to the env."""

    def __init__(self, expert: object | None) -> None:
        self.calls: list[tuple[Any, Any]] = []
        self.expert = expert

    def set_next_reset_options(self, options: dict[str, Any]) -> None:
        self.calls.append((options["route"], options["special_vehicles"]))

    def set_expert(self, expert: object | None) -> None:
        self.expert = expert


def test_each_episode_gets_its_phase_and_the_c2_expert_takes_over_at_the_switch() -> None:
    c1_expert, c2_expert = object(), object()
    shift = RouteShift(3, 2, expert_c2=c2_expert)
    runner = FakeRunner(c1_expert)
    experts = []
    for episode in range(shift.episodes):
        shift(episode, runner)  # type: ignore[arg-type]
        experts.append(runner.expert)
    assert runner.calls == [(1, False)] * 3 + [(2, True)] * 2
    assert experts == [c1_expert] * 3 + [c2_expert] * 2
    assert [a["phase"] for a in shift.applied] == ["C1", "C1", "C1", "C2", "C2"]
    with pytest.raises(ValueError, match="past the route-shift schedule"):
        shift(5, runner)  # type: ignore[arg-type]


def test_a_method_without_takeovers_keeps_no_expert() -> None:
    shift = RouteShift(1, 1, expert_c2=object())
    runner = FakeRunner(None)
    shift(0, runner)  # type: ignore[arg-type]
    shift(1, runner)  # type: ignore[arg-type]
    assert runner.expert is None


def test_prepare_training_checks_the_protocol_options() -> None:
    setup = prepare_training("sumo", protocol="route-shift", c1=4, c2=2, method="fni-rl")
    assert setup.episodes == 6 and setup.scenarios == ["c1"] and setup.name == "route_shift"
    assert setup.study == {
        "protocol": "route-shift",
        "c1": 4,
        "c2": 2,
        "switch_episode": 4,
        "method": "fni-rl",
        "expert_c1": "sumo",
        "expert_c2": "sumo",
    }
    for kwargs, message in [
        ({"sim": "highway", "protocol": "route-shift"}, "SUMO study"),
        ({"sim": "sumo", "protocol": "route-shift", "episodes": 10, "c1": 2, "c2": 2}, "drop --episodes"),
        ({"sim": "sumo", "protocol": "route-shift", "scenario": "c2"}, "drop --scenario"),
        ({"sim": "sumo", "c1": 3}, "belong to --protocol route-shift"),
        ({"sim": "sumo", "adversarial_ratio": 0.5}, "--sim highway"),
        ({"sim": "sumo", "protocol": "curriculum"}, "unknown protocol"),
    ]:
        with pytest.raises(ValueError, match=message):
            prepare_training(**kwargs)


def test_phase_rows_take_the_end_of_c1_and_both_ends_of_c2() -> None:
    from studies.route_shift import StudyRun

    rows = [{"episode": i} for i in range(9)]
    run = StudyRun(Path("r"), "X", "sac", rows, 6)
    parts = phase_rows(run)
    assert {k: [r["episode"] for r in v] for k, v in parts.items()} == {
        "X: C1 last 2": [4, 5],
        "X: C2 first 1": [6],
        "X: C2 last 1": [8],
    }
