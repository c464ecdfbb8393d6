"""2D lidar: a vectorised numpy ray caster, and a reference one built on pymunk segment queries.

The numpy caster treats the world as *one-sided* segments (a box's edges facing outwards, each wall
twice, once per side) plus circles, and casts every ray against every shape in a handful of array
operations. For a segment a->b seen from its left side and a ray o + t d (|d| = 1):

- the ray lies in the wedge between the endpoints iff cross(a - o, d) >= 0 and cross(d, b - o) >= 0;
- then it hits the segment's line at t = h / (-n . d), with n the left unit normal and
  h = (o - a) . n > 0 the origin's distance to the line.

The three quantities are linear in d, so one ``(3K, 2) @ (2, rays)`` product gives them all, with
the inverse range -n/h folded into the matrix. Segments seen from behind give negative inverse
ranges or fail the wedge test, so no culling is needed; a max over shapes of the inverse range is
the nearest hit. Rays are stored sector-major in blocks (ray j of every sector, then ray j + 1), so
a sector's nearest range is an element-wise max of contiguous rows.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from sims.ugv.config import LidarConfig

WEDGE_TOLERANCE = 1e-5
"""Rays passing within this (m, across the ray) of a segment end still count as hits: no ray slips
between two edges meeting at a corner because of rounding."""


def ray_angles(config: LidarConfig) -> np.ndarray:
    """Ray angles relative to the heading (rad), in the caster's block order: index j * sectors + s is
    ray j of sector s; sector 0 is the rightmost (-fov/2), the last the leftmost."""
    fov = math.radians(config.fov_deg)
    k, sectors = config.rays_per_sector, config.sectors
    sector_width = fov / sectors
    angles = np.empty(k * sectors)
    for j in range(k):
        angles[j * sectors : (j + 1) * sectors] = -fov / 2 + (np.arange(sectors) + (j + 0.5) / k) * sector_width
    return angles


def oriented_box_edges(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    """(4, 4) rows ax, ay, bx, by of a box's edges, ordered clockwise so that the outside is on the left."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = length / 2, width / 2
    # corners clockwise: front-left, front-right, rear-right, rear-left (in the box frame)
    local = ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))
    corners = [(x + c * px - s * py, y + s * px + c * py) for px, py in local]
    return np.array([(*corners[i], *corners[(i + 1) % 4]) for i in range(4)])


def box_edges_batch(poses: np.ndarray, length: float, width: float) -> np.ndarray:
    """``oriented_box_edges`` for many poses at once: (n, 3) x, y, yaw -> (n, 4, 4)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    local = np.array(
        [(length / 2, width / 2), (length / 2, -width / 2), (-length / 2, -width / 2), (-length / 2, width / 2)]
    )
    cx = poses[:, 0:1] + c * local[:, 0] - s * local[:, 1]
    cy = poses[:, 1:2] + s * local[:, 0] + c * local[:, 1]
    nxt = [1, 2, 3, 0]
    return np.stack([cx, cy, cx[:, nxt], cy[:, nxt]], axis=2)


def two_sided(segments: np.ndarray) -> np.ndarray:
    """Both orientations of each (ax, ay, bx, by) row: a wall is seen from either side."""
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    return np.vstack([segments, segments[:, [2, 3, 0, 1]]])


def segment_table(segments: np.ndarray) -> np.ndarray:
    """Per one-sided segment, the constants the caster needs: (K, 7) float32 rows
    ``n_x, n_y, n . a, -a_y, a_x, b_y, -b_x`` (n the unit normal on the visible, left side)."""
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    a, b = seg[:, 0:2], seg[:, 2:4]
    e = b - a
    length = np.hypot(e[:, 0], e[:, 1])
    if np.any(length <= 0):
        raise ValueError("zero-length segment")
    n = np.stack([-e[:, 1], e[:, 0]], axis=1) / length[:, None]
    table = np.column_stack([n, (n * a).sum(axis=1), -a[:, 1], a[:, 0], b[:, 1], -b[:, 0]])
    return table.astype(np.float32)


class NumpyLidar:
    """Vectorised ray caster over static geometry (set once per episode) and moving geometry (per step).

    ``set_static`` takes one-sided segments and circles; ``set_dynamic`` replaces the moving part,
    whose row counts are fixed by ``dynamic_segments`` / ``dynamic_circles`` at ``set_static``.
    """

    def __init__(self, config: LidarConfig) -> None:
        self.config = config
        self.angles = ray_angles(config)
        self.n_rays = len(self.angles)
        self._rel_dirs = np.stack([np.cos(self.angles), np.sin(self.angles)]).astype(np.float32)  # (2, n)
        self._floor = np.float32(1.0 / config.max_range)
        self.set_static(np.zeros((0, 4)), np.zeros((0, 3)))

    def set_static(
        self,
        segments: np.ndarray,
        circles: np.ndarray,
        dynamic_segments: int = 0,
        dynamic_circles: int = 0,
    ) -> None:
        """``segments``: (K, 4) one-sided rows ax, ay, bx, by; ``circles``: (C, 3) rows x, y, radius."""
        static = segment_table(segments) if len(segments) else np.zeros((0, 7), np.float32)
        self._n_static_segments = len(static)
        self._table = np.vstack([static, np.zeros((dynamic_segments, 7), np.float32)])
        k = len(self._table)
        self._mt = np.zeros((3 * k, 2), np.float32)
        self._products = np.zeros((3 * k, self.n_rays), np.float32)
        self._ok = np.zeros((k, self.n_rays), bool)
        circles = np.asarray(circles, dtype=float).reshape(-1, 3)
        self._n_static_circles = len(circles)
        self._circles = np.vstack([circles, np.zeros((dynamic_circles, 3))]).astype(np.float32)

    def set_dynamic(self, segments: np.ndarray | None = None, circles: np.ndarray | None = None) -> None:
        """Replace the moving geometry: (Kd, 4) one-sided segments and (Cd, 3) circles."""
        if segments is not None and len(segments):
            self._table[self._n_static_segments :] = segment_table(segments)
        if circles is not None and len(circles):
            self._circles[self._n_static_circles :] = circles

    def set_dynamic_table(self, table: np.ndarray) -> None:
        """Like ``set_dynamic`` for segments already converted by :func:`segment_table` (cheaper per step)."""
        self._table[self._n_static_segments :] = table

    def cast(self, x: float, y: float, yaw: float) -> np.ndarray:
        """Inverse ranges (1/m) of every ray, at least 1 / max_range (nothing hit); float32, block order."""
        c, s = math.cos(yaw), math.sin(yaw)
        rel = self._rel_dirs
        dirs = np.array([[c, -s], [s, c]], np.float32) @ rel  # (2, n) world-frame unit directions
        best = np.full(self.n_rays, self._floor, np.float32)
        table = self._table
        k = len(table)
        if k:
            mt, products = self._mt, self._products
            h = table[:, 0] * np.float32(x) + table[:, 1] * np.float32(y) - table[:, 2]
            # rows of -n/h: the inverse range along d is (-n/h) . d
            np.divide(table[:, 0:2], -h[:, None], out=mt[:k])
            np.subtract(table[:, 3:5], np.array([-y, x], np.float32), out=mt[k : 2 * k])
            np.subtract(table[:, 5:7], np.array([y, -x], np.float32), out=mt[2 * k :])
            np.matmul(mt, dirs, out=products)
            ok = np.greater_equal(np.minimum(products[k : 2 * k], products[2 * k :]), -WEDGE_TOLERANCE, out=self._ok)
            inverse = products[:k]
            np.multiply(inverse, ok, out=inverse)
            np.maximum(best, inverse.max(axis=0), out=best)
        if len(self._circles):
            circ = self._circles
            w = circ[:, 0:2] - np.array([x, y], np.float32)
            proj = w @ dirs  # (C, n): d . (c - o)
            c2 = (w * w).sum(axis=1) - circ[:, 2] ** 2  # |c - o|^2 - r^2, > 0 outside the circle
            disc = proj * proj - c2[:, None]
            # nearest hit t = c2 / (proj + sqrt(disc)), so 1/t = (proj + sqrt(disc)) / c2
            inverse_c = (np.sqrt(np.maximum(disc, 0)) + proj) / np.maximum(c2, 1e-12)[:, None]
            inverse_c *= (disc >= 0) & (proj > 0)
            if np.any(c2 <= 0):  # the origin is inside a circle: everything reads range 0
                inverse_c[c2 <= 0] = np.float32(1e9)
            np.maximum(best, inverse_c.max(axis=0), out=best)
        return best


class PymunkLidar:
    """The reference caster: one ``Space.segment_query_first`` per ray (slow, simple, exact)."""

    def __init__(self, config: LidarConfig, space: pymunk.Space, shape_filter: pymunk.ShapeFilter) -> None:
        self.config = config
        self.angles = ray_angles(config)
        self.n_rays = len(self.angles)
        self.space = space
        self.filter = shape_filter

    def cast(self, x: float, y: float, yaw: float) -> np.ndarray:
        max_range = self.config.max_range
        out = np.empty(self.n_rays, np.float32)
        query = self.space.segment_query_first
        for i, angle in enumerate(self.angles):
            heading = yaw + float(angle)
            end = (x + max_range * math.cos(heading), y + max_range * math.sin(heading))
            hit = query((x, y), end, 0.0, self.filter)
            out[i] = 1.0 / max(hit.alpha * max_range, 1e-9) if hit is not None else 1.0 / max_range
        return np.maximum(out, np.float32(1.0 / max_range))


def sector_inverse(inverse: np.ndarray, sectors: int) -> np.ndarray:
    """Per sector, the largest inverse range (= nearest hit) over its rays."""
    return inverse.reshape(-1, sectors).max(axis=0)
