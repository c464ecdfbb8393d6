"""Mean and 95% confidence interval over training seeds (Student's t-interval).

A study trains every method on a handful of seeds (five by default), so the interval uses Student's t
distribution with ``n - 1`` degrees of freedom, not the normal 1.96: with five seeds the half-width is
``2.776 * s / sqrt(5)``. No scipy dependency: the two-sided 97.5% quantiles for 1..30 degrees of freedom are
tabulated and larger samples use the Cornish-Fisher expansion, which is accurate to 1e-3 there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

_T975 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
    2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
    2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
)  # fmt: skip
"""t_{0.975} for 1..30 degrees of freedom (standard tables)."""


def t_quantile_975(dof: int) -> float:
    """The 97.5% quantile of Student's t with ``dof`` degrees of freedom (the 95% two-sided multiplier)."""
    if dof < 1:
        raise ValueError(f"a t-interval needs at least 1 degree of freedom, got {dof}")
    if dof <= len(_T975):
        return _T975[dof - 1]
    z = 1.959964
    g1 = (z**3 + z) / 4
    g2 = (5 * z**5 + 16 * z**3 + 3 * z) / 96
    g3 = (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384
    return z + g1 / dof + g2 / dof**2 + g3 / dof**3


@dataclass(frozen=True)
class Interval:
    """A sample mean with its 95% t-interval half-width (``nan`` half-width for a single seed)."""

    mean: float
    half_width: float
    n: int
    """Number of values (seeds) behind the mean."""

    @property
    def low(self) -> float:
        return self.mean - self.half_width

    @property
    def high(self) -> float:
        return self.mean + self.half_width

    def overlaps(self, other: Interval) -> bool:
        """Whether the two intervals share any value (an undefined interval overlaps everything)."""
        if math.isnan(self.half_width) or math.isnan(other.half_width):
            return True
        return self.low <= other.high and other.low <= self.high

    def format(self, digits: int = 2) -> str:
        """``mean ± half`` (``mean (n=1)`` when there is no interval)."""
        if math.isnan(self.half_width):
            return f"{self.mean:.{digits}f} (n={self.n})"
        return f"{self.mean:.{digits}f} ± {self.half_width:.{digits}f}"


def mean_ci(values: Sequence[float]) -> Interval:
    """Mean and 95% t-interval of ``values`` (one per seed); NaN values are a clear error, not dropped."""
    xs = [float(v) for v in values]
    if not xs:
        raise ValueError("mean_ci needs at least one value")
    if any(math.isnan(x) for x in xs):
        raise ValueError(f"mean_ci got NaN among {xs}: a seed did not produce this metric")
    n = len(xs)
    mean = sum(xs) / n
    if n == 1:
        return Interval(mean, math.nan, 1)
    var = sum((x - mean) ** 2 for x in xs) / (n - 1)
    return Interval(mean, t_quantile_975(n - 1) * math.sqrt(var / n), n)
