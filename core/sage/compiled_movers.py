"""The mover model's velocities compiled with numba: :func:`compiled_mover_velocities`, the computation of
:func:`core.sage.movers.mover_velocities` (its rules: that module's docstring) in one compiled call.

The numpy version costs about a millisecond a gate step on the UGV, almost all of it the dispatch of some hundreds of
small array operations (segments of L + 1 scans, their association scan to scan, each track's fit), not arithmetic:
measured by ``bench/bench_gate.py --policy policies/ugv-default``, it was the largest part of the deployed gate's step.
Here the same float64 arithmetic runs as one loop nest; the ego step's prediction of the newest scan is the same
compiled kernel (``core._ego_kernel.scan``) on the same float32 rows. The velocities agree with the numpy version's
within float64 rounding (``tests/core/sage/test_compiled_movers.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from core._ego_kernel import scan as ego_scan
from core.motion import EgoScanStep, _kernel_geometry

# numba's on-disk cache (cache=True) checks the timestamp of this file alone: a change to core/_ego_kernel.py or to
# core/sage/movers.py's rules must come with a change to this file (see core/sage/compiled_gate.py). Last: the scan's
# rays per radian as a product.


@numba.njit(cache=True, nogil=True)
def _segments(
    r: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    ratio: float,
    width: float,
    first: np.ndarray,
    last: np.ndarray,
    centroid: np.ndarray,
    extent: np.ndarray,
    spacing: np.ndarray,
    cut: np.ndarray,
) -> int:
    """The segments of the scan ``r`` (S,) as ``core.sage.movers._Segments`` finds them, written into the arrays; their
    number."""
    s = r.shape[0]
    px, py = np.zeros(s), np.zeros(s)
    hit = np.empty(s, dtype=np.bool_)
    for i in range(s):
        hit[i] = r[i] < 1.0
        if hit[i]:
            px[i], py[i] = r[i] * cos[i], r[i] * sin[i]
    count = 0
    for i in range(s):
        if not hit[i]:
            continue
        joined_before = i > 0 and hit[i - 1] and max(r[i - 1], r[i]) <= ratio * min(r[i - 1], r[i])
        if not joined_before:
            first[count] = i
        joined_after = i + 1 < s and hit[i + 1] and max(r[i], r[i + 1]) <= ratio * min(r[i], r[i + 1])
        if not joined_after:
            last[count] = i
            count += 1
    # the centroids as differences of the points' running sums (numpy's cumsum: the same additions in the same order)
    total_x, total_y = np.zeros(s + 1), np.zeros(s + 1)
    for i in range(s):
        total_x[i + 1] = total_x[i] + px[i]
        total_y[i + 1] = total_y[i] + py[i]
    for j in range(count):
        f, e = first[j], last[j]
        n = max(e - f + 1, 1)
        centroid[j, 0] = (total_x[e + 1] - total_x[f]) / n
        centroid[j, 1] = (total_y[e + 1] - total_y[f]) / n
        extent[j] = math.hypot(px[e] - px[f], py[e] - py[f])
        spacing[j] = math.hypot(centroid[j, 0], centroid[j, 1]) * width
        cut[j] = f == 0 or e == s - 1
    return count


@numba.njit(cache=True, nogil=True)
def _velocities(
    scans: np.ndarray,
    actions: np.ndarray,
    moved: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    numbers: np.ndarray,
    channels: np.ndarray,
    max_speed: float,
    max_size: float,
    min_speed: float,
    out: np.ndarray,
) -> None:
    """``out`` (S, 2): each sector's velocity from ``scans`` (L + 1, S) float64 oldest first, ``actions`` (L, A) float64
    and ``moved`` (S,) the ego step's prediction of the newest scan from the one before (float32, as computed)."""
    ratio, width, forward_scale, forward_offset, turn_scale = numbers[0], numbers[1], numbers[2], numbers[3], numbers[4]
    forward_channel, turn_channel = channels[0], channels[1]
    history, s = scans.shape[0] - 1, scans.shape[1]
    first = np.empty((history + 1, s), dtype=np.int64)
    last = np.empty((history + 1, s), dtype=np.int64)
    centroid = np.empty((history + 1, s, 2))
    extent, spacing = np.empty((history + 1, s)), np.empty((history + 1, s))
    cut = np.empty((history + 1, s), dtype=np.bool_)
    counts = np.empty(history + 1, dtype=np.int64)
    # index 0: the newest scan; index h: the scan h steps before it
    for h in range(history + 1):
        counts[h] = _segments(
            scans[history - h], cos, sin, ratio, width, first[h], last[h], centroid[h], extent[h], spacing[h], cut[h]
        )
    any_candidate = False
    for j in range(counts[0]):
        if not cut[0, j] and extent[0, j] <= max_size:
            any_candidate = True
    if not any_candidate:
        return
    # what the ego step leaves unexplained in the newest scan, widened by a sector each side
    unexplained = np.empty(s, dtype=np.bool_)
    for i in range(s):
        unexplained[i] = abs(scans[history, i] - np.float64(moved[i])) > min_speed
    changed = np.empty(s, dtype=np.bool_)
    for i in range(s):
        changed[i] = unexplained[i] or (i > 0 and unexplained[i - 1]) or (i + 1 < s and unexplained[i + 1])
    # every older scan's centroids moved into the newest frame by the executed actions (the arcs composed)
    x, y, turn = 0.0, 0.0, 0.0
    for h in range(1, history + 1):
        action = actions[history - h]
        distance = action[forward_channel] * forward_scale + forward_offset
        step_turn = action[turn_channel] * turn_scale
        half = 0.5 * step_turn
        chord = distance * (math.sin(half) / half if abs(half) > 1e-6 else 1.0)
        ax, ay = chord * math.cos(half), chord * math.sin(half)
        c, sn = math.cos(step_turn), math.sin(step_turn)
        x, y, turn = ax + c * x - sn * y, ay + sn * x + c * y, step_turn + turn
        c, sn = math.cos(turn), math.sin(turn)
        for j in range(counts[h]):
            dx, dy = centroid[h, j, 0] - x, centroid[h, j, 1] - y
            centroid[h, j, 0], centroid[h, j, 1] = c * dx + sn * dy, c * dy - sn * dx
    times_mean = 0.0
    for t in range(history + 1):
        times_mean += t - history
    times_mean /= history + 1
    centred = np.empty(history + 1)
    squares = 0.0
    for t in range(history + 1):
        centred[t] = (t - history) - times_mean
        squares += centred[t] * centred[t]
    track = np.empty((history + 1, 2))
    for j in range(counts[0]):
        if cut[0, j] or extent[0, j] > max_size:
            continue
        touched = False
        for i in range(first[0, j], last[0, j] + 1):
            touched = touched or changed[i]
        if not touched:
            continue  # the ego step explains it: static
        here_x, here_y = centroid[0, j, 0], centroid[0, j, 1]
        seg_extent, seg_spacing = extent[0, j], spacing[0, j]
        track[history, 0], track[history, 1] = here_x, here_y
        found_all = True
        for h in range(1, history + 1):
            best, best_distance = -1, 0.0
            for k in range(counts[h]):
                distance = math.hypot(centroid[h, k, 0] - here_x, centroid[h, k, 1] - here_y)
                if best < 0 or distance < best_distance:
                    best, best_distance = k, distance
            if best < 0:
                found_all = False
                break
            allowance = max(seg_spacing, spacing[h, best])
            if best_distance > max_speed + allowance or abs(extent[h, best] - seg_extent) > 1.5 * allowance:
                found_all = False
                break
            if cut[h, best]:
                found_all = False
                break
            here_x, here_y = centroid[h, best, 0], centroid[h, best, 1]
            seg_extent, seg_spacing = extent[h, best], spacing[h, best]
            track[history - h, 0], track[history - h, 1] = here_x, here_y
        if not found_all:
            continue
        mean_x, mean_y = 0.0, 0.0
        for t in range(history + 1):
            mean_x += track[t, 0]
            mean_y += track[t, 1]
        mean_x /= history + 1
        mean_y /= history + 1
        vx, vy = 0.0, 0.0
        for t in range(history + 1):
            vx += centred[t] * (track[t, 0] - mean_x)
            vy += centred[t] * (track[t, 1] - mean_y)
        vx /= squares
        vy /= squares
        speed = math.hypot(vx, vy)
        own_spacing = spacing[0, j]
        if speed < max(min_speed, own_spacing / history):
            continue
        worst = 0.0
        for t in range(history):
            worst = max(worst, math.hypot(track[t + 1, 0] - track[t, 0] - vx, track[t + 1, 1] - track[t, 1] - vy))
        if worst > max(0.5 * speed, own_spacing, min_speed):
            continue
        for i in range(first[0, j], last[0, j] + 1):
            out[i, 0], out[i, 1] = vx, vy


_LAYOUT: dict[EgoScanStep, tuple[np.ndarray, ...]] = {}


def _layout(step: EgoScanStep) -> tuple[np.ndarray, ...]:
    """The sectors' return bearings' cosines and sines, the numbers the arcs and the joint rule read, and the ego
    step's own packed geometry (cached per step)."""
    if step not in _LAYOUT:
        from core.sage.movers import _layout as bearings

        cos, sin, ratio = bearings(step)
        numbers = np.array([ratio, step.width, step.forward_scale, step.forward_offset, step.turn_scale], np.float64)
        channels = np.array([step.forward_channel, step.turn_channel], np.int64)
        _LAYOUT[step] = (np.ascontiguousarray(cos), np.ascontiguousarray(sin), numbers, channels)
    return _LAYOUT[step]


def compiled_mover_velocities(
    step: EgoScanStep,
    scans: np.ndarray,
    actions: np.ndarray,
    max_speed: float,
    max_size: float,
    min_speed: float,
) -> np.ndarray:
    """:func:`core.sage.movers.mover_velocities` compiled: (S, 2) each sector's velocity from L + 1 consecutive scans
    ``scans`` (L + 1, >= S) oldest first and the L executed actions ``actions`` (L, A), L >= 2."""
    s = step.sectors
    scans = np.ascontiguousarray(np.asarray(scans, np.float64)[:, :s])
    actions = np.ascontiguousarray(np.asarray(actions, np.float64))
    history = len(scans) - 1
    if history < 2 or len(actions) != history:
        raise ValueError(f"mover velocities need L + 1 >= 3 scans and L actions, got {len(scans)} and {len(actions)}")
    cos, sin, numbers, channels = _layout(step)
    # the ego step's prediction of the newest scan from the one before, on float32 rows (as ``step.apply`` computes it)
    moved = np.empty((1, s), np.float32)
    ego_scan(scans[-2:-1].astype(np.float32), actions[-1:].astype(np.float32), moved, *_kernel_geometry(step))
    out = np.zeros((s, 2), np.float64)
    _velocities(scans, actions, moved[0], cos, sin, numbers, channels, max_speed, max_size, min_speed, out)
    return out
