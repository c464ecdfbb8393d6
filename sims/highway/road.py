"""Road layouts built from highway-env's lane geometry, and a faster highway-env ``Road`` for logging.

Two layouts, both with a straight main road along +x (lane k centred at y = -k·w, lane 0 leftmost):

- ``highway``: 2-4 straight lanes.
- ``merge``: 2-3 main lanes and an on-ramp from the right (south) that becomes an acceleration lane
  between ``merge_start`` and ``merge_end`` and ends there (highway-env's merge-v0 geometry, mirrored so
  that it is on the driver's right in a y-up frame).

The main road stays straight in both, so the route coordinate is simply x; lanes are highway-env
``StraightLane``/``SineLane`` objects so that highway-env's IDM/MOBIL vehicles can drive them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, overload

import numpy as np
from highway_env.road.lane import AbstractLane, LineType, SineLane, StraightLane
from highway_env.road.road import LaneIndex, Road, RoadNetwork
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Landmark, Obstacle

LANE_WIDTH = StraightLane.DEFAULT_WIDTH
RAMP_OFFSET = 6.5
"""Lateral distance of the ramp's straight part from the acceleration lane [m] (as merge-v0)."""
RAMP_CONVERGE = 80.0
"""Length of the ramp's S-curve onto the acceleration lane [m] (as merge-v0)."""

Layout = Literal["highway", "merge"]


@dataclass(frozen=True)
class RoadLayout:
    kind: Layout = "highway"
    lanes: int = 3
    """Main-road lanes."""
    length: float = 3000.0
    speed_limit: float = 30.0
    merge_start: float = 400.0
    """x where the ramp joins as an acceleration lane (merge only)."""
    merge_end: float = 500.0
    """x where the acceleration lane ends (merge only)."""
    ramp_start: float = -150.0
    """x where the ramp's straight part starts (merge only)."""

    @overload
    def lane_y(self, lane: int | np.integer[Any]) -> float: ...
    @overload
    def lane_y(self, lane: np.ndarray) -> np.ndarray: ...
    def lane_y(self, lane: int | np.integer[Any] | np.ndarray) -> float | np.ndarray:
        """Centre line y of main-road lane ``lane``."""
        return -LANE_WIDTH * lane

    @property
    def left_edge_y(self) -> float:
        return LANE_WIDTH / 2

    @property
    def right_edge_y(self) -> float:
        """Right edge of the main road (the acceleration lane lies beyond it in the merge zone)."""
        return -LANE_WIDTH * (self.lanes - 1) - LANE_WIDTH / 2

    def lane_of(self, y: float | np.ndarray) -> np.ndarray:
        """Nearest main-road lane index for a lateral position (clipped to the main road)."""
        return np.clip(np.rint(-np.asarray(y) / LANE_WIDTH), 0, self.lanes - 1).astype(int)


def build_network(layout: RoadLayout) -> RoadNetwork:
    net = RoadNetwork()
    c, s, n = LineType.CONTINUOUS_LINE, LineType.STRIPED, LineType.NONE
    w = LANE_WIDTH
    if layout.kind == "highway":
        for k in range(layout.lanes):
            types = [c if k == 0 else s, c if k == layout.lanes - 1 else n]
            lane = StraightLane(
                [0.0, -k * w], [layout.length, -k * w], line_types=types, speed_limit=layout.speed_limit
            )
            net.add_lane("a", "b", lane)
        return net
    if layout.kind != "merge":
        raise ValueError(f"unknown road layout {layout.kind!r}; choose highway or merge")
    xb, xc = layout.merge_start, layout.merge_end
    for k in range(layout.lanes):
        y = -k * w
        last = k == layout.lanes - 1
        types = [c if k == 0 else s, c if last else n]
        types_merge = [c if k == 0 else s, s if last else n]
        for a, b, x0, x1, t in (
            ("a", "b", 0.0, xb, types),
            ("b", "c", xb, xc, types_merge),
            ("c", "d", xc, layout.length, types),
        ):
            net.add_lane(a, b, StraightLane([x0, y], [x1, y], line_types=t, speed_limit=layout.speed_limit))
    y_acc = -layout.lanes * w
    ramp_speed = min(layout.speed_limit, 25.0)
    x_curve = xb - RAMP_CONVERGE
    straight = StraightLane(
        [layout.ramp_start, y_acc - RAMP_OFFSET],
        [x_curve, y_acc - RAMP_OFFSET],
        line_types=[c, c],
        forbidden=True,
        speed_limit=ramp_speed,
    )
    amplitude = -RAMP_OFFSET / 2  # negative: the S-curve climbs from the ramp (south) up to the acceleration lane
    curve = SineLane(
        [x_curve, y_acc - RAMP_OFFSET / 2],
        [xb, y_acc - RAMP_OFFSET / 2],
        amplitude,
        np.pi / RAMP_CONVERGE,
        np.pi / 2,
        line_types=[c, c],
        forbidden=True,
        speed_limit=ramp_speed,
    )
    accel = StraightLane([xb, y_acc], [xc, y_acc], line_types=[n, c], forbidden=True, speed_limit=layout.speed_limit)
    net.add_lane("j", "k", straight)
    net.add_lane("k", "b", curve)
    net.add_lane("b", "c", accel)
    return net


def _offset_polyline(lane: AbstractLane, lateral: float, step: float = 2.0) -> np.ndarray:
    samples = 2 if type(lane) is StraightLane else max(2, int(np.ceil(lane.length / step)) + 1)
    s = np.linspace(0.0, lane.length, samples)
    return np.array([lane.position(si, lateral) for si in s])


def road_edges(layout: RoadLayout, network: RoadNetwork) -> list[np.ndarray]:
    """The drivable area's boundary as polylines (each an (n, 2) array): what the LiDAR sees as road."""
    w, length = LANE_WIDTH, layout.length
    left = np.array([[0.0, layout.left_edge_y], [length, layout.left_edge_y]])
    yr = layout.right_edge_y
    if layout.kind == "highway":
        return [left, np.array([[0.0, yr], [length, yr]])]
    xb, xc = layout.merge_start, layout.merge_end
    ramp = [network.get_lane(("j", "k", 0)), network.get_lane(("k", "b", 0))]
    ramp_left = np.vstack([_offset_polyline(lane, w / 2) for lane in ramp])
    ramp_right = np.vstack([_offset_polyline(lane, -w / 2) for lane in ramp])
    y_acc_right = -layout.lanes * w - w / 2
    accel_right = np.vstack([ramp_right, [[xc, y_acc_right], [xc, yr]]])
    return [
        left,
        np.array([[0.0, yr], [xb, yr]]),
        ramp_left,
        accel_right,
        np.array([[xc, yr], [length, yr]]),
    ]


def polyline_segments(polylines: list[np.ndarray]) -> np.ndarray:
    """(M, 4) array of segments [x0, y0, x1, y1] from a list of polylines."""
    return np.vstack([np.hstack([p[:-1], p[1:]]) for p in polylines]).astype(np.float64)


def lane_outline(lane: AbstractLane, step: float = 4.0) -> np.ndarray:
    """A closed polygon around one lane (for drawing the road surface)."""
    w = lane.width_at(0.0)
    left = _offset_polyline(lane, w / 2, step)
    right = _offset_polyline(lane, -w / 2, step)
    return np.vstack([left, right[::-1]])


def on_road(network: RoadNetwork, position: np.ndarray) -> bool:
    """highway-env's convention: the centre of the vehicle lies on some lane."""
    return any(lane.on_lane(position) for lane in network.lanes_list())


class FastRoad(Road):
    """highway-env's ``Road`` with a vectorised neighbour search during ``act()``.

    highway-env finds each vehicle's leader and follower by looping over every vehicle and projecting it
    on the lane (``Road.neighbour_vehicles``): O(N²) Python calls per step, 60% of a logging step. Here
    every vehicle's lane coordinates are computed once per lane per ``act()`` with numpy, and the same
    leader/follower (same tie rules) is picked from arrays. Outside ``act()`` and for lane types other
    than straight/sine lanes it defers to highway-env.
    """

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self._positions: np.ndarray | None = None
        self._lane_cache: dict[LaneIndex, tuple[np.ndarray, np.ndarray]] = {}
        self._index: dict[int, int] = {}

    def act(self) -> None:
        others = [o for o in self.objects if not isinstance(o, Landmark)]
        self._candidates = [*self.vehicles, *others]
        self._positions = np.array([v.position for v in self._candidates], dtype=float).reshape(-1, 2)
        self._index = {id(v): i for i, v in enumerate(self._candidates)}
        self._lane_cache = {}
        try:
            super().act()
        finally:
            self._positions = None

    def _lane_coordinates(self, lane_index: LaneIndex) -> tuple[np.ndarray, np.ndarray] | None:
        cached = self._lane_cache.get(lane_index)
        if cached is not None:
            return cached
        lane = self.network.get_lane(lane_index)
        if type(lane) not in (StraightLane, SineLane):
            return None
        assert self._positions is not None
        delta = self._positions - lane.start
        s = delta @ lane.direction
        r = delta @ lane.direction_lateral
        if isinstance(lane, SineLane):
            r = r - lane.amplitude * np.sin(lane.pulsation * s + lane.phase)
        on = (np.abs(r) <= lane.width / 2 + 1) & (s >= -lane.VEHICLE_LENGTH) & (s < lane.length + lane.VEHICLE_LENGTH)
        self._lane_cache[lane_index] = (s, on)
        return s, on

    def neighbour_vehicles(
        self, vehicle: Vehicle, lane_index: LaneIndex | None = None
    ) -> tuple[Vehicle | None, Vehicle | None]:
        if self._positions is None or self.neighbour_vehicles_connected_lanes:
            return super().neighbour_vehicles(vehicle, lane_index)
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        coords = self._lane_coordinates(lane_index)
        if coords is None:
            return super().neighbour_vehicles(vehicle, lane_index)
        s_all, on = coords
        s = self.network.get_lane(lane_index).local_coordinates(vehicle.position)[0]
        mask = on.copy()
        own = self._index.get(id(vehicle))
        if own is not None:
            mask[own] = False
        # highway-env keeps the last of equal fronts (<=) and the first of equal rears (>)
        front = np.flatnonzero(mask & (s_all >= s))
        rear = np.flatnonzero(mask & (s_all < s))
        v_front = v_rear = None
        if front.size:
            best = s_all[front].min()
            v_front = self._candidates[front[s_all[front] == best][-1]]
        if rear.size:
            best = s_all[rear].max()
            v_rear = self._candidates[rear[s_all[rear] == best][0]]
        return v_front, v_rear


def make_road(layout: RoadLayout, np_random: np.random.Generator, fast: bool = True) -> Road:
    network = build_network(layout)
    road = (FastRoad if fast else Road)(network=network, np_random=np_random)
    if layout.kind == "merge":
        # the acceleration lane ends in a barrier, as in merge-v0: IDM vehicles merge before it
        road.objects.append(Obstacle(road, [layout.merge_end, -layout.lanes * LANE_WIDTH]))
    return road
