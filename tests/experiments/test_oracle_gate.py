"""The privileged-gate bench's scenario choice (the rows themselves are a long experiment, not a unit test)."""

from __future__ import annotations

import pytest

from experiments.calibration import table_scenarios
from experiments.oracle_gate import chosen_scenarios, danger_rule, slug


def test_scenarios_default_to_the_gate_table() -> None:
    assert chosen_scenarios("ugv", None) == table_scenarios("ugv")


def test_scenarios_named_split_comma_lists_and_keep_order() -> None:
    assert chosen_scenarios("ugv", ["ugv-fields:test:2+, 3", "ugv-fields:test"]) == [
        "ugv-fields:test:2+",
        "3",
        "ugv-fields:test",
    ]


def test_an_unknown_scenario_stops_before_any_episode() -> None:
    with pytest.raises(SystemExit, match="'nowhere'"):
        chosen_scenarios("highway", ["highway-shift:test", "nowhere"])


def test_slug_names_a_folder() -> None:
    assert slug("ugv-fields:test:2+") == "ugv-fields-test-2plus"
    assert slug("highway-shift:test") == "highway-shift-test"


def test_danger_rule_fires_on_either_part() -> None:
    rule = danger_rule(2.0, 0.12)
    assert rule({"ttc": 1.5, "nearest_gap": 1.0})
    assert rule({"ttc": 9.0, "nearest_gap": 0.05})
    assert not rule({"ttc": 9.0, "nearest_gap": 1.0})
    assert not danger_rule(None, 0.12)({"ttc": 0.1, "nearest_gap": 1.0})
