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

WEDGE_TOLERANCE = 0.0
"""Rays passing this close (m, across the ray) outside a segment's end still count as hits. Zero is
enough: two edges sharing a corner compute the same cross product with opposite signs, exactly, so
a ray through a corner always passes the wedge test of at least one of them."""


def ray_angles(config: LidarConfig) -> np.ndarray:
    """Ray angles relative to the heading (rad), evenly spaced from -fov/2 like a real scanner's beams
    (so one ray points straight ahead), in the caster's block order: index j * sectors + s is ray j of
    sector s, at -fov/2 + (s + j / k) * fov / sectors; sector 0 is the rightmost, the last the leftmost."""
    fov = math.radians(config.fov_deg)
    k, sectors = config.rays_per_sector, config.sectors
    sector_width = fov / sectors
    angles = np.empty(k * sectors)
    for j in range(k):
        angles[j * sectors : (j + 1) * sectors] = -fov / 2 + (np.arange(sectors) + j / k) * sector_width
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


def circle_table(circles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per circle (x, y, r): rows ``(c_x, c_y), (-c_y, c_x)`` as (C, 2, 2) float32, and r^2 as (C, 1)."""
    circles = np.asarray(circles, dtype=float).reshape(-1, 3)
    cx, cy, r = circles[:, 0], circles[:, 1], circles[:, 2]
    rows = np.stack([np.stack([cx, cy], axis=1), np.stack([-cy, cx], axis=1)], axis=1)
    return rows.astype(np.float32), (r**2)[:, None].astype(np.float32)


class NumpyLidar:
    """Vectorised ray caster over static geometry (set once per episode) and moving geometry (per step).

    ``set_static`` takes one-sided segments and circles and reserves rows for the moving ones, which
    ``set_dynamic_table`` / ``set_dynamic_circles`` replace at every step.

    Circles join the same matrix product with two rows each, giving for every ray the projection
    p = d . (c - o) and the perpendicular offset q = d x (c - o); the ray hits at
    t = p - sqrt(r^2 - q^2) when r^2 >= q^2 and t > 0 (NaN or negative otherwise, both ignored).
    A ray starting inside a circle does not see that circle (the robot would have collided already).
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
        circle_rows, radius2 = circle_table(circles)
        self._n_static_circles = len(circle_rows)
        self._circle_rows = np.concatenate([circle_rows, np.zeros((dynamic_circles, 2, 2), np.float32)])
        self._radius2 = np.concatenate([radius2, np.zeros((dynamic_circles, 1), np.float32)])
        k, c, n = len(self._table), len(self._circle_rows), self.n_rays
        self._k, self._c = k, c
        self._mt = np.zeros((3 * k + 2 * c, 2), np.float32)
        self._products = np.zeros((3 * k + 2 * c, n), np.float32)
        self._inverse = np.zeros((k + c, n), np.float32)
        self._tmp = np.zeros((max(k, c), n), np.float32)
        self._ok = np.zeros((k, n), bool)

    def set_dynamic_table(self, table: np.ndarray) -> None:
        """Replace the moving segments, given as rows of :func:`segment_table`."""
        self._table[self._n_static_segments :] = table

    def set_dynamic_segments(self, segments: np.ndarray) -> None:
        """Replace the moving segments, given as (Kd, 4) one-sided rows ax, ay, bx, by."""
        self.set_dynamic_table(segment_table(segments))

    def set_dynamic_circles(self, circles: np.ndarray) -> None:
        """Replace the moving circles, given as (Cd, 3) rows x, y, radius."""
        rows, radius2 = circle_table(circles)
        self._circle_rows[self._n_static_circles :] = rows
        self._radius2[self._n_static_circles :] = radius2

    def cast(self, x: float, y: float, yaw: float) -> np.ndarray:
        """Inverse ranges (1/m) of every ray, at least 1 / max_range (nothing hit); float32, block order."""
        c, s = math.cos(yaw), math.sin(yaw)
        dirs = np.array(((c, -s), (s, c)), np.float32) @ self._rel_dirs  # (2, n) world-frame directions
        # every offset the rows need, in one array: (-x, -y, 1) | perp(o), perp'(o) | o, perp(o)
        offsets = np.array((-x, -y, 1.0, -y, x, y, -x, x, y, -y, x), np.float32)
        k, n_circles = self._k, self._c
        mt = self._mt
        if k:
            table = self._table
            neg_h = table[:, 0:3] @ offsets[0:3]  # -(distance of o to each segment's line)
            mt3 = mt[: 3 * k].reshape(k, 3, 2)
            np.divide(table[:, 0:2], neg_h[:, None], out=mt3[:, 0])  # rows n / -h: inverse range along d
            np.subtract(table[:, 3:7].reshape(k, 2, 2), offsets[3:7].reshape(2, 2), out=mt3[:, 1:3])
        if n_circles:
            np.subtract(self._circle_rows, offsets[7:11].reshape(2, 2), out=mt[3 * k :].reshape(n_circles, 2, 2))
        products = self._products
        np.matmul(mt, dirs, out=products)
        inverse = self._inverse
        if k:
            p3 = products[: 3 * k].reshape(k, 3, -1)
            tmp = self._tmp[:k]
            np.minimum(p3[:, 1], p3[:, 2], out=tmp)  # inside the wedge iff both crosses are >= 0
            np.greater_equal(tmp, -WEDGE_TOLERANCE, out=self._ok)
            np.multiply(p3[:, 0], self._ok, out=inverse[:k])
        if n_circles:
            pc = products[3 * k :].reshape(n_circles, 2, -1)
            tmp = self._tmp[:n_circles]
            with np.errstate(invalid="ignore", divide="ignore"):
                np.multiply(pc[:, 1], pc[:, 1], out=tmp)
                np.subtract(self._radius2, tmp, out=tmp)
                np.sqrt(tmp, out=tmp)  # NaN where the ray misses
                np.subtract(pc[:, 0], tmp, out=tmp)
                np.reciprocal(tmp, out=inverse[k:])
        if not (k or n_circles):
            return np.full(self.n_rays, self._floor, np.float32)
        nearest = np.fmax.reduce(inverse, axis=0)  # fmax skips the NaNs of missed circles
        return np.fmax(nearest, self._floor, out=nearest)


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
