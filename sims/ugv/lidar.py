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


def footprint_ranges(config: LidarConfig, length: float, width: float) -> np.ndarray:
    """Per sector, the smallest distance from the scanner to the edge of a ``length`` x ``width`` box centred on it
    (the robot's body, heading along x) along any of the sector's rays (m). A sector reading at or under it has
    something at or inside the body, whichever ray the reading came from: the simulator's collision
    (``SimDescriptor.contact_floors``)."""
    angles = ray_angles(config).reshape(config.rays_per_sector, config.sectors)  # (ray j, sector s)
    cos, sin = np.abs(np.cos(angles)), np.abs(np.sin(angles))
    with np.errstate(divide="ignore"):
        edge = np.minimum(np.where(cos > 0, length / 2 / cos, np.inf), np.where(sin > 0, width / 2 / sin, np.inf))
    return edge.min(axis=0)


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
        # persistent buffers, and views into them made once here rather than at every cast
        self._rotation = np.zeros((2, 2), np.float32)
        self._dirs = np.zeros((2, n), np.float32)
        self._offsets = np.zeros(11, np.float32)  # (-x, -y, 1) | perp(o), perp'(o) | o, perp(o)
        self._neg_h = np.zeros(k, np.float32)
        mt = self._mt = np.zeros((3 * k + 2 * c, 2), np.float32)
        products = self._products = np.zeros((3 * k + 2 * c, n), np.float32)
        inverse = self._inverse = np.zeros((k + c, n), np.float32)
        tmp = np.zeros((max(k, c), n), np.float32)
        table = self._table
        mt3, p3 = mt[: 3 * k].reshape(k, 3, 2), products[: 3 * k].reshape(k, 3, n)
        pc = products[3 * k :].reshape(c, 2, n)
        self._views = {
            "table_h": table[:, 0:3],
            "table_n": table[:, 0:2],
            "table_ab": table[:, 3:7].reshape(k, 2, 2),
            "neg_h": self._neg_h[:, None],
            "offset_h": self._offsets[0:3],
            "offset_ab": self._offsets[3:7].reshape(2, 2),
            "offset_c": self._offsets[7:11].reshape(2, 2),
            "mt_n": mt3[:, 0],
            "mt_ab": mt3[:, 1:3],
            "mt_c": mt[3 * k :].reshape(c, 2, 2),
            "p_inverse": p3[:, 0],
            "p_a": p3[:, 1],
            "p_b": p3[:, 2],
            "p_along": pc[:, 0],
            "p_across": pc[:, 1],
            "inverse_segments": inverse[:k],
            "inverse_circles": inverse[k:],
            "tmp_segments": tmp[:k],
            "tmp_circles": tmp[:c],
            "ok": np.zeros((k, n), bool),
        }
        assert k == 0 or np.shares_memory(self._views["table_ab"], table)  # set_dynamic_table shows through

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
        k, n_circles, v = self._k, self._c, self._views
        if not (k or n_circles):
            return np.full(self.n_rays, self._floor, np.float32)
        c, s = math.cos(yaw), math.sin(yaw)
        rotation = self._rotation
        rotation[0, 0] = rotation[1, 1] = c
        rotation[0, 1], rotation[1, 0] = -s, s
        np.matmul(rotation, self._rel_dirs, out=self._dirs)  # (2, n) world-frame ray directions
        self._offsets[:] = (-x, -y, 1.0, -y, x, y, -x, x, y, -y, x)
        if k:
            np.matmul(v["table_h"], v["offset_h"], out=self._neg_h)  # -(distance from o to each line)
            edge_on = not self._neg_h.all()  # o on a segment's line (a pose on a crate's edge line, say)
            if edge_on:
                on_line = self._neg_h == 0.0
                self._neg_h[on_line] = 1.0
            np.divide(v["table_n"], v["neg_h"], out=v["mt_n"])  # rows n / -h: the inverse range along d
            if edge_on:
                v["mt_n"][on_line] = 0.0  # seen edge-on, a segment has no width to hit (a box's other edges do)
            np.subtract(v["table_ab"], v["offset_ab"], out=v["mt_ab"])  # perp(a - o), perp'(b - o)
        if n_circles:
            np.subtract(self._circle_rows, v["offset_c"], out=v["mt_c"])  # c - o, perp(c - o)
        np.matmul(self._mt, self._dirs, out=self._products)
        if k:
            tmp = v["tmp_segments"]
            np.minimum(v["p_a"], v["p_b"], out=tmp)  # inside the wedge iff both crosses are >= 0
            np.greater_equal(tmp, -WEDGE_TOLERANCE, out=v["ok"])
            np.multiply(v["p_inverse"], v["ok"], out=v["inverse_segments"])
        if n_circles:
            tmp = v["tmp_circles"]
            with np.errstate(invalid="ignore", divide="ignore"):
                np.multiply(v["p_across"], v["p_across"], out=tmp)
                np.subtract(self._radius2, tmp, out=tmp)
                np.sqrt(tmp, out=tmp)  # NaN where the ray misses
                np.subtract(v["p_along"], tmp, out=tmp)
                np.reciprocal(tmp, out=v["inverse_circles"])
        nearest = np.fmax.reduce(self._inverse, axis=0)  # fmax skips the NaNs of missed circles
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
