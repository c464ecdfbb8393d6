"""The route-shift study's schedule and curves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studies.route_shift_schedule import rolling_rates, route_shift_phases, route_shift_schedule


def test_schedule_is_c1_on_route_1_then_c2_on_route_2_with_special_vehicles() -> None:
    schedule = route_shift_schedule(3, 2)
    assert [(e.episode, e.phase, e.route, e.special_vehicles) for e in schedule] == [
        (0, "C1", 1, False),
        (1, "C1", 1, False),
        (2, "C1", 1, False),
        (3, "C2", 2, True),
        (4, "C2", 2, True),
    ]
    phases = route_shift_phases(1000, 500)
    assert len(phases) == 1500
    assert phases[999] == {"route": 1, "special_vehicles": False}
    assert phases[1000] == {"route": 2, "special_vehicles": True}
    with pytest.raises(ValueError):
        route_shift_schedule(-1, 2)


def test_rolling_rates_average_the_trailing_window_and_skip_missing_episodes() -> None:
    rows = [{"success": 1.0}, {"success": 0.0}, {}, {"success": 1.0}, {"success": 1.0}]
    rates = rolling_rates(rows, keys=("success",), window=2)["success"]
    # windows: [1] [1,0] [0,-] [-,1] [1,1]
    np.testing.assert_allclose(rates, [1.0, 0.5, 0.0, 1.0, 1.0])
    assert math.isnan(rolling_rates([{}], keys=("collision",), window=3)["collision"][0])
