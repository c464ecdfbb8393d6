"""What to draw for the SUMO study, as plain data (``core.scene``): the app draws it, the sim never does.

Static: every lane of the network as a polyline of its width and every junction as a polygon, read once per
network file with sumolib (cached; the static key changes when the network's content does). Movers: one box per
vehicle coloured by its type (special vehicles in their own colours, labelled) and one small circle per
signalised link at its stop line, coloured by the light's state.
"""

from __future__ import annotations

import functools
import hashlib
import math
from pathlib import Path
from typing import Any

from core.scene import Box, Circle, Polygon, Polyline, Shape
from sims.sumo import engine

libsumo = engine.libsumo

EGO_COLOR = "#00c850"
ROAD_COLOR = "#3c3f44"
JUNCTION_COLOR = "#44484e"
TYPE_COLORS = {
    "car": "#8fa0b4",
    "van": "#c8c8c8",
    "truck": "#8c6446",
    "moto": "#7846a0",
    "bus": "#f0be00",
    "firetruck": "#dc1e1e",
    "police": "#1e3cdc",
    "ambulance": "#f5f5f5",
}
SPECIAL_LABELS = {"bus": "bus", "firetruck": "fire truck", "police": "police", "ambulance": "ambulance"}
"""Special vehicles of phase C2, by base vehicle type."""
SIGNAL_COLORS = {"G": "#22cc44", "g": "#22cc44", "y": "#f0c000", "Y": "#f0c000", "r": "#e02020", "R": "#e02020"}


def base_type(type_id: str) -> str:
    """SUMO copies a type per vehicle when one is changed at run time (``car@flow.3``); the base is before ``@``."""
    return type_id.split("@", 1)[0]


def box(position: tuple[float, float], heading: float, length: float, width: float, color: str, label: str = "") -> Box:
    shape = Box(
        kind="box", x=float(position[0]), y=float(position[1]), yaw=float(heading), length=length, width=width,
        color=color,
    )  # fmt: skip
    if label:
        shape["label"] = label
    return shape


@functools.lru_cache(maxsize=4)
def _network(net_file: str) -> Any:
    import sumolib

    return sumolib.net.readNet(net_file, withInternal=False)


@functools.lru_cache(maxsize=4)
def static_shapes(net_file: str) -> tuple[str, list[Shape]]:
    """(static key, lane polylines and junction polygons) of a network file."""
    digest = hashlib.sha1(Path(net_file).read_bytes()).hexdigest()[:10]
    key = f"sumo:{Path(net_file).name.removesuffix('.xml').removesuffix('.net')}:{digest}"
    net = _network(net_file)
    shapes: list[Shape] = []
    for node in net.getNodes():
        outline = node.getShape()
        if len(outline) >= 3:
            shapes.append(Polygon(kind="polygon", points=[[float(x), float(y)] for x, y, *_ in outline],
                                  color=JUNCTION_COLOR))  # fmt: skip
    for edge in net.getEdges():
        for lane in edge.getLanes():
            points = [[float(x), float(y)] for x, y, *_ in lane.getShape()]
            shapes.append(Polyline(kind="polyline", points=points, width=float(lane.getWidth()), color=ROAD_COLOR))
    return key, shapes


@functools.lru_cache(maxsize=4)
def roundabout_entry_lanes(net_file: str) -> frozenset[str]:
    """Internal (junction) lanes that enter a roundabout from one of its arms."""
    import sumolib

    net = sumolib.net.readNet(net_file, withInternal=True)
    ring = {edge for roundabout in net.getRoundabouts() for edge in roundabout.getEdges()}
    entries: set[str] = set()
    for edge in net.getEdges(withInternal=False):
        if edge.getID() in ring:
            continue
        for lane in edge.getLanes():
            for conn in lane.getOutgoing():
                if conn.getTo().getID() in ring and conn.getViaLaneID():
                    entries.add(conn.getViaLaneID())
    return frozenset(entries)


@functools.lru_cache(maxsize=4)
def goal_marker(net_file: str, goal_edge: str) -> Circle:
    """A circle at the end of the goal edge (the off-ramp exit)."""
    lane = _network(net_file).getEdge(goal_edge).getLanes()[0]
    x, y, *_ = lane.getShape()[-1]
    return Circle(kind="circle", x=float(x), y=float(y), radius=4.0, color="#40a0ff", label="goal")


def vehicle_boxes(exclude: str = "") -> list[Shape]:
    """One box per vehicle in the running simulation (SUMO positions are front bumpers; boxes are centred)."""
    shapes: list[Shape] = []
    for vid in libsumo.vehicle.getIDList():
        if vid == exclude:
            continue
        kind = base_type(libsumo.vehicle.getTypeID(vid))
        length = libsumo.vehicle.getLength(vid)
        heading = math.radians(90.0 - libsumo.vehicle.getAngle(vid))
        fx, fy = libsumo.vehicle.getPosition(vid)
        centre = (fx - 0.5 * length * math.cos(heading), fy - 0.5 * length * math.sin(heading))
        color = TYPE_COLORS.get(kind, "#a0a0a0")
        shapes.append(box(centre, heading, length, libsumo.vehicle.getWidth(vid), color, SPECIAL_LABELS.get(kind, "")))
    return shapes


def signal_circles() -> list[Shape]:
    """A small circle per signalised link at the end of its incoming lane, coloured by the light's state."""
    shapes: list[Shape] = []
    for tls in libsumo.trafficlight.getIDList():
        state = libsumo.trafficlight.getRedYellowGreenState(tls)
        seen: dict[str, int] = {}
        for index, links in enumerate(libsumo.trafficlight.getControlledLinks(tls)):
            if not links or index >= len(state):
                continue
            incoming = links[0][0]
            shape = libsumo.lane.getShape(incoming)
            (x0, y0), (x1, y1) = shape[-2], shape[-1]
            heading = math.atan2(y1 - y0, x1 - x0)
            k = seen.get(incoming, 0)
            seen[incoming] = k + 1
            # spread the links of one lane along its stop line, so each stays visible
            offset = (k - 1) * 1.0
            x = x1 - offset * math.sin(heading)
            y = y1 + offset * math.cos(heading)
            color = SIGNAL_COLORS.get(state[index], "#808080")
            label = f"{tls}:{index}"
            shapes.append(Circle(kind="circle", x=float(x), y=float(y), radius=0.5, color=color, label=label))
    return shapes
