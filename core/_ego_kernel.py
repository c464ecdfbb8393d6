"""The ego step's scan (:meth:`core.motion.EgoScanStep.apply`) compiled with numba, for calls that need no gradient.

The tensor version costs some 130 small tensor operations a call, almost all of it dispatch: 0.57 ms for the five
rows of one imagined step of the gate's rollout, 3.6 ms a gate step where the gate without the ego step took 0.33
ms. This loop does the same arithmetic row by row in float64, with the same tests, so that it gives the tensor
version's result computed in float64 (``tests/core/test_motion.py`` holds them to it); float32 inputs are read into
float64 and the result rounded back. It casts each surface segment only at the rays within the bearings its ends
span, not every sector's rays at every segment the step could bring in front of them. With the gate kernel's
buffers bound once (:meth:`core.motion.EgoScanStep.bound`), the gate step over the ego step costs 0.45 ms against
0.33 ms without (``bench/bench_gate.py --ego``, one core of this project's 2-core machine).
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Every function here compiles with error_model="numpy": no check before each division for a zero divisor, which
# none has (a ray's denominator is tested against 1e-9 first, a sector's width and a turn's sinc argument likewise), so
# the same numbers come out some 10% sooner.

TURN = 2.0 * math.pi
RAY_MARGIN = 1e-3
"""Rays are cast at a surface segment within its ends' bearings widened by this share of the rays' spacing: a ray at
a bearing outside them misses it (its ``across`` is outside [0, 1] by orders of magnitude more than rounding moves it,
unless a moved return lands within 1e-12 of the robot), and the nearest hit is the same as over every candidate."""


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _meet(ax: float, ay: float, ex: float, ey: float, ux: float, uy: float) -> float:
    """Where the ray u meets the segment A -> A + E (inf: it does not); the arithmetic of ``core.motion._cast``, its
    second division only where the first finds the ray within the segment."""
    den = ux * ey - uy * ex
    if abs(den) <= 1e-9:
        return math.inf
    across = (ax * uy - ay * ux) / den
    if not 0.0 <= across <= 1.0:  # tested first: most candidates miss, and then need no second division
        return math.inf
    along = (ax * ey - ay * ex) / den
    return along if along > 0.0 else math.inf


BEARING_ERROR = 1e-7
"""A bound on :func:`_bearing_near`'s error (rad): its polynomial errs under 2e-8 (1.4e-8 measured on 5e7 bearings)."""


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bearing_near(y: float, x: float) -> float:
    """atan2(y, x) within :data:`BEARING_ERROR`, a few times sooner: Abramowitz and Stegun's 4.4.49 on the octant. A
    return's bearing decides only its sector and which rays are cast at its surface; where the bound leaves either in
    doubt, :func:`_placed` takes the exact atan2, so every result is the exact bearing's."""
    ax, ay = abs(x), abs(y)
    big, small = max(ax, ay), min(ax, ay)
    if big == 0.0:
        return math.atan2(y, x)
    t = small / big
    s = t * t
    p = -0.0161657367 + s * 0.0028662257
    p = -0.0752896400 + s * (0.0429096138 + s * p)
    p = -0.1420889944 + s * (0.1065626393 + s * p)
    p = t * (1.0 + s * (-0.3333314528 + s * (0.1999355085 + s * p)))
    if ay > ax:
        p = 0.5 * math.pi - p
    if x < 0.0:
        p = math.pi - p
    return math.copysign(p, y)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _placed(near: float, y: float, x: float, start: float, width: float, slack: float) -> tuple[float, float, int]:
    """For a return at (x, y) whose bearing is ``near`` within :data:`BEARING_ERROR`: bounds on its bearing from the
    first ray (:func:`_from_start` of the exact bearing lies between them) and the sector it falls in (``floor((bearing
    - start) / width)`` of the exact bearing); ``slack`` is BEARING_ERROR / width. The exact atan2 decides where the
    bound straddles a sector's edge or the first ray's bearing (the bound is seven times the error, so the rounding of
    these few operations cannot carry the exact value past an edge the bound clears)."""
    turned = _from_start(near, start)
    position = (near - start) / width
    sector = math.floor(position - slack)
    if turned < BEARING_ERROR or turned > TURN - BEARING_ERROR or sector != math.floor(position + slack):
        exact = math.atan2(y, x)
        turned = _from_start(exact, start)
        return turned, turned, math.floor((exact - start) / width)
    return turned - BEARING_ERROR, turned + BEARING_ERROR, sector


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _from_start(bearing: float, start: float) -> float:
    """(bearing - start) % TURN, in [0, TURN], without the floating-point remainder (a tenth of a row's cost) where the
    difference is within a turn of that range: the remainder is then exact and the one addition or subtraction that
    stands for it gives the same number (Sterbenz's lemma for the subtraction), and so the same bits."""
    relative = bearing - start
    if 0.0 <= relative < TURN:
        return relative + 0.0  # -0.0 as the remainder gives it, +0.0
    if -TURN <= relative < 0.0:
        return relative + TURN
    if TURN <= relative < 2.0 * TURN:
        return relative - TURN
    return relative % TURN


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _move_returns(
    ranges: np.ndarray,
    distance: float,
    turn: float,
    cos: np.ndarray,
    sin: np.ndarray,
    joint_ratio: float,
    r: np.ndarray,
    x0: np.ndarray,
    y0: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    hit: np.ndarray,
    bearing: np.ndarray,
    joined: np.ndarray,
) -> None:
    """One row's returns before the step (``r``, ``x0``, ``y0``) and seen from the pose after an arc of ``distance``
    and ``turn`` (``x``, ``y``, and ``bearing`` where a hit, within :data:`BEARING_ERROR`), which are hits, and which
    neighbours join into a surface segment."""
    s = r.shape[0]
    half = 0.5 * turn
    chord = distance if abs(half) <= 1e-6 else distance * (math.sin(half) / half)
    shift_x, shift_y = chord * math.cos(half), chord * math.sin(half)
    c, n = math.cos(turn), math.sin(turn)
    for j in range(s):
        r[j] = ranges[j]
        x0[j], y0[j] = r[j] * cos[j], r[j] * sin[j]
        px, py = x0[j] - shift_x, y0[j] - shift_y
        x[j], y[j] = c * px + n * py, c * py - n * px
        hit[j] = r[j] < 1.0
        if hit[j]:  # read for returns only, and within BEARING_ERROR (an atan2 was a third of a row's cost)
            bearing[j] = _bearing_near(y[j], x[j])
    for j in range(s - 1):
        near, far = min(r[j], r[j + 1]), max(r[j], r[j + 1])
        joined[j] = hit[j] and hit[j + 1] and far <= joint_ratio * near


@numba.njit(cache=True, nogil=True, error_model="numpy")
def scan(
    states: np.ndarray,
    actions: np.ndarray,
    out: np.ndarray,
    directions: np.ndarray,
    segments: np.ndarray,
    numbers: np.ndarray,
    channels: np.ndarray,
) -> None:
    """Writes into ``out`` (B, D) the (B, D) ``states`` with their first S channels, ranges, moved by the (B, A)
    ``actions`` (any float dtype and strides; ``out`` must not overlap ``states``). Packed in few arrays because a
    call's cost grows with its arguments: ``directions`` (S, 2 + 2 rays) float64, each sector's return bearing's
    cosine and sine, then its rays' cosines and sines; ``segments`` (S, 2 window + 2 + 2 rays) int64, the segments
    (index of their first return) each sector's rays are tested against after the step, then the two where the robot
    is, then whether ray q can meet the t-th of those (column t * rays + q; ``core.motion._own_crossings``);
    ``numbers`` float64: start, width, forward scale and offset, turn scale, joint ratio; ``channels`` int64: the
    action's forward and turn channels."""
    k = (directions.shape[1] - 2) // 2
    cos, sin, ray_cos, ray_sin = directions[:, 0], directions[:, 1], directions[:, 2 : 2 + k], directions[:, 2 + k :]
    candidates = segments.shape[1] - 2 - 2 * k
    last_candidate, own, crosses = (
        candidates - 1,
        segments[:, candidates : candidates + 2],
        segments[:, candidates + 2 :],
    )
    start, width, forward_scale, forward_offset, turn_scale, joint_ratio = numbers
    forward_channel, turn_channel = channels
    rows, s = states.shape[0], directions.shape[0]
    r, x0, y0 = np.empty(s), np.empty(s), np.empty(s)
    x, y = np.empty(s), np.empty(s)
    hit = np.empty(s, dtype=np.bool_)
    joined = np.zeros(s - 1, dtype=np.bool_)
    landed, after, bearing = np.empty(s), np.empty(s), np.empty(s)
    turned_low, turned_high = np.empty(s), np.empty(s)
    # rays per radian: a product where two divisions were (a few ulps apart: a ray it adds or drops lies RAY_MARGIN
    # of a spacing outside the segment's bearings, and misses it)
    per_ray, slack = k / width, BEARING_ERROR / width
    for b in range(rows):
        out[b, s:] = states[b, s:]
        _move_returns(
            states[b], actions[b, forward_channel] * forward_scale + forward_offset,
            actions[b, turn_channel] * turn_scale, cos, sin, joint_ratio, r, x0, y0, x, y, hit, bearing, joined,
        )  # fmt: skip
        landed[:], after[:] = math.inf, math.inf
        for j in range(s):
            if not hit[j]:
                continue
            # bounds on the bearing from the first ray on, in [0, 2 pi] (read below), and the sector it lands in
            turned_low[j], turned_high[j], sector = _placed(bearing[j], y[j], x[j], start, width, slack)
            inside = 0 < j < s - 1 and joined[j - 1] and joined[j]
            if not inside and 0 <= sector < s:
                landed[sector] = min(landed[sector], math.hypot(x[j], y[j]))
        # Cast from the new pose segment by segment, at the rays within the bearings its ends span (RAY_MARGIN of a
        # ray's spacing to spare) that would test it (it is among their sector's candidates): the same hits as casting
        # each sector's rays at all its candidates, with a tenth of the tests.
        for j in range(s - 1):
            if not joined[j]:
                continue
            ax, ay, ex, ey = x[j], y[j], x[j + 1] - x[j], y[j + 1] - y[j]
            # the ends' bearings from the first ray on, in [0, 2 pi]: the arc between them, or both ways past the
            # first ray's bearing (the arc is under pi: a segment does not pass through the robot). Their bounds give
            # the rays of every bearing they may have, and all rays where the arc may be either: more rays than the
            # exact bearings give, which miss the segment
            lo, hi = min(turned_low[j], turned_low[j + 1]), max(turned_high[j], turned_high[j + 1])
            if hi - lo <= math.pi:
                # the rays within the bearings of its ends (a ray further out misses it by far more than rounding)
                first = max(0, math.ceil(lo * per_ray - RAY_MARGIN))
                last = min(s * k - 1, math.floor(hi * per_ray + RAY_MARGIN))
            else:
                first, last = 0, s * k - 1
            i, q = first // k, first % k  # the ray i * k + q, stepped without a division
            for _ in range(first, last + 1):
                if segments[i, 0] <= j <= segments[i, last_candidate]:
                    after[i] = min(after[i], _meet(ax, ay, ex, ey, ray_cos[i, q], ray_sin[i, q]))
                q += 1
                if q == k:
                    i, q = i + 1, 0
        for i in range(s):
            before = math.inf  # the nearest hit of the sector's rays on the two segments where the robot was
            for t in range(2):
                idx = own[i, t]
                if joined[idx]:
                    ax, ay = x0[idx], y0[idx]
                    ex, ey = x0[idx + 1] - ax, y0[idx + 1] - ay
                    for q in range(k):
                        if crosses[i, t * k + q]:
                            before = min(before, _meet(ax, ay, ex, ey, ray_cos[i, q], ray_sin[i, q]))
            after_i = after[i]
            seen = r[i] + (after_i - before) if math.isfinite(before) and math.isfinite(after_i) else after_i
            nearest = min(seen, landed[i])
            out[b, i] = r[i] if math.isinf(nearest) else min(max(nearest, 0.0), 1.0)


CHOICE_FIELDS = 6
"""Per (row, sector), what :func:`scan_with_choices` records, each field a contiguous (B, S) plane: the output's kind
(``KIND_*``), the segment (index of its first return) and ray (``sector * rays + ray``) that gave the cast after the
step, the two that gave the cast before it, and the return that landed in the sector (-1 where none)."""
KIND_RANGE, KIND_CLAMPED, KIND_SEEN, KIND_AFTER, KIND_LANDED = 0, 1, 2, 3, 4
"""The reading is the range itself (nothing seen); a clamp's bound (0 or 1); the range moved by the change between
the casts; the cast after the step; a return that landed in the sector."""


@numba.njit(cache=True, nogil=True, error_model="numpy")
def scan_with_choices(
    states: np.ndarray,
    actions: np.ndarray,
    out: np.ndarray,
    choices: np.ndarray,
    directions: np.ndarray,
    segments: np.ndarray,
    numbers: np.ndarray,
    channels: np.ndarray,
) -> None:
    """:func:`scan`, also writing into ``choices`` (:data:`CHOICE_FIELDS`, B, S) int64 which candidate gave each
    reading: a gradient then needs only the chosen segment and ray per sector (``core.motion.EgoScanStep.apply`` with
    gradients recomputes those in torch), not every sector's rays at every candidate."""
    k = (directions.shape[1] - 2) // 2
    cos, sin, ray_cos, ray_sin = directions[:, 0], directions[:, 1], directions[:, 2 : 2 + k], directions[:, 2 + k :]
    candidates = segments.shape[1] - 2 - 2 * k
    last_candidate, own, crosses = (
        candidates - 1,
        segments[:, candidates : candidates + 2],
        segments[:, candidates + 2 :],
    )
    start, width, forward_scale, forward_offset, turn_scale, joint_ratio = numbers
    forward_channel, turn_channel = channels
    rows, s = states.shape[0], directions.shape[0]
    r, x0, y0 = np.empty(s), np.empty(s), np.empty(s)
    x, y = np.empty(s), np.empty(s)
    hit = np.empty(s, dtype=np.bool_)
    joined = np.zeros(s - 1, dtype=np.bool_)
    landed, after, bearing = np.empty(s), np.empty(s), np.empty(s)
    turned_low, turned_high = np.empty(s), np.empty(s)
    # rays per radian: a product where two divisions were (a few ulps apart: a ray it adds or drops lies RAY_MARGIN
    # of a spacing outside the segment's bearings, and misses it)
    per_ray, slack = k / width, BEARING_ERROR / width
    for b in range(rows):
        out[b, s:] = states[b, s:]
        choices[:, b, :] = -1
        _move_returns(
            states[b], actions[b, forward_channel] * forward_scale + forward_offset,
            actions[b, turn_channel] * turn_scale, cos, sin, joint_ratio, r, x0, y0, x, y, hit, bearing, joined,
        )  # fmt: skip
        landed[:], after[:] = math.inf, math.inf
        for j in range(s):
            if not hit[j]:
                continue
            turned_low[j], turned_high[j], sector = _placed(bearing[j], y[j], x[j], start, width, slack)
            inside = 0 < j < s - 1 and joined[j - 1] and joined[j]
            if not inside and 0 <= sector < s:
                distance_j = math.hypot(x[j], y[j])
                if distance_j < landed[sector]:
                    landed[sector] = distance_j
                    choices[5, b, sector] = j
        for j in range(s - 1):
            if not joined[j]:
                continue
            ax, ay, ex, ey = x[j], y[j], x[j + 1] - x[j], y[j + 1] - y[j]
            lo, hi = min(turned_low[j], turned_low[j + 1]), max(turned_high[j], turned_high[j + 1])
            if hi - lo <= math.pi:
                # the rays within the bearings of its ends (a ray further out misses it by far more than rounding)
                first = max(0, math.ceil(lo * per_ray - RAY_MARGIN))
                last = min(s * k - 1, math.floor(hi * per_ray + RAY_MARGIN))
            else:
                first, last = 0, s * k - 1
            i, q = first // k, first % k
            for ray in range(first, last + 1):
                if segments[i, 0] <= j <= segments[i, last_candidate]:
                    along = _meet(ax, ay, ex, ey, ray_cos[i, q], ray_sin[i, q])
                    if along < after[i]:
                        after[i] = along
                        choices[1, b, i] = j
                        choices[2, b, i] = ray
                q += 1
                if q == k:
                    i, q = i + 1, 0
        for i in range(s):
            before = math.inf
            for t in range(2):
                idx = own[i, t]
                if joined[idx]:
                    ax, ay = x0[idx], y0[idx]
                    for q in range(k):
                        if not crosses[i, t * k + q]:
                            continue
                        along = _meet(ax, ay, x0[idx + 1] - ax, y0[idx + 1] - ay, ray_cos[i, q], ray_sin[i, q])
                        if along < before:
                            before = along
                            choices[3, b, i] = idx
                            choices[4, b, i] = i * k + q
            after_i = after[i]
            both = math.isfinite(before) and math.isfinite(after_i)
            seen = r[i] + (after_i - before) if both else after_i
            kind = KIND_SEEN if both else KIND_AFTER
            nearest = seen
            if landed[i] < seen:
                nearest, kind = landed[i], KIND_LANDED
            if math.isinf(nearest):
                out[b, i], kind = r[i], KIND_RANGE
            else:
                out[b, i] = min(max(nearest, 0.0), 1.0)
                if nearest < 0.0 or nearest > 1.0:
                    kind = KIND_CLAMPED
            choices[0, b, i] = kind


@numba.njit(cache=True, nogil=True, error_model="numpy")
def contact(
    states: np.ndarray,
    actions: np.ndarray,
    delta: np.ndarray,
    floors: np.ndarray,
    closing: np.ndarray,
    touching: np.ndarray,
    directions: np.ndarray,
    segments: np.ndarray,
    numbers: np.ndarray,
    channels: np.ndarray,
) -> None:
    """Writes into ``touching`` (N, B) bool whether member n's imagined state, ``states`` moved by :func:`scan` plus its
    predicted change ``delta[n]`` (N, B, F), is at or under ``floors`` (F,) in some channel i < F that ``closing``
    (1 or B, F) bool allows: ``core.sage.fear.with_contact`` of that state, without the state. ``states`` (B, D) are
    shared by the members, or (N B, D) one per member (row n B + b), with their (B or N B, A) ``actions``. The moved
    state is held in the states' dtype before the sum, as the tensor path's ``base + delta``, so the same numbers are
    compared; torch's reductions over a channel axis this short cost more than the comparisons themselves."""
    members, rows, width = delta.shape
    base = np.empty_like(states)
    scan(states, actions, base, directions, segments, numbers, channels)
    shared = states.shape[0] == rows
    for n in range(members):
        for b in range(rows):
            row = b if shared else n * rows + b
            allowed = closing[b if closing.shape[0] > 1 else 0]
            found = False
            for i in range(width):
                if allowed[i] and base[row, i] + delta[n, b, i] <= floors[i]:
                    found = True
                    break
            touching[n, b] = found
