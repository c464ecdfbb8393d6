"""Vectorised geometry: vehicle boxes, ego collisions, the 72-beam LiDAR and interaction statistics."""

from __future__ import annotations

import numpy as np


def box_corners(x: np.ndarray, y: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """(N, 4, 2) corners of oriented boxes, counter-clockwise from front-left."""
    c, s = np.cos(heading), np.sin(heading)
    hl, hw = length / 2, width / 2
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    lx = local[None, :, 0] * hl[:, None]
    ly = local[None, :, 1] * hw[:, None]
    cx = x[:, None] + lx * c[:, None] - ly * s[:, None]
    cy = y[:, None] + lx * s[:, None] + ly * c[:, None]
    return np.stack([cx, cy], axis=-1)


def half_extents(length: np.ndarray, width: np.ndarray, heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes along x and y of the axis-aligned box around boxes turned by ``heading``."""
    c, s = np.abs(np.cos(heading)), np.abs(np.sin(heading))
    return length / 2 * c + width / 2 * s, length / 2 * s + width / 2 * c


def overlaps(ego_corners: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(N,) whether the ego box (4, 2) overlaps each box (N, 4, 2): separating-axis test."""
    if corners.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    e_axes = np.array([ego_corners[0] - ego_corners[1], ego_corners[0] - ego_corners[3]])  # (2, 2)
    o_axes = np.stack([corners[:, 0] - corners[:, 1], corners[:, 0] - corners[:, 3]], axis=1)  # (N, 2, 2)
    axes = np.concatenate([np.broadcast_to(e_axes, o_axes.shape), o_axes], axis=1)  # (N, 4, 2)
    pe = np.einsum("nad,kd->nak", axes, ego_corners)  # (N, 4 axes, 4 corners)
    po = np.einsum("nad,nkd->nak", axes, corners)
    separated = (pe.max(-1) < po.min(-1)) | (po.max(-1) < pe.min(-1))
    return ~separated.any(-1)


def ray_distances(origin: np.ndarray, angles: np.ndarray, segments: np.ndarray, max_range: float) -> np.ndarray:
    """Distance along each ray (angles in world frame) to the first segment [x0, y0, x1, y1] hit, or max_range."""
    if segments.shape[0] == 0:
        return np.full(angles.shape, max_range)
    d = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # (R, 2)
    a = segments[:, :2] - origin  # (S, 2)
    e = segments[:, 2:] - segments[:, :2]  # (S, 2)
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # cross(d, e)  (R, S)
    cross_ae = a[:, 0] * e[:, 1] - a[:, 1] * e[:, 0]  # (S,)
    cross_ad = a[None, :, 0] * d[:, None, 1] - a[None, :, 1] * d[:, None, 0]  # (R, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = cross_ae[None, :] / denom
        u = cross_ad / denom
    hit = (np.abs(denom) > 1e-12) & (t >= 0.0) & (u >= 0.0) & (u <= 1.0)
    t = np.where(hit, t, np.inf)
    return np.minimum(t.min(axis=1), max_range)


def box_segments(corners: np.ndarray) -> np.ndarray:
    """(4N, 4) edges of boxes (N, 4, 2)."""
    nxt = np.roll(corners, -1, axis=1)
    return np.concatenate([corners, nxt], axis=-1).reshape(-1, 4)


def segments_near(segments: np.ndarray, point: np.ndarray, radius: float) -> np.ndarray:
    """Segments whose bounding box comes within ``radius`` of ``point`` (a cheap pre-filter)."""
    lo = np.minimum(segments[:, :2], segments[:, 2:]) - radius
    hi = np.maximum(segments[:, :2], segments[:, 2:]) + radius
    keep = np.all((point >= lo) & (point <= hi), axis=1)
    return segments[keep]


def interaction_stats(
    ego: np.ndarray,
    ego_length: float,
    ego_width: float,
    x: np.ndarray,
    y: np.ndarray,
    heading: np.ndarray,
    speed: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    ttc_cap: float,
    gap_cap: float,
) -> tuple[float, float, float]:
    """Time to collision, gap to the nearest vehicle and gap to the leader, measured in the ego's frame.

    TTC: over vehicles overlapping the ego's lateral footprint (±0.3 m), bumper-to-bumper distance over
    closing speed, the smallest one; ``ttc_cap`` when nothing closes in. Gap: box-to-box distance to the
    nearest vehicle (axis-aligned in the ego frame). Lead gap: bumper-to-bumper distance to the nearest
    vehicle ahead in that footprint (the inter-vehicle spacing of car following). Gaps capped at ``gap_cap``.
    """
    if x.size == 0:
        return ttc_cap, gap_cap, gap_cap
    ex, ey, eh, ev = ego
    c, s = np.cos(eh), np.sin(eh)
    rx, ry = x - ex, y - ey
    dx = rx * c + ry * s
    dy = -rx * s + ry * c
    rel_h = heading - eh
    dvx = speed * np.cos(rel_h) - ev
    half_x, half_y = half_extents(length, width, rel_h)
    long_clear = np.abs(dx) - half_x - ego_length / 2
    lat_clear = np.abs(dy) - half_y - ego_width / 2
    gap = np.hypot(np.maximum(long_clear, 0.0), np.maximum(lat_clear, 0.0))
    in_band = lat_clear < 0.3
    closing = -np.sign(dx) * dvx
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(in_band & (closing > 1e-3), np.maximum(long_clear, 0.0) / closing, np.inf)
    lead = np.where(in_band & (dx > 0), np.maximum(long_clear, 0.0), np.inf)
    return float(min(ttc.min(), ttc_cap)), float(min(gap.min(), gap_cap)), float(min(lead.min(), gap_cap))
