"""Study statistics, budgets and the paper's numbers as data."""

from __future__ import annotations

import math
import statistics

import pytest

from studies.budgets import BUDGET_NAMES, budget
from studies.paper import paper_value
from studies.stats import mean_ci, t_quantile_975


def test_five_seed_interval_uses_students_t() -> None:
    values = [0.10, 0.20, 0.15, 0.30, 0.25]
    ci = mean_ci(values)
    expected_half = 2.776 * statistics.stdev(values) / math.sqrt(5)
    assert ci.mean == pytest.approx(0.20)
    assert ci.half_width == pytest.approx(expected_half)
    assert ci.half_width > 1.96 * statistics.stdev(values) / math.sqrt(5)  # wider than the normal interval
    assert ci.n == 5


def test_large_sample_quantile_approaches_normal() -> None:
    assert t_quantile_975(30) == pytest.approx(2.042)
    assert t_quantile_975(31) < t_quantile_975(30)
    assert t_quantile_975(60) == pytest.approx(2.000, abs=2e-3)
    assert t_quantile_975(10_000) == pytest.approx(1.960, abs=1e-3)


def test_single_seed_has_no_interval_and_bad_input_is_refused() -> None:
    one = mean_ci([0.5])
    assert math.isnan(one.half_width) and one.format() == "0.50 (n=1)"
    with pytest.raises(ValueError, match="at least one"):
        mean_ci([])
    with pytest.raises(ValueError, match="NaN"):
        mean_ci([0.1, float("nan")])


def test_overlap_decides_separated_intervals() -> None:
    low = mean_ci([0.01, 0.02, 0.03, 0.02, 0.02])
    high = mean_ci([0.30, 0.35, 0.32, 0.31, 0.33])
    assert not low.overlaps(high)
    assert low.overlaps(mean_ci([0.0, 0.05, 0.02, 0.01, 0.03]))


def test_budgets_count_environment_steps_and_grow() -> None:
    smoke, small, full = (budget(n) for n in BUDGET_NAMES)
    assert smoke.train_steps < small.train_steps < full.train_steps
    assert small.seeds == full.seeds == 5
    with pytest.raises(ValueError, match="smoke, small, full"):
        budget("huge")


def test_paper_numbers_by_our_method_names() -> None:
    cell = paper_value("highway", ("test", "sage", "adversarial"), "collision_rate_pct")
    assert cell is not None and cell.mean == 13.2
    sac = paper_value("highway", ("test", "sac", "adversarial"), "collision_rate_pct")
    assert sac is not None and sac.mean == 43.8
    speed = paper_value("highway", ("train", "SAC", "normal"), "speed_mps")
    assert speed is not None and speed.format() == "9.42 ± 3.71"
    assert paper_value("route-shift", ("c1", "sage"), "collision_rate_pct") is None
