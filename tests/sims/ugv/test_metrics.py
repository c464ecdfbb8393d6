"""Metric functions on trajectories with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sims.ugv.metrics import (
    METRIC_COLUMNS,
    average_speed,
    curvature_profile,
    episode_metrics,
    mean_lateral_acceleration,
    mean_path_curvature,
    travel_distance,
)

DT = 0.1


def circle(radius: float, speed: float, seconds: float, centre: tuple[float, float] = (1.0, -2.0)) -> np.ndarray:
    t = np.arange(0.0, seconds + 1e-9, DT)
    angle = speed / radius * t
    return np.column_stack([centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle)])


@pytest.mark.parametrize(("radius", "speed"), [(0.5, 0.3), (2.0, 0.6), (10.0, 0.45)])
def test_circle_has_curvature_one_over_r_and_lateral_acc_v2_over_r(radius: float, speed: float) -> None:
    xy = circle(radius, speed, seconds=8.0)
    assert mean_path_curvature(xy, DT) == pytest.approx(1.0 / radius, rel=1e-9)
    assert mean_lateral_acceleration(xy, DT) == pytest.approx(speed**2 / radius, rel=1e-9)
    kappa, v = curvature_profile(xy, DT)
    np.testing.assert_allclose(kappa, 1.0 / radius, rtol=1e-9)
    np.testing.assert_allclose(v, speed, rtol=1e-9)
    # travel distance is the chord polyline: slightly under the arc length
    assert travel_distance(xy) == pytest.approx(speed * 8.0, rel=1e-3)
    assert travel_distance(xy) < speed * 8.0


def test_straight_line_has_zero_curvature_and_lateral_acc() -> None:
    t = np.arange(0, 5.0 + 1e-9, DT)
    xy = np.column_stack([2.0 + 0.4 * t * math.cos(0.3), -1.0 + 0.4 * t * math.sin(0.3)])
    assert mean_path_curvature(xy, DT) == pytest.approx(0.0, abs=1e-9)
    assert mean_lateral_acceleration(xy, DT) == pytest.approx(0.0, abs=1e-9)
    assert travel_distance(xy) == pytest.approx(2.0)
    assert average_speed(xy, DT) == pytest.approx(0.4)


def test_standing_still_is_left_out_not_divided_by_zero() -> None:
    moving = circle(1.0, 0.5, seconds=2.0)
    still = np.repeat(moving[-1:], 30, axis=0)
    xy = np.vstack([moving, still])
    assert mean_path_curvature(xy, DT) == pytest.approx(1.0, rel=1e-9)  # only the moving samples count
    assert average_speed(xy, DT) == pytest.approx(travel_distance(moving) / (DT * (len(xy) - 1)))
    assert mean_path_curvature(still, DT) == 0.0 and mean_lateral_acceleration(still, DT) == 0.0
    assert average_speed(still[:1], DT) == 0.0


def test_episode_row_has_the_paper_columns() -> None:
    xy = circle(2.0, 0.5, seconds=3.0)
    row = episode_metrics(xy, DT, success=True, collision=False, timeout=False)
    assert tuple(row) == METRIC_COLUMNS
    assert (row["success"], row["collision"], row["timeout"]) == (1.0, 0.0, 0.0)
    assert row["path_curvature"] == pytest.approx(0.5)
    assert row["lateral_acc"] == pytest.approx(0.125)
