"""Scores of the self-awareness signals against what happened: labels, early warning, intervals of a curve point's
violations and the comparison of two gatings at equal takeover."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from core.metrics import difference_interval, wilson_interval


@dataclass
class SignalScore:
    auroc: float
    average_precision: float


def labels_within(violation: np.ndarray, episode: np.ndarray, steps: int) -> np.ndarray:
    """1 where a violation happens at this step or within the next ``steps - 1`` steps of the same episode."""
    n = len(violation)
    out = np.zeros(n, bool)
    next_violation = -1
    for i in range(n - 1, -1, -1):
        if i + 1 < n and episode[i + 1] != episode[i]:
            next_violation = -1
        if violation[i]:
            next_violation = i
        out[i] = next_violation >= 0 and next_violation - i < steps
    return out


EARLY_LEAD_S = 1.5
""":func:`early_warning`'s lead [s]: a warning this far ahead, or up to twice that, counts as early (the scripted
highway expert avoided, by a steady manoeuvre, every collision of a replayed handful from 2 s before the takeover and
few from the takeover itself, ``docs/notes/calibration_history.md``)."""
EARLY_FIRING = (0.2, 0.3, 0.45, 0.55)
"""The firing shares :func:`early_warning` compares at."""


def early_warning(
    fear: np.ndarray,
    violation: np.ndarray,
    episode: np.ndarray,
    dt: float,
    lead_s: float = EARLY_LEAD_S,
    firing: Sequence[float] = EARLY_FIRING,
) -> list[dict[str, float]]:
    """How early a signal warns of the violations, compared at equal firing rather than at a gate's own τ (two world
    models' fears on different scales compare fairly): for each share f of ``firing``, the threshold that ``fear``
    exceeds on f of the steps more than 2 · ``lead_s`` from a violation (their (1 - f) quantile), and the share of
    violation steps at which fear exceeded it on some step ``lead_s`` to 2 · ``lead_s`` before, within the episode."""
    lead = max(1, round(lead_s / dt))
    # steps where the gate computed no fear (NaN) neither set a threshold nor warn
    far = ~labels_within(violation, episode, 2 * lead) & np.isfinite(fear)
    hits = np.flatnonzero(violation)
    rows = []
    for share in firing:
        threshold = float(np.quantile(fear[far], 1.0 - share)) if far.any() else math.nan
        warned = 0
        for i in hits:
            window = np.arange(max(0, int(i) - 2 * lead), i - lead + 1)
            window = window[episode[window] == episode[i]]
            warned += bool((np.nan_to_num(fear[window], nan=-np.inf) > threshold).any())
        rows.append(
            {
                "firing": float(share),
                "lead_s": float(lead_s),
                "threshold": threshold,
                "warned": warned / len(hits) if len(hits) else math.nan,
            }
        )
    return rows


def violation_interval(point: dict[str, float]) -> tuple[float, float]:
    """The 95% Wilson interval of a curve point's share of episodes with a violation."""
    return wilson_interval(*violation_counts(point))


def compare_curves(
    curve: dict[str, list[dict[str, float]]], against: str, name: str = "fear (SAGE)", tolerance: float = 0.05
) -> dict[str, int]:
    """Count ``name``'s points that are better, tied with or worse than ``against`` at (nearly) the same takeover
    rate: the ``against`` point nearest in takeover, if within ``tolerance``, and the 95% interval of the
    difference in the share of episodes with a violation (:func:`core.metrics.difference_interval`): better when
    it lies wholly below 0 (fewer violations), worse when wholly above. Points with no counterpart that near are
    ``unmatched``. The issue's target, "above random at every takeover rate", is ``worse == tied == 0``."""
    verdict = {"better": 0, "tied": 0, "worse": 0, "unmatched": 0}
    others = curve.get(against, [])
    for point in curve.get(name, []):
        near = min(others, key=lambda q: abs(q["takeover_rate"] - point["takeover_rate"]), default=None)
        if near is None or abs(near["takeover_rate"] - point["takeover_rate"]) > tolerance:
            verdict["unmatched"] += 1
            continue
        low, high = difference_interval(*violation_counts(point), *violation_counts(near))
        if high < 0:
            verdict["better"] += 1
        elif low > 0:
            verdict["worse"] += 1
        else:
            verdict["tied"] += 1
    return verdict


def violation_counts(point: dict[str, float]) -> tuple[int, int]:
    """(episodes with a violation, episodes) of a curve point."""
    n = int(point.get("episodes", 0))
    return round(point["violation_rate"] * n), n
