"""What ``scene()`` returns for a highway world: plain data per ``core.scene``, never drawn here."""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from core.scene import Box, Polygon, Polyline, Scene, Shape
from sims.highway.road import RoadLayout, lane_outline
from sims.highway.world import World, road_geometry

ROAD = "#3a3d42"
EDGE = "#f2f2f2"
DIVIDER = "#9a9ea6"
TRAFFIC = {"normal": "#6c8ebf", "aggressive": "#d79b00", "defensive": "#82b366"}
ADVERSARY = "#d0312d"
YIELDING = "#9673a6"
EGO = "#1ba1e2"
VIEW_BEHIND, VIEW_AHEAD, VIEW_SIDE = 40.0, 80.0, 30.0


def _pts(a: np.ndarray) -> list[list[float]]:
    return np.round(np.asarray(a, dtype=float), 2).tolist()


@lru_cache(maxsize=32)
def static_shapes(layout: RoadLayout) -> tuple[Shape, ...]:
    """Road surface polygons, lane dividers and edges; the same for every episode on this layout."""
    geo = road_geometry(layout)
    shapes: list[Shape] = []
    for lane in geo.network.lanes_list():
        shapes.append(Polygon(kind="polygon", points=_pts(lane_outline(lane)), color=ROAD))
    for k in range(1, layout.lanes):
        y = float(layout.lane_y(k)) + 2.0
        shapes.append(
            Polyline(kind="polyline", points=[[0.0, y], [layout.length, y]], width=0.15, color=DIVIDER, label="divider")
        )
    if layout.kind == "merge":
        y = layout.right_edge_y
        shapes.append(
            Polyline(
                kind="polyline",
                points=[[layout.merge_start, y], [layout.merge_end, y]],
                width=0.15,
                color=DIVIDER,
                label="divider",
            )
        )
    for edge in geo.edges:
        shapes.append(Polyline(kind="polyline", points=_pts(edge), width=0.25, color=EDGE, label="edge"))
    return tuple(shapes)


def build_scene(world: World, static_key: str, labels: dict[str, str], rays: bool, behaviour: np.ndarray) -> Scene:
    tr = world.traffic
    ex, ey, eh, _ = world.ego_state
    near = np.abs(tr.x - ex) < 200.0
    names = ("normal", "aggressive", "defensive")
    movers: list[Shape] = []
    for i in np.flatnonzero(near):
        if tr.paths.adversarial[i]:
            color = ADVERSARY
        elif tr.yielding[i]:
            color = YIELDING
        else:
            color = TRAFFIC[names[int(behaviour[i])]] if i < len(behaviour) else TRAFFIC["normal"]
        movers.append(
            Box(
                kind="box",
                x=float(tr.x[i]),
                y=float(tr.y[i]),
                yaw=float(tr.heading[i]),
                length=float(tr.length[i]),
                width=float(tr.width[i]),
                color=color,
            )
        )
    ego = Box(
        kind="box",
        x=float(ex),
        y=float(ey),
        yaw=float(eh),
        length=world.cfg.ego.length,
        width=world.cfg.ego.width,
        color=EGO,
        label="ego",
    )
    lay = world.layout
    scene: dict[str, Any] = {
        "sim": "highway",
        "bounds": [
            float(ex - VIEW_BEHIND),
            float(min(ey, lay.right_edge_y) - VIEW_SIDE / 2),
            float(ex + VIEW_AHEAD),
            float(max(ey, lay.left_edge_y) + VIEW_SIDE / 2),
        ],
        "static_key": static_key,
        "static": list(static_shapes(lay)),
        "movers": movers,
        "ego": ego,
        "goal": Box(
            kind="box",
            x=float(world.route_end),
            y=float((lay.left_edge_y + lay.right_edge_y) / 2),
            yaw=0.0,
            length=1.0,
            width=float(lay.left_edge_y - lay.right_edge_y),
            color="#60a917",
            label="route end",
        ),
        "labels": labels,
    }
    if rays:
        ends = world.ray_ends()
        scene["rays"] = {"origin": [float(ex), float(ey)], "ends": _pts(ends), "hit": (world.lidar < 1.0).tolist()}
    return scene  # type: ignore[return-value]
