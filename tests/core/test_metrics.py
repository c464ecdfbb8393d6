"""AUROC and average precision against hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.metrics import auroc, average_precision, difference_interval, reliability, wilson_interval


def test_auroc_counts_ordered_pairs_and_ties_half() -> None:
    assert auroc(np.array([0.1, 0.2, 0.8, 0.9]), np.array([0, 0, 1, 1])) == 1.0
    assert auroc(np.array([0.9, 0.8, 0.2, 0.1]), np.array([0, 0, 1, 1])) == 0.0
    # positives 0.5, 0.7 against negatives 0.5, 0.1: pairs (0.5 vs 0.5 tie) 0.5 + 1 + 1 + 1 = 3.5 of 4
    assert auroc(np.array([0.5, 0.7, 0.5, 0.1]), np.array([1, 1, 0, 0])) == 3.5 / 4
    assert math.isnan(auroc(np.array([0.1, 0.2]), np.array([0, 0])))
    rng = np.random.default_rng(0)
    assert abs(auroc(rng.random(20000), rng.random(20000) < 0.1) - 0.5) < 0.02


def test_average_precision_and_reliability() -> None:
    # ranking: pos, neg, pos -> precision at the hits 1 and 2/3
    assert average_precision(np.array([0.9, 0.8, 0.7]), np.array([1, 0, 1])) == (1 + 2 / 3) / 2
    bins = reliability(np.array([0.05, 0.05, 0.95, 0.95]), np.array([0, 0, 1, 0]), bins=10)
    assert bins == [(0.05, 0.0, 2), (0.95, 0.5, 2)]


def test_wilson_interval_matches_the_textbook_values_and_stays_in_range() -> None:
    # 0 of 10: (0, 0.278); 5 of 10: (0.237, 0.763) (Wilson 1927 / Newcombe 1998 tables)
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert wilson_interval(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    low, high = wilson_interval(10, 10)
    assert high == pytest.approx(1.0) and low == pytest.approx(0.7225, abs=1e-4)
    # more episodes, a narrower interval around the same rate
    assert np.diff(wilson_interval(10, 40)) < np.diff(wilson_interval(5, 20))
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(11, 10)


def test_difference_interval_matches_newcombes_worked_examples() -> None:
    # Newcombe (1998), Statistics in Medicine 17:873-890, table II, method 10
    assert difference_interval(56, 70, 48, 80) == pytest.approx((0.0524, 0.3339), abs=1e-4)
    assert difference_interval(9, 10, 3, 10) == pytest.approx((0.1705, 0.8090), abs=1e-4)
    assert difference_interval(5, 56, 0, 29) == pytest.approx((-0.0381, 0.1926), abs=1e-4)
    # antisymmetric, and narrower with more episodes at the same rates
    low, high = difference_interval(3, 10, 9, 10)
    assert (low, high) == pytest.approx((-0.8090, -0.1705), abs=1e-4)
    assert np.diff(difference_interval(8, 40, 28, 40)) < np.diff(difference_interval(2, 10, 7, 10))
    assert all(math.isnan(v) for v in difference_interval(0, 0, 1, 10))
