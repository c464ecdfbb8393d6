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


def _write_run(folder: Path, c1: int, c2_takeovers: list[int], takeover: bool = True) -> Path:
    """A route-shift run folder as `sage train --protocol route-shift` writes it: one demonstration, ``c1`` route-1
    episodes, then one C2 episode of 100 steps per entry of ``c2_takeovers`` (its expert-driven steps); a C2
    episode collides when fewer than half of its steps were taken over."""
    import json

    rows = [{"episode": 0, "steps": 50, "takeovers": 50, "collision": 0.0, "route": 1, "phase": "demo"}]
    rows += [{"episode": 1 + i, "steps": 100, "takeovers": 0, "collision": 1.0, "route": 1} for i in range(c1)]
    rows += [
        {"episode": 1 + c1 + i, "steps": 100, "takeovers": t, "collision": float(t < 50), "route": 2}
        for i, t in enumerate(c2_takeovers)
    ]
    folder.mkdir(parents=True)
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    # a switch by steps: study.json names no switch episode, the first route-2 episode is it
    (folder / "study.json").write_text(
        json.dumps({"protocol": "route-shift", "method": "sage", "switch_episode": None})
    )
    (folder / "config.json").write_text(json.dumps({"agent": {"method": "sage", "takeover": takeover}}))
    return folder


def test_a_falling_c2_takeover_gives_a_negative_change_and_rising_collisions_a_positive_one(tmp_path: Path) -> None:
    from studies.route_shift import read_run, shift_metrics

    # C2: six episodes, the expert driving 90, 80, 60, 40, 20, 10 of each episode's 100 steps
    run = read_run(_write_run(tmp_path / "sage-s0", c1=3, c2_takeovers=[90, 80, 60, 40, 20, 10]))
    metrics = shift_metrics(run)
    assert metrics["c2_takeover_early"] == pytest.approx(0.85) and metrics["c2_takeover_late"] == pytest.approx(0.15)
    assert metrics["c2_takeover_change"] == pytest.approx(-0.7)
    assert metrics["c2_takeover_rate"] == pytest.approx(0.5)
    # the first third never collides (taken over most of the way), the last third always does
    assert (metrics["c2_early_collision"], metrics["c2_late_collision"], metrics["c2_collision_change"]) == (0, 1, 1)
    assert metrics["c1_late_collision"] == 1.0  # the demonstration is not a C1 episode


def test_no_c2_episodes_or_no_takeovers_give_not_applicable_not_an_error(tmp_path: Path) -> None:
    import math

    from studies.route_shift import read_run, shift_metrics

    no_c2 = shift_metrics(read_run(_write_run(tmp_path / "a", c1=4, c2_takeovers=[])))
    assert all(math.isnan(no_c2[k]) for k in ("c2_takeover_early", "c2_takeover_change", "c2_collision_change"))
    assert math.isnan(no_c2["c2_early_collision"]) and no_c2["c1_late_collision"] == 1.0
    ungated = shift_metrics(read_run(_write_run(tmp_path / "b", c1=2, c2_takeovers=[0, 0, 0], takeover=False)))
    assert math.isnan(ungated["c2_takeover_early"]) and math.isnan(ungated["c2_takeover_change"])
    assert ungated["c2_takeover_rate"] == 0.0 and ungated["c2_collision_change"] == 0.0
