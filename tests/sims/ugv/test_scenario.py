"""Scenario files: the four built-ins, validation errors that name the field, mover timing, sampling."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sims
from sims.ugv.scenario import (
    BUILTIN_SCENARIOS,
    MoverPlan,
    ScenarioError,
    load_scenario,
    parse_scenario,
    sample_layout,
)
from tests.sims.ugv.conftest import room


@pytest.mark.parametrize("number", sorted(BUILTIN_SCENARIOS))
def test_builtin_scenarios_load_at_indoor_scale(number: int) -> None:
    scenario = load_scenario(number)
    layout = sample_layout(scenario, np.random.default_rng(0))
    sx, sy, _ = layout.start
    gx, gy, _ = layout.goal
    assert 5.0 <= np.hypot(gx - sx, gy - sy) <= 9.0  # the paper's travel distances
    assert (len(layout.movers) > 0) == (number >= 3)  # 1, 2 static; 3, 4 dynamic
    assert load_scenario(str(number)) == scenario


def test_any_file_runs_without_code(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    path = write_scenario(
        room(
            obstacles=[{"kind": "box", "x": 2.0, "y": [1.0, 1.2], "length": 0.5, "width": 0.5}],
            walls=[{"points": [[2.0, 3.0], [2.0, 4.0]]}],
        )
    )
    env = sims.make("ugv", scenario=str(path))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (58,)
    assert env.unwrapped.scenario.name == "test_room"


def _error(data: dict[str, Any]) -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, source="my.yaml")
    return str(info.value)


def test_missing_field_is_named() -> None:
    data = room()
    del data["start"]
    message = _error(data)
    assert "my.yaml" in message and "start: Field required" in message


def test_wrong_type_is_named() -> None:
    message = _error(room(start={"x": "left", "y": 2.0}))
    assert "start.x: expected a number or a [low, high] range, got 'left'" in message
    assert "time_limit: Input should be a valid number" in _error(room(time_limit="soon"))


def test_goal_outside_the_map_is_named() -> None:
    message = _error(room(goal={"x": [3.5, 5.0], "y": 2.0, "radius": 0.3}))
    assert "goal.x: [3.5, 5] lies outside the map bounds x in [0, 4]" in message


def test_other_problems_are_named() -> None:
    assert "start.y: range [3.0, 1.0] has low > high" in _error(room(start={"x": 1, "y": [3, 1]}))
    circle = {"kind": "circle", "x": 1, "y": 1, "radius": -1}
    assert "obstacles.0.circle.radius: Input should be greater than 0" in _error(room(obstacles=[circle]))
    assert "obstacles.0: Input tag 'triangle'" in _error(room(obstacles=[{"kind": "triangle", "x": 1, "y": 1}]))
    assert "movers.0.path: List should have at least 2 items" in _error(room(movers=[{"path": [[1, 1]], "speed": 1}]))
    assert "movers.0.speed: speed must be positive" in _error(room(movers=[{"path": [[1, 1], [2, 2]], "speed": 0}]))
    assert "movers.0.path.1.x" in _error(room(movers=[{"path": [[1, 1], [7, 1]], "speed": 0.5}]))
    assert "bounds" in _error(room(bounds=[4, 0, 0, 4]))
    assert "goal.colour: Extra inputs are not permitted" in _error(room(goal={"x": 3, "y": 2, "colour": "red"}))


def test_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="scenario file not found"):
        load_scenario(tmp_path / "nowhere.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(broken)
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n")
    with pytest.raises(ScenarioError, match="must be a mapping"):
        load_scenario(listed)
    with pytest.raises(ScenarioError, match="unknown scenario number 7"):
        load_scenario(7)
    with pytest.raises(TypeError, match="built-in scenario number or a YAML path, got True"):
        load_scenario(True)  # an int to Python, but no scenario number (nor a path)
    with pytest.raises(ScenarioError, match=r"start\.x: expected a number"):
        sims.make("ugv", scenario=str(_write(tmp_path, room(start={"x": "far", "y": 1}))))


def test_unplayable_start_is_reported(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    blocked = room(obstacles=[{"kind": "box", "x": 1.0, "y": 2.0, "length": 1.0, "width": 1.0}])
    env = sims.make("ugv", scenario=str(write_scenario(blocked)))
    with pytest.raises(ScenarioError, match="no free start pose"):
        env.reset(seed=0)


def _write(tmp_path: Path, data: dict[str, Any]) -> Path:
    import yaml

    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _plan(**kw: Any) -> MoverPlan:
    values: dict[str, Any] = {
        "kind": "box",
        "length": 0.6,
        "width": 0.4,
        "radius": 0.25,
        "path": np.array([[0.0, 0.0], [2.0, 0.0]]),
        "speed": 1.0,
        "start_time": 0.0,
        "dwell": 0.0,
        "loop": "pingpong",
    }
    values.update(kw)
    return MoverPlan(**values)


def test_mover_pingpong_with_dwell_and_delay() -> None:
    plan = _plan(start_time=1.0, dwell=0.5)
    poses = plan.poses(np.array([0.0, 1.0, 2.0, 3.0, 3.4, 3.5, 4.5, 5.5, 6.0, 7.0]))
    np.testing.assert_allclose(poses[:, 0], [0, 0, 1, 2, 2, 2, 1, 0, 0, 1], atol=1e-12)
    assert poses[2, 2] == pytest.approx(0.0) and poses[6, 2] == pytest.approx(np.pi)  # turned around
    negative = _plan(start_time=-0.5).poses(np.array([0.0]))
    assert negative[0, 0] == pytest.approx(0.5)  # already under way


def test_mover_cycle_and_once() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    poses = _plan(path=square, loop="cycle").poses(np.array([0.5, 1.5, 3.5, 4.5]))
    np.testing.assert_allclose(poses[:, :2], [[0.5, 0], [1, 0.5], [0, 0.5], [0.5, 0]], atol=1e-12)
    np.testing.assert_allclose(poses[:, 2], [0, np.pi / 2, -np.pi / 2, 0], atol=1e-12)
    once = _plan(loop="once").poses(np.array([1.0, 5.0]))
    np.testing.assert_allclose(once[:, 0], [1.0, 2.0])


def test_randomisation_is_seeded_and_within_ranges() -> None:
    scenario = load_scenario(3)
    a = sample_layout(scenario, np.random.default_rng(1))
    b = sample_layout(scenario, np.random.default_rng(1))
    c = sample_layout(scenario, np.random.default_rng(2))
    assert a.start == b.start and a.goal == b.goal and a.movers[0].start_time == b.movers[0].start_time
    assert a.start != c.start
    for layout in (a, c):
        assert 0.8 <= layout.start[0] <= 1.2 and 2.75 <= layout.start[1] <= 3.25
        assert 0.45 <= layout.movers[0].speed <= 0.55 and -0.5 <= layout.movers[0].start_time <= 1.5
        assert 4.1 <= layout.movers[0].path[0, 0] <= 4.5  # shifted by [-0.2, 0.2]


def test_ranged_waypoints_are_drawn_per_reset_within_their_ranges() -> None:
    walker = {"path": [[[0.5, 1.5], 1.0], [3.0, [2.5, 3.5]]], "speed": 0.5, "shift": {"x": [0, 0.2]}}
    scenario = parse_scenario(room(movers=[walker]))
    paths = [sample_layout(scenario, np.random.default_rng(seed)).movers[0].path for seed in range(20)]
    starts, ends = np.array([p[0] for p in paths]), np.array([p[1] for p in paths])
    assert (starts[:, 0] >= 0.5).all() and (starts[:, 0] <= 1.7).all() and np.ptp(starts[:, 0]) > 0.5
    assert (ends[:, 1] >= 2.5).all() and (ends[:, 1] <= 3.5).all() and np.ptp(ends[:, 1]) > 0.5
    np.testing.assert_array_equal(starts[:, 1], 1.0)  # a fixed coordinate stays put
    again = sample_layout(scenario, np.random.default_rng(3)).movers[0].path
    np.testing.assert_array_equal(again, paths[3])  # seeded


def test_ranged_waypoints_are_validated_over_their_whole_range() -> None:
    outside = {"path": [[1, 1], [[2.0, 4.5], 1]], "speed": 0.5}
    assert "movers.0.path.1.x: [2, 4.5] lies outside the map bounds x in [0, 4]" in _error(room(movers=[outside]))
    assert "movers.0: path has zero length" in _error(room(movers=[{"path": [[1, 1], [1, 1]], "speed": 1}]))
    # ranged points that could coincide are allowed, and a draw that makes them coincide still moves
    overlapping = parse_scenario(room(movers=[{"path": [[[1, 2], 1], [[1, 2], 1]], "speed": 1}]))
    layout = sample_layout(overlapping, np.random.default_rng(0))
    assert np.isfinite(layout.movers[0].poses(np.linspace(0, 5, 11))).all()


def test_the_traffic_training_field_draws_movers_that_cross_the_field() -> None:
    scenario = load_scenario(Path(sims.__file__).parent / "ugv" / "scenarios" / "traffic.yaml")
    headings = []
    for seed in range(10):
        layout = sample_layout(scenario, np.random.default_rng(seed))
        assert len(layout.movers) == 3
        first = layout.movers[0].path
        headings.append(np.arctan2(*(first[1] - first[0])[::-1]))
    assert np.ptp(headings) > 0.3  # the crossing vehicle's slant differs from reset to reset
