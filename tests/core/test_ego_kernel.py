"""The compiled ray-segment test (``core._ego_kernel._meet``) decides hit or miss without its first division where the
numerator is clear of both ends (issue 63); it must return what the division returned, bit for bit, on every input:
random rays and segments, numerators at and within rounding of both ends, signed zeros and non-finite values."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

numba = pytest.importorskip("numba")

from core import _ego_kernel  # noqa: E402


def reference(ax: float, ay: float, ex: float, ey: float, ux: float, uy: float) -> float:
    """``_meet`` as it was: both divisions, in Python's IEEE doubles."""
    den = ux * ey - uy * ex
    if abs(den) <= 1e-9:
        return math.inf
    try:
        across = (ax * uy - ay * ux) / den
    except ZeroDivisionError:  # pragma: no cover - den is over 1e-9 here
        return math.inf
    if not 0.0 <= across <= 1.0:
        return math.inf
    along = (ax * ey - ay * ex) / den
    return along if along > 0.0 else math.inf


def bits(x: float) -> bytes:
    return struct.pack("<d", x)


def same(got: float, expected: float) -> bool:
    return bits(got) == bits(expected) or (math.isnan(got) and math.isnan(expected))


def test_random_rays_and_segments_give_the_same_bits() -> None:
    rng = np.random.default_rng(0)
    rows = rng.uniform(-1.5, 1.5, (20_000, 4))
    angles = rng.uniform(-math.pi, math.pi, 20_000)
    hits = 0
    for (ax, ay, ex, ey), angle in zip(rows, angles, strict=True):
        ux, uy = math.cos(angle), math.sin(angle)
        expected = reference(ax, ay, ex, ey, ux, uy)
        got = _ego_kernel._meet(ax, ay, ex, ey, ux, uy)
        assert same(got, expected), (ax, ay, ex, ey, ux, uy, got, expected)
        hits += math.isfinite(expected)
    assert 1_000 < hits < 19_000  # both outcomes occur: the comparison can fail


def test_numerators_at_and_within_rounding_of_the_ends_give_the_same_bits() -> None:
    """Rays through a segment's ends and a few ulps either side, for both signs of the denominator: where the rounded
    quotient may land on 0 or 1 from outside, the division decides, as before."""
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(2_000):
        ax, ay = rng.uniform(-1.5, 1.5, 2)
        ex, ey = rng.uniform(-1.5, 1.5, 2)
        for end in (0.0, 1.0):
            px, py = ax + end * ex, ay + end * ey  # the segment's end: across is 0 or 1 in exact arithmetic
            base = math.atan2(py, px)
            for steps in range(-6, 7):
                angle = base + steps * 2.0**-52 * max(1.0, abs(base))
                for sign in (1.0, -1.0):  # the ray and its opposite: both signs of the denominator
                    ux, uy = sign * math.cos(angle), sign * math.sin(angle)
                    expected = reference(ax, ay, ex, ey, ux, uy)
                    got = _ego_kernel._meet(ax, ay, ex, ey, ux, uy)
                    assert same(got, expected), (ax, ay, ex, ey, ux, uy, got, expected)
                    checked += 1
    assert checked == 2_000 * 2 * 13 * 2


@pytest.mark.parametrize(
    "args",
    [
        (0.0, 0.0, 1.0, 0.0, 0.0, 1.0),  # the segment starts at the robot
        (-0.0, 0.0, 1.0, 0.0, 0.0, 1.0),
        (0.5, -0.5, 0.0, 1.0, 1.0, 0.0),  # through the middle
        (0.5, -0.5, 0.0, 1.0, 1.0, -0.0),
        (0.5, 0.0, 0.0, 1.0, 1.0, 0.0),  # through the first end exactly
        (0.5, -1.0, 0.0, 1.0, 1.0, 0.0),  # through the second end exactly
        (0.5, -1.0, 0.0, 1.0, -1.0, 0.0),  # behind the robot
        (1.0, 1.0, 1.0, 1.0, math.sqrt(0.5), math.sqrt(0.5)),  # parallel
        (math.nan, 0.0, 1.0, 0.0, 0.0, 1.0),
        (0.5, math.nan, 0.0, 1.0, 1.0, 0.0),
        (math.inf, -0.5, 0.0, 1.0, 1.0, 0.0),
        (0.5, -math.inf, 0.0, 1.0, 1.0, 0.0),
        (0.5, -0.5, 0.0, math.inf, 1.0, 0.0),
        (0.5, -0.5, 1e-310, 1.0, 1.0, 0.0),
        (1e-310, -0.5, 0.0, 1.0, 1.0, 0.0),
        (0.5, -0.5, 0.0, 1e300, 1.0, 0.0),
        (0.5, -1e300, 0.0, 1e300, 1.0, 0.0),
    ],
)
def test_edge_cases_give_the_same_bits(args: tuple[float, ...]) -> None:
    assert same(_ego_kernel._meet(*args), reference(*args))
