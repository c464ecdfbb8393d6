"""Draws a simulator's plain-data scene (:mod:`core.scene`) with viser, for any simulator.

The simulator never draws; it returns boxes, circles, polylines and polygons in world metres, and this
module turns them into viser nodes: static geometry once per ``static_key``, movers as one batched mesh
per shape kind (one array assignment per frame however many objects there are), the ego, the goal, the
lidar rays and the ego's trail.

:class:`SceneView` runs the drawing in its own thread on the newest scene only, so the control loop
hands over a scene in microseconds and a slow frame is skipped rather than delaying a step.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import viser

log = logging.getLogger(__name__)

GROUND_Z = 0.0
TRAIL_POINTS = 600
FOLLOW_LENGTHS = 14.0
"""The follow view frames a square this many ego lengths wide around the ego (a car: ~60 m; the UGV: ~8 m)."""
ROAD_FOLLOW_LENGTHS = 9.0
"""... along a road narrower than that window (the pedestrian crossing: ~40 m, the ego and the pedestrian large)."""
FOLLOW_MIN = 4.0
"""... and at least this wide (m)."""
RAY_FREE = (38, 110, 130)
RAY_HIT = (214, 84, 104)
TRAIL_COLOR = (255, 200, 60)


def rgb(color: str | Sequence[int] | None, default: tuple[int, int, int] = (160, 160, 160)) -> tuple[int, int, int]:
    """``"#rrggbb"`` (or an RGB triple) to a tuple of ints; a malformed colour falls back to ``default``."""
    if isinstance(color, str):
        text = color.lstrip("#")
        if len(text) == 3:
            text = "".join(c * 2 for c in text)
        try:
            value = int(text, 16)
        except ValueError:
            return default
        return (value >> 16) & 255, (value >> 8) & 255, value & 255
    if isinstance(color, Sequence) and len(color) >= 3:
        return int(color[0]), int(color[1]), int(color[2])
    return default


def linear(color: tuple[int, int, int]) -> tuple[int, int, int]:
    """sRGB to linear 0-255: viser hands per-vertex and per-instance colours to three.js as linear values,
    so without this every ``#rrggbb`` of a batched mesh or a line would come out washed out."""

    def channel(c: int) -> int:
        x = c / 255.0
        y = x / 12.92 if x <= 0.04045 else ((x + 0.055) / 1.055) ** 2.4
        return round(255 * y)

    return channel(color[0]), channel(color[1]), channel(color[2])


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0)


def box_height(length: float, width: float) -> float:
    """A plausible height for a top-down box: a wall, a robot or a car looks like one."""
    return float(np.clip(0.4 * math.sqrt(max(length * width, 1e-6)), 0.15, 1.6))


def _unit_box() -> tuple[np.ndarray, np.ndarray]:
    """A 1 x 1 x 1 box standing on z = 0, centred in x and y."""
    v = np.array(
        [[x, y, z] for z in (0.0, 1.0) for y in (-0.5, 0.5) for x in (-0.5, 0.5)],
        dtype=np.float32,
    )
    f = np.array(
        [
            [0, 2, 1], [1, 2, 3],  # bottom
            [4, 5, 6], [5, 7, 6],  # top
            [0, 1, 4], [1, 5, 4],  # -y
            [2, 6, 3], [3, 6, 7],  # +y
            [0, 4, 2], [2, 4, 6],  # -x
            [1, 3, 5], [3, 7, 5],  # +x
        ],
        dtype=np.uint32,
    )  # fmt: skip
    return v, f


def _unit_cylinder(segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Radius 1, height 1, standing on z = 0."""
    angles = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    bottom = np.concatenate([ring, np.zeros((segments, 1))], axis=1)
    top = np.concatenate([ring, np.ones((segments, 1))], axis=1)
    verts = np.concatenate([bottom, top, [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]]).astype(np.float32)
    cb, ct = 2 * segments, 2 * segments + 1
    faces = []
    for i in range(segments):
        j = (i + 1) % segments
        faces += [[i, j, segments + i], [j, segments + j, segments + i], [cb, j, i], [ct, segments + i, segments + j]]
    return verts, np.array(faces, dtype=np.uint32)


BOX_MESH = _unit_box()
CYLINDER_MESH = _unit_cylinder()


def triangulate(points: np.ndarray) -> np.ndarray:
    """Ear-clipping triangulation of a simple polygon (either winding); returns (F, 3) vertex indices.

    The point-in-triangle test runs over all remaining corners at once (numpy), so road outlines with
    thousands of points triangulate in a fraction of a second.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n = len(pts)
    if n < 3:
        return np.zeros((0, 3), dtype=np.uint32)
    area = 0.5 * float(np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1]))
    ring = np.arange(n) if area > 0 else np.arange(n)[::-1].copy()
    triangles: list[tuple[int, int, int]] = []
    k, misses = 0, 0
    while len(ring) > 3 and misses < len(ring):
        m = len(ring)
        k %= m
        i0, i1, i2 = int(ring[k - 1]), int(ring[k]), int(ring[(k + 1) % m])
        a, b, c = pts[i0], pts[i1], pts[i2]
        convex = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) > 1e-12
        if convex:
            p = pts[ring]
            d1 = (b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])
            d2 = (c[0] - b[0]) * (p[:, 1] - b[1]) - (c[1] - b[1]) * (p[:, 0] - b[0])
            d3 = (a[0] - c[0]) * (p[:, 1] - c[1]) - (a[1] - c[1]) * (p[:, 0] - c[0])
            inside = (d1 >= 0) & (d2 >= 0) & (d3 >= 0)
            inside[[(k - 1) % m, k, (k + 1) % m]] = False
            if not inside.any():
                triangles.append((i0, i1, i2))
                ring = np.delete(ring, k)
                misses = 0
                continue
        k += 1
        misses += 1  # a full round without an ear: not a simple polygon, keep what was found
    if len(ring) == 3:
        triangles.append((int(ring[0]), int(ring[1]), int(ring[2])))
    return np.array(triangles, dtype=np.uint32).reshape(-1, 3)


def _segments(points: Sequence[Sequence[float]], closed: bool, z: float) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 2)
    if closed and len(pts) > 2:
        pts = np.concatenate([pts, pts[:1]])
    if len(pts) < 2:
        return np.zeros((0, 2, 3), dtype=np.float32)
    xyz = np.concatenate([pts, np.full((len(pts), 1), z, dtype=np.float32)], axis=1)
    return np.stack([xyz[:-1], xyz[1:]], axis=1)


class SceneDrawer:
    """Turns scene dicts into viser nodes. Call :meth:`draw` from one thread at a time."""

    def __init__(self, server: viser.ViserServer, root: str = "/world") -> None:
        self.server = server
        self.root = root
        self.static_key: str | None = None
        self._static_handles: list[Any] = []
        self._batches: dict[str, Any] = {}
        self._batch_sizes: dict[str, int] = {}
        self._ego: Any = None
        self._ego_nose: Any = None
        self._ego_shape: tuple[float, float] | None = None
        self._goal: Any = None
        self._goal_key: Any = None
        self._rays: Any = None
        self._mover_lines: Any = None
        self._trail: Any = None
        self._trail_points: list[tuple[float, float]] = []
        self.bounds: list[float] = [-5.0, -5.0, 5.0, 5.0]
        self.origin = (0.0, 0.0)
        """World point shown at the scene's origin: the centre of the simulator's bounds. Simulators whose
        bounds are a window around the ego (highway, SUMO) move it every frame, so the world slides under
        a still camera and every viewer keeps the view they orbited to."""
        self.view = "follow"
        """``follow``: the camera frames a window of ``FOLLOW_LENGTHS`` ego lengths around the ego and the world
        slides under it; ``overview``: the simulator's whole bounds (the operator toggles it with V)."""
        self._framed: tuple[str, float] | None = None
        self._origin_frame = server.scene.add_frame(root, show_axes=False)
        self._ground: Any = None
        self._cell = 1.0

    # -- entry point -----------------------------------------------------------------------------
    def draw(self, scene: dict[str, Any], static: dict[str, Any] | None = None, trail: bool = True) -> None:
        """Draw one frame. ``static`` supplies static geometry stored apart (replay)."""
        with self.server.atomic():
            source = static if static is not None else scene
            key = str(source.get("static_key", scene.get("static_key", "")))
            if key != self.static_key:
                self._draw_static(source.get("static") or [], source.get("bounds") or scene.get("bounds"))
                self.static_key = key
                self._trail_points = []
                self._framed = None
            elif self.view == "overview" and scene.get("bounds") and len(scene["bounds"]) == 4:
                self._follow([float(b) for b in scene["bounds"]])
            if scene.get("ego"):
                self._frame_view(scene["ego"])
            self._draw_movers(scene.get("movers") or [])
            ego = scene.get("ego")
            if ego:
                self._draw_ego(ego)
                if trail:
                    self._extend_trail(float(ego["x"]), float(ego["y"]))
            self._draw_goal(scene.get("goal"))
            self._draw_rays(scene.get("rays"))

    def reset_trail(self, points: Sequence[tuple[float, float]] = ()) -> None:
        self._trail_points = list(points)[-TRAIL_POINTS:]
        self._update_trail()

    # -- static ----------------------------------------------------------------------------------
    def _draw_static(self, shapes: list[dict[str, Any]], bounds: Sequence[float] | None) -> None:
        for handle in self._static_handles:
            handle.remove()
        self._static_handles = []
        scene = self.server.scene
        base = f"{self.root}/static"
        if bounds is not None and len(bounds) == 4:
            self.bounds = [float(b) for b in bounds]
        x0, y0, x1, y1 = self.bounds
        span = max(x1 - x0, y1 - y0, 1.0)
        cell = 10 ** math.floor(math.log10(span / 10.0))
        self._cell = cell
        self._ground = scene.add_grid(
            f"{base}/ground",
            width=(x1 - x0) + 2 * cell,
            height=(y1 - y0) + 2 * cell,
            position=((x0 + x1) / 2, (y0 + y1) / 2, GROUND_Z - 0.002),
            cell_size=cell,
            section_size=cell * 5,
            cell_color=(44, 52, 64),
            section_color=(70, 82, 100),
            plane_color=(22, 27, 34),
            plane_opacity=1.0,
            shadow_opacity=0.0,
        )
        self._static_handles.append(self._ground)
        boxes = [s for s in shapes if s.get("kind") == "box"]
        circles = [s for s in shapes if s.get("kind") == "circle"]
        if boxes:
            self._static_handles.append(self._batched(f"{base}/boxes", boxes, BOX_MESH, self._box_transforms))
        if circles:
            self._static_handles.append(
                self._batched(f"{base}/circles", circles, CYLINDER_MESH, self._circle_transforms)
            )
        by_width: dict[float, list[tuple[np.ndarray, tuple[int, int, int]]]] = {}
        for k, s in enumerate(shapes):
            if s.get("kind") == "polyline":
                seg = _segments(s.get("points", []), bool(s.get("closed", False)), 0.01 + 1e-4 * k)
                by_width.setdefault(round(float(s.get("width", 0.05)), 3), []).append((seg, rgb(s.get("color"))))
        for i, (width, items) in enumerate(sorted(by_width.items())):
            handle = self._lines(f"{base}/lines{i}", items, max(width, 0.02))
            if handle is not None:
                self._static_handles.append(handle)
        by_color: dict[tuple[int, int, int], list[np.ndarray]] = {}
        for s in shapes:
            if s.get("kind") == "polygon" and len(s.get("points", [])) >= 3:
                by_color.setdefault(rgb(s.get("color")), []).append(np.asarray(s["points"], dtype=np.float64))
        for i, (color, polygons) in enumerate(by_color.items()):
            verts, faces, offset = [], [], 0
            for poly in polygons:
                tris = triangulate(poly)
                verts.append(np.concatenate([poly, np.full((len(poly), 1), 0.004)], axis=1))
                faces.append(tris + offset)
                offset += len(poly)
            self._static_handles.append(
                scene.add_mesh_simple(
                    f"{base}/polygons{i}",
                    np.concatenate(verts).astype(np.float32),
                    np.concatenate(faces).astype(np.uint32),
                    color=color,
                    side="double",
                    cast_shadow=False,
                    receive_shadow=False,
                )
            )
        self._frame_camera()

    def set_view(self, view: str) -> None:
        """``follow`` or ``overview`` (see :attr:`view`); the camera is reframed at the next frame."""
        if view not in ("follow", "overview"):
            raise ValueError(f"unknown view {view!r}; choose follow or overview")
        self.view = view
        self._framed = None

    def follow_window(self, ego: dict[str, Any]) -> list[float]:
        """The window around the ego that the follow view frames: FOLLOW_LENGTHS ego lengths (at least
        FOLLOW_MIN m) each way, but no wider and no taller than the simulator's bounds. A road narrower than the
        window (the pedestrian crossing's 12 m) is framed by its own width and ROAD_FOLLOW_LENGTHS along it, not by
        empty space beside it (the camera stood three times as far, the pedestrian a 4-pixel dot)."""
        length = float(ego.get("length", 1.0))
        size = max(FOLLOW_LENGTHS * length, FOLLOW_MIN)
        world_height = max(self.bounds[3] - self.bounds[1], FOLLOW_MIN)
        along = max(ROAD_FOLLOW_LENGTHS * length, FOLLOW_MIN) if world_height < size else size
        width = min(along, max(self.bounds[2] - self.bounds[0], FOLLOW_MIN))
        height = min(size, world_height)
        x, y = float(ego["x"]), float(ego["y"])
        return [x - width / 2, y - height / 2, x + width / 2, y + height / 2]

    def _frame_view(self, ego: dict[str, Any]) -> None:
        """Follow: keep the ego at the origin (the world slides) and frame its window once per view and size."""
        if self.view == "overview":
            if self._framed != ("overview", 0.0):
                self._frame_camera()
                self._framed = ("overview", 0.0)
            return
        window = self.follow_window(ego)
        self._follow(window)
        size = round(max(window[2] - window[0], window[3] - window[1]), 3)
        if self._framed != ("follow", size):
            self._frame_camera(bounds=window, move_origin=False)
            self._framed = ("follow", size)

    def _frame_camera(
        self, aspect: float = 2.0, bounds: Sequence[float] | None = None, move_origin: bool = True
    ) -> None:
        """Look at ``bounds`` (default: the whole map) from above and slightly behind, framed for a wide view."""
        x0, y0, x1, y1 = self.bounds if bounds is None else bounds
        if move_origin:
            self._move_origin((x0 + x1) / 2, (y0 + y1) / 2, move_ground=False)
        half_height = max(y1 - y0, 1.0) / 2 * 1.3
        half_width = max(x1 - x0, 1.0) / 2 * 1.3
        distance = max(half_height, half_width / aspect) / math.tan(math.radians(75.0 / 2))
        tilt = math.radians(28.0)
        position = (0.0, -distance * math.sin(tilt), distance * math.cos(tilt))
        look_at = (0.0, 0.0, 0.0)
        self.server.initial_camera.position = position
        self.server.initial_camera.look_at = look_at
        self.server.initial_camera.up = (0.0, 0.0, 1.0)
        for client in self.server.get_clients().values():
            with contextlib.suppress(AssertionError):  # not reported its camera yet: starts from initial_camera
                client.camera.position = position
                client.camera.look_at = look_at

    def _move_origin(self, cx: float, cy: float, move_ground: bool = True) -> None:
        self.origin = (cx, cy)
        self._origin_frame.position = (-cx, -cy, 0.0)
        if move_ground and self._ground is not None:
            # keep the ground under the camera, on the grid's own lines so that they seem to scroll
            step = 5 * self._cell
            self._ground.position = (round(cx / step) * step, round(cy / step) * step, GROUND_Z - 0.002)

    def _follow(self, bounds: Sequence[float]) -> None:
        cx, cy = (bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2
        span = max(bounds[2] - bounds[0], bounds[3] - bounds[1], 1.0)
        if math.hypot(cx - self.origin[0], cy - self.origin[1]) >= 0.005 * span:
            self._move_origin(cx, cy)

    # -- dynamic ---------------------------------------------------------------------------------
    @staticmethod
    def _box_transforms(shapes: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n = len(shapes)
        pos = np.zeros((n, 3), np.float32)
        wxyz = np.zeros((n, 4), np.float32)
        scale = np.ones((n, 3), np.float32)
        colors = np.zeros((n, 3), np.uint8)
        for i, s in enumerate(shapes):
            length, width = float(s.get("length", 1.0)), float(s.get("width", 1.0))
            pos[i] = (float(s["x"]), float(s["y"]), GROUND_Z)
            wxyz[i] = yaw_quaternion(float(s.get("yaw", 0.0)))
            scale[i] = (length, width, box_height(length, width))
            colors[i] = linear(rgb(s.get("color")))
        return pos, wxyz, scale, colors

    @staticmethod
    def _circle_transforms(shapes: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n = len(shapes)
        pos = np.zeros((n, 3), np.float32)
        wxyz = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
        scale = np.ones((n, 3), np.float32)
        colors = np.zeros((n, 3), np.uint8)
        for i, s in enumerate(shapes):
            r = float(s.get("radius", 0.5))
            pos[i] = (float(s["x"]), float(s["y"]), GROUND_Z)
            scale[i] = (r, r, float(np.clip(0.8 * r, 0.15, 1.5)))
            colors[i] = linear(rgb(s.get("color")))
        return pos, wxyz, scale, colors

    def _batched(self, name: str, shapes: list[dict[str, Any]], mesh: Any, transforms: Any) -> Any:
        pos, wxyz, scale, colors = transforms(shapes)
        return self.server.scene.add_batched_meshes_simple(
            name,
            mesh[0],
            mesh[1],
            batched_wxyzs=wxyz,
            batched_positions=pos,
            batched_scales=scale,
            batched_colors=colors,
            lod="off",
            flat_shading=True,
        )

    def _draw_movers(self, movers: list[dict[str, Any]]) -> None:
        groups = {
            "boxes": ([m for m in movers if m.get("kind") == "box"], BOX_MESH, self._box_transforms),
            "circles": ([m for m in movers if m.get("kind") == "circle"], CYLINDER_MESH, self._circle_transforms),
        }
        for kind, (shapes, mesh, transforms) in groups.items():
            name = f"{self.root}/movers/{kind}"
            handle = self._batches.get(kind)
            if not shapes:
                if handle is not None:
                    handle.remove()
                    self._batches.pop(kind)
                continue
            if handle is None or self._batch_sizes.get(kind) != len(shapes):
                if handle is not None:
                    handle.remove()
                self._batches[kind] = self._batched(name, shapes, mesh, transforms)
                self._batch_sizes[kind] = len(shapes)
            else:
                pos, wxyz, scale, colors = transforms(shapes)
                handle.batched_positions = pos
                handle.batched_wxyzs = wxyz
                handle.batched_scales = scale
                handle.batched_colors = colors
        lines = [
            (
                _segments(m.get("points", []), bool(m.get("closed", m.get("kind") == "polygon")), 0.03),
                rgb(m.get("color")),
            )
            for m in movers
            if m.get("kind") in ("polyline", "polygon")
        ]
        if self._mover_lines is not None:
            self._mover_lines.remove()
            self._mover_lines = None
        if lines:
            self._mover_lines = self._lines(f"{self.root}/movers/lines", lines, 0.05)

    def _lines(self, name: str, items: list[tuple[np.ndarray, tuple[int, int, int]]], thickness: float) -> Any:
        segs = [seg for seg, _ in items if len(seg)]
        if not segs:
            return None
        points = np.concatenate(segs)
        colors = np.concatenate(
            [np.broadcast_to(np.array(linear(c), np.uint8), (len(seg), 2, 3)) for seg, c in items if len(seg)]
        )
        return self.server.scene.add_line_segments(name, points, colors, thickness=thickness)

    def _draw_ego(self, ego: dict[str, Any]) -> None:
        length, width = float(ego.get("length", 0.5)), float(ego.get("width", 0.4))
        if self._ego is None or self._ego_shape != (length, width):
            for handle in (self._ego, self._ego_nose):
                if handle is not None:
                    handle.remove()
            height = box_height(length, width)
            scene = self.server.scene
            self._ego = scene.add_frame(f"{self.root}/ego", show_axes=False)
            scene.add_box(
                f"{self.root}/ego/body",
                dimensions=(length, width, height),
                color=rgb(ego.get("color"), (80, 200, 120)),
                position=(0.0, 0.0, height / 2),
            )
            self._ego_nose = scene.add_box(
                f"{self.root}/ego/nose",
                dimensions=(0.25 * length, 0.5 * width, 0.2 * height),
                color=(255, 255, 255),
                position=(0.38 * length, 0.0, height + 0.1 * height),
            )
            self._ego_shape = (length, width)
        self._ego.position = (float(ego["x"]), float(ego["y"]), GROUND_Z)
        self._ego.wxyz = yaw_quaternion(float(ego.get("yaw", 0.0)))

    def _draw_goal(self, goal: dict[str, Any] | None) -> None:
        key = None if not goal else tuple(sorted((k, str(v)) for k, v in goal.items()))
        if key == self._goal_key:
            return
        if self._goal is not None:
            self._goal.remove()
            self._goal = None
        self._goal_key = key
        if not goal:
            return
        color = rgb(goal.get("color"), (255, 210, 64))
        name = f"{self.root}/goal"
        if goal.get("kind") == "box":
            length, width = float(goal.get("length", 1.0)), float(goal.get("width", 1.0))
            self._goal = self.server.scene.add_box(
                name,
                dimensions=(length, width, 0.02),
                color=color,
                opacity=0.55,
                position=(float(goal["x"]), float(goal["y"]), 0.01),
                wxyz=yaw_quaternion(float(goal.get("yaw", 0.0))),
            )
        else:
            r = float(goal.get("radius", 0.5))
            verts = CYLINDER_MESH[0] * np.array([r, r, 0.03], np.float32)
            self._goal = self.server.scene.add_mesh_simple(
                name,
                verts,
                CYLINDER_MESH[1],
                color=color,
                opacity=0.55,
                position=(float(goal["x"]), float(goal["y"]), 0.0),
                cast_shadow=False,
            )

    def _draw_rays(self, rays: dict[str, Any] | None) -> None:
        if not rays or not rays.get("ends"):
            if self._rays is not None:
                self._rays.remove()
                self._rays = None
            return
        origin = np.asarray(rays["origin"], dtype=np.float32).reshape(2)
        ends = np.asarray(rays["ends"], dtype=np.float32).reshape(-1, 2)
        n = len(ends)
        points = np.zeros((n, 2, 3), np.float32)
        points[:, 0, :2] = origin
        points[:, 1, :2] = ends
        points[:, :, 2] = 0.12
        hit = np.asarray(rays.get("hit") or [False] * n, dtype=bool).reshape(-1)[:n]
        # near hits glow red, far ones fade to the free-ray colour: the eye finds the danger at once
        dist = np.linalg.norm(ends - origin, axis=1)
        reach = float(dist.max()) if n else 1.0
        closeness = np.where(hit, np.clip(1.0 - dist / max(0.5 * reach, 1e-6), 0.0, 1.0), 0.0)[:, None]
        mixed = (1.0 - closeness) * np.array(linear(RAY_FREE)) + closeness * np.array(linear(RAY_HIT))
        colors = np.broadcast_to(mixed[:, None, :], (n, 2, 3)).astype(np.uint8)
        if self._rays is None or len(self._rays.points) != n:
            if self._rays is not None:
                self._rays.remove()
            self._rays = self.server.scene.add_line_segments(f"{self.root}/rays", points, colors, thickness=0.01)
        else:
            self._rays.points = points
            self._rays.colors = colors

    def _extend_trail(self, x: float, y: float) -> None:
        if self._trail_points and math.hypot(x - self._trail_points[-1][0], y - self._trail_points[-1][1]) > 5.0 * max(
            1.0, (self.bounds[2] - self.bounds[0]) / 10.0
        ):
            self._trail_points = []  # a jump (new episode) starts a new trail
        self._trail_points.append((x, y))
        del self._trail_points[:-TRAIL_POINTS]
        self._update_trail()

    def _update_trail(self) -> None:
        if len(self._trail_points) < 2:
            if self._trail is not None:
                self._trail.remove()
                self._trail = None
            return
        points = _segments(self._trail_points, False, 0.02)
        if self._trail is None:
            self._trail = self.server.scene.add_line_segments(
                f"{self.root}/trail", points, linear(TRAIL_COLOR), thickness=0.04
            )
        else:
            self._trail.points = points


class SceneView:
    """Draws the newest scene handed over by :meth:`show` in a background thread (coalescing frames)."""

    def __init__(self, server: viser.ViserServer, max_fps: float = 15.0) -> None:
        self.drawer = SceneDrawer(server)
        self.min_interval = 1.0 / max_fps
        """Each frame makes every viewer render; above the control rate that only costs the pages CPU."""
        self._lock = threading.Lock()
        self._pending: tuple[dict[str, Any], dict[str, Any] | None, bool] | None = None
        self._reset_trail: list[tuple[float, float]] | None = None
        self._wake = threading.Event()
        self._stop = False
        self.frames_drawn = 0
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="scene-view", daemon=True)
        self._thread.start()

    def show(self, scene: dict[str, Any], static: dict[str, Any] | None = None, trail: bool = True) -> None:
        with self._lock:
            self._pending = (scene, static, trail)
        self._wake.set()

    def reset_trail(self, points: Sequence[tuple[float, float]] = ()) -> None:
        with self._lock:
            self._reset_trail = list(points)
        self._wake.set()

    @property
    def view(self) -> str:
        return self.drawer.view

    def set_view(self, view: str) -> None:
        """``follow`` the ego or show the ``overview`` (a ValueError for anything else)."""
        with self._lock:
            self.drawer.set_view(view)
        self._wake.set()

    def close(self) -> None:
        self._stop = True
        self._wake.set()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        last = 0.0
        while not self._stop:
            self._wake.wait()
            self._wake.clear()
            wait = last + self.min_interval - time.monotonic()
            if wait > 0:
                time.sleep(wait)  # newer scenes replace the pending one meanwhile
            last = time.monotonic()
            with self._lock:
                pending, self._pending = self._pending, None
                reset, self._reset_trail = self._reset_trail, None
            try:
                if reset is not None:
                    self.drawer.reset_trail(reset)
                if pending is not None:
                    self.drawer.draw(*pending)
                    self.frames_drawn += 1
            except Exception:  # a malformed scene must not stop the drawing of the next one
                self.errors += 1
                log.exception("scene drawing failed")
