"""Plain-data scene description: what a simulator returns from ``scene()`` for the app to draw.

Everything is in world metres and radians, x east, y north, z up (the drawing is top-down 2D).
Colours are ``"#rrggbb"`` strings. A scene is a JSON-serialisable dict so that it can cross a
process boundary or be stored with a session.

``static`` changes only at reset (walls, road outlines); its ``static_key`` changes when it does,
so a viewer redraws static geometry only then. ``movers`` are the per-step moving objects
(obstacles, vehicles) and are meant to be drawn with batched meshes.
"""

from __future__ import annotations

from typing import Literal, NotRequired, TypedDict


class Box(TypedDict):
    kind: Literal["box"]
    x: float
    y: float
    yaw: float
    length: float  # along the heading
    width: float
    color: str
    label: NotRequired[str]


class Circle(TypedDict):
    kind: Literal["circle"]
    x: float
    y: float
    radius: float
    color: str
    label: NotRequired[str]


class Polyline(TypedDict):
    kind: Literal["polyline"]
    points: list[list[float]]  # [[x, y], ...]
    width: float
    color: str
    closed: NotRequired[bool]
    label: NotRequired[str]


class Polygon(TypedDict):
    kind: Literal["polygon"]
    points: list[list[float]]
    color: str
    label: NotRequired[str]


Shape = Box | Circle | Polyline | Polygon


class Rays(TypedDict):
    origin: list[float]  # [x, y]
    ends: list[list[float]]  # one [x, y] per ray, where it hit or its max range
    hit: list[bool]


class Scene(TypedDict):
    sim: str
    bounds: list[float]  # [xmin, ymin, xmax, ymax] of the interesting area, for the camera
    static_key: str  # changes whenever ``static`` changes
    static: list[Shape]
    movers: list[Shape]
    ego: Box
    goal: NotRequired[Circle | Box | None]
    rays: NotRequired[Rays | None]
    labels: NotRequired[dict[str, str]]  # small status texts, e.g. {"phase": "C2"}
