"""The TEB band's residuals and Jacobian entries (:class:`sims.ugv.teb.TebOptimizer`) compiled with numba.

The solver asks for them some 30 times per band solve, and in numpy each ask was some 60 small-array operations
whose dispatch cost more than their arithmetic. These loops do the same arithmetic element by element, in the same
order (no fastmath: no fused or reordered operations), so they give the numpy version's bits
(``tests/sims/ugv/test_teb_equivalence.py`` holds them to the residuals and Jacobian the numpy version recorded). The
transcendental functions stay in numpy: the caller passes cos θ, sin θ and ΔT = exp(u), so no library's cos or exp
can differ from the one the numpy version used.

``weights`` packs the settings: the square roots of the kinematics, forward, velocity, acceleration, time,
obstacle and inflation weights, then v_max, w_max, the two acceleration limits, the minimum obstacle distance and
the inflation distance.
"""

from __future__ import annotations

import math

import numba
import numpy as np

SQRT_KINEMATICS, SQRT_FORWARD, SQRT_VELOCITY, SQRT_ACCELERATION, SQRT_TIME, SQRT_OBSTACLE, SQRT_INFLATION = range(7)
V_MAX, W_MAX, ACC_LIMIT_V, ACC_LIMIT_W, MIN_OBSTACLE_DIST, INFLATION_DIST = range(7, 13)
WEIGHTS = 13


@numba.njit(cache=True, nogil=True, inline="always")
def _relu(x: float) -> float:
    """np.maximum(0.0, x): 0.0 unless x is above it (NaN passes through)."""
    return 0.0 if x <= 0.0 else x


@numba.njit(cache=True, nogil=True, inline="always")
def _sign(x: float) -> float:
    """np.sign."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x  # 0.0, -0.0 or NaN, as np.sign gives them


@numba.njit(cache=True, nogil=True)
def band_terms(
    z: np.ndarray,
    start: np.ndarray,
    end_xy: np.ndarray,
    v0: float,
    w0: float,
    obstacles: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
    dts: np.ndarray,
    th: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The terms residuals and Jacobian share: per segment j (8, n - 1) its dx, dy, progress, v, w, span, linear and
    angular acceleration; per segment and obstacle slot (3, n - 1, m) the offset's x and y and the gap."""
    n = len(th)
    segments = n - 1
    m = obstacles.shape[1]
    if len(z) < 2 * (n - 2) or len(dts) != segments or obstacles.shape[0] != segments or obstacles.shape[2] != 2:
        raise ValueError("band_terms: z, dts or obstacles do not fit the band's poses")
    xy = np.empty((n, 2))
    xy[0, 0], xy[0, 1] = start[0], start[1]
    for i in range(1, n - 1):
        xy[i, 0], xy[i, 1] = z[2 * (i - 1)], z[2 * (i - 1) + 1]
    xy[n - 1, 0], xy[n - 1, 1] = end_xy[0], end_xy[1]
    dx, dy, progress = np.empty(segments), np.empty(segments), np.empty(segments)
    v, w, spans = np.empty(segments), np.empty(segments), np.empty(segments)
    acc_v, acc_w = np.empty(segments), np.empty(segments)
    for j in range(segments):
        dx[j] = xy[j + 1, 0] - xy[j, 0]
        dy[j] = xy[j + 1, 1] - xy[j, 1]
        progress[j] = c[j] * dx[j] + s[j] * dy[j]
        turn = (th[j + 1] - th[j] + math.pi) % (2 * math.pi) - math.pi
        v[j] = progress[j] / dts[j]
        w[j] = turn / dts[j]
        spans[j] = 0.5 * ((dts[0] if j == 0 else dts[j - 1]) + dts[j])
        acc_v[j] = ((v[j] - v0) if j == 0 else (v[j] - v[j - 1])) / spans[j]
        acc_w[j] = ((w[j] - w0) if j == 0 else (w[j] - w[j - 1])) / spans[j]
    segment_terms = np.empty((8, segments))
    segment_terms[0], segment_terms[1], segment_terms[2], segment_terms[3] = dx, dy, progress, v
    segment_terms[4], segment_terms[5], segment_terms[6], segment_terms[7] = w, spans, acc_v, acc_w
    slot_terms = np.empty((3, segments, m))
    for j in range(segments):
        for i in range(m):
            ox = xy[j + 1, 0] - obstacles[j, i, 0]
            oy = xy[j + 1, 1] - obstacles[j, i, 1]
            gap = math.sqrt(ox * ox + oy * oy)
            slot_terms[0, j, i], slot_terms[1, j, i] = ox, oy
            slot_terms[2, j, i] = gap if (gap >= 1e-9 or gap != gap) else 1e-9  # np.maximum(gap, 1e-9)
    return segment_terms, slot_terms


@numba.njit(cache=True, nogil=True, inline="always")
def entries(segments: int, m: int) -> int:
    """How many Jacobian entries :func:`band_jacobian` computes for a band of ``segments`` and ``m`` obstacle slots
    (the writes below are unchecked: the layout must hold exactly these)."""
    return 39 * segments - 9 + 4 * segments * m


@numba.njit(cache=True, nogil=True)
def band_residuals(
    segment_terms: np.ndarray,
    slot_terms: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
    dts: np.ndarray,
    weights: np.ndarray,
) -> np.ndarray:
    """The residual vector, in the numpy version's order of blocks."""
    segments, m = slot_terms.shape[1], slot_terms.shape[2]
    dx, dy, progress, v, w = segment_terms[0], segment_terms[1], segment_terms[2], segment_terms[3], segment_terms[4]
    acc_v, acc_w, gaps = segment_terms[6], segment_terms[7], slot_terms[2]
    out = np.empty(7 * segments + 2 * segments * m)
    sk, sf, sv = weights[SQRT_KINEMATICS], weights[SQRT_FORWARD], weights[SQRT_VELOCITY]
    sa, st = weights[SQRT_ACCELERATION], weights[SQRT_TIME]
    for j in range(segments):
        out[j] = sk * ((c[j] + c[j + 1]) * dy[j] - (s[j] + s[j + 1]) * dx[j])
        out[segments + j] = sf * _relu(-progress[j])
        out[2 * segments + j] = sv * _relu(v[j] - weights[V_MAX])
        out[3 * segments + j] = sv * _relu(abs(w[j]) - weights[W_MAX])
        out[4 * segments + j] = sa * _relu(abs(acc_v[j]) - weights[ACC_LIMIT_V])
        out[5 * segments + j] = sa * _relu(abs(acc_w[j]) - weights[ACC_LIMIT_W])
        out[6 * segments + j] = st * dts[j]
    row = 7 * segments
    for j in range(segments):
        for i in range(m):
            out[row + j * m + i] = weights[SQRT_OBSTACLE] * _relu(weights[MIN_OBSTACLE_DIST] - gaps[j, i])
    row += segments * m
    for j in range(segments):
        for i in range(m):
            out[row + j * m + i] = weights[SQRT_INFLATION] * _relu(weights[INFLATION_DIST] - gaps[j, i])
    return out


@numba.njit(cache=True, nogil=True)
def band_jacobian(
    segment_terms: np.ndarray,
    slot_terms: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
    dts: np.ndarray,
    weights: np.ndarray,
    flat: np.ndarray,
    shape: tuple[int, int],
) -> np.ndarray:
    """The Jacobian entries in the numpy version's order of terms, added at ``flat`` (``sims.ugv.teb._band_layout``)
    one after the other as np.add.at did, into a (rows, free + 1) matrix whose last column is cut off by the caller."""
    segments, m = slot_terms.shape[1], slot_terms.shape[2]
    dx, dy, progress, v, w = segment_terms[0], segment_terms[1], segment_terms[2], segment_terms[3], segment_terms[4]
    spans, acc_v, acc_w = segment_terms[5], segment_terms[6], segment_terms[7]
    ox, oy, gaps = slot_terms[0], slot_terms[1], slot_terms[2]
    k, sf, sv = weights[SQRT_KINEMATICS], weights[SQRT_FORWARD], weights[SQRT_VELOCITY]
    sa, st = weights[SQRT_ACCELERATION], weights[SQRT_TIME]
    so, si = weights[SQRT_OBSTACLE], weights[SQRT_INFLATION]
    dp = np.empty((segments, 5))  # d progress_j / d (x_j, x_j+1, y_j, y_j+1, th_j)
    gain_v, gain_w, dspan_own = np.empty(segments), np.empty(segments), np.empty(segments)
    for j in range(segments):
        dp[j, 0], dp[j, 1], dp[j, 2], dp[j, 3] = -c[j], c[j], -s[j], s[j]
        dp[j, 4] = -s[j] * dx[j] + c[j] * dy[j]
        gain_v[j] = sa * (1.0 if abs(acc_v[j]) > weights[ACC_LIMIT_V] else 0.0) * _sign(acc_v[j]) / spans[j]
        gain_w[j] = sa * (1.0 if abs(acc_w[j]) > weights[ACC_LIMIT_W] else 0.0) * _sign(acc_w[j]) / spans[j]
        dspan_own[j] = dts[j] if j == 0 else 0.5 * dts[j]
    if len(flat) != entries(segments, m):
        raise ValueError("band_jacobian: the layout does not fit the band")
    values = np.empty(len(flat))
    e = 0
    # non-holonomic kinematics
    for j in range(segments):
        values[e] = k * (s[j] + s[j + 1])
        values[e + segments] = -k * (s[j] + s[j + 1])
        values[e + 2 * segments] = -k * (c[j] + c[j + 1])
        values[e + 3 * segments] = k * (c[j] + c[j + 1])
        values[e + 4 * segments] = k * (-s[j] * dy[j] - c[j] * dx[j])
        values[e + 5 * segments] = k * (-s[j + 1] * dy[j] - c[j + 1] * dx[j])
        e += 1
    e += 5 * segments
    # forward driving
    for j in range(segments):
        forward = 1.0 if progress[j] < 0 else 0.0
        for q in range(5):
            values[e] = -sf * forward * dp[j, q]
            e += 1
    # speed limit
    for j in range(segments):
        speeding = 1.0 if v[j] > weights[V_MAX] else 0.0
        for q in range(5):
            values[e] = sv * speeding * dp[j, q] / dts[j]
            e += 1
    for j in range(segments):
        speeding = 1.0 if v[j] > weights[V_MAX] else 0.0
        values[e] = -sv * speeding * v[j]
        e += 1
    # yaw-rate limit
    for j in range(segments):
        turning = 1.0 if abs(w[j]) > weights[W_MAX] else 0.0
        values[e] = sv * turning * _sign(w[j]) / dts[j]
        values[e + segments] = -sv * turning * _sign(w[j]) / dts[j]
        values[e + 2 * segments] = -sv * turning * abs(w[j])
        e += 1
    e += 2 * segments
    # linear acceleration: through the progress of segments j and j - 1, then dt_j and dt_{j-1}
    for j in range(segments):
        for q in range(5):
            values[e] = gain_v[j] * (dp[j, q] / dts[j])
            e += 1
    for j in range(1, segments):
        for q in range(5):
            values[e] = -gain_v[j] * (dp[j - 1, q] / dts[j - 1])
            e += 1
    for j in range(segments):
        values[e] = gain_v[j] * (-v[j]) - gain_v[j] * acc_v[j] * dspan_own[j]
        e += 1
    for j in range(1, segments):
        values[e] = gain_v[j] * v[j - 1] - gain_v[j] * acc_v[j] * 0.5 * dts[j - 1]
        e += 1
    # angular acceleration, through the headings
    for j in range(segments):
        values[e] = gain_w[j] / dts[j]
        values[e + segments] = -(gain_w[j] / dts[j])
        e += 1
    e += segments
    for j in range(1, segments):
        values[e] = -(gain_w[j] / dts[j - 1])
        values[e + segments - 1] = gain_w[j] / dts[j - 1]
        e += 1
    e += segments - 1
    for j in range(segments):
        values[e] = gain_w[j] * (-w[j]) - gain_w[j] * acc_w[j] * dspan_own[j]
        e += 1
    for j in range(1, segments):
        values[e] = gain_w[j] * w[j - 1] - gain_w[j] * acc_w[j] * 0.5 * dts[j - 1]
        e += 1
    # time
    for j in range(segments):
        values[e] = st * dts[j]
        e += 1
    # obstacle clearance and inflation
    for weight, dist in ((so, weights[MIN_OBSTACLE_DIST]), (si, weights[INFLATION_DIST])):
        for axis in range(2):
            for j in range(segments):
                for i in range(m):
                    active = 1.0 if gaps[j, i] < dist else 0.0
                    unit = (ox[j, i] if axis == 0 else oy[j, i]) / gaps[j, i]
                    values[e] = -weight * active * unit
                    e += 1
    jacobian = np.zeros(shape)
    flat_view = jacobian.reshape(-1)
    for entry in range(len(flat)):
        flat_view[flat[entry]] += values[entry]
    return jacobian
