"""Road layouts on highway-env lanes, and the vectorised neighbour search that speeds up logging."""

from __future__ import annotations

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

from sims.highway.road import FastRoad, RoadLayout, make_road, on_road, road_edges
from sims.highway.world import road_geometry


def _traffic(fast: bool, steps: int) -> np.ndarray:
    rng = np.random.default_rng(3)
    layout = RoadLayout(kind="merge", lanes=3, merge_start=250.0, merge_end=340.0)
    road = make_road(layout, rng, fast=fast)
    assert isinstance(road, FastRoad) == fast
    for i in range(16):
        lane = road.network.get_lane(("a", "b", int(rng.integers(3))))
        v = IDMVehicle(
            road,
            lane.position(40.0 + 14.0 * i, 0.0),
            speed=float(rng.uniform(18, 26)),
            target_speed=float(rng.uniform(20, 30)),
        )
        road.vehicles.append(v)
    ramp = road.network.get_lane(("j", "k", 0))
    for s in (20.0, 60.0, 100.0):
        road.vehicles.append(IDMVehicle(road, ramp.position(s, 0.0), speed=20.0, target_speed=25.0))
    out = []
    for _ in range(steps):
        road.act()
        road.step(0.2)
        out.append([(*v.position, v.heading, v.speed) for v in road.vehicles])
    return np.array(out)


def test_fast_road_drives_exactly_like_highway_env_road() -> None:
    """Same leaders and followers (same tie rules), so the same IDM/MOBIL traffic, merges included."""
    slow, fast = _traffic(False, 50), _traffic(True, 50)
    assert np.array_equal(slow, fast)
    lanes_changed = np.abs(np.diff(slow[:, :, 1], axis=0)).sum(axis=0) > 1.0
    assert lanes_changed.sum() >= 3  # the comparison covers lane changes and ramp merges, not just following


def test_merge_layout_edges_and_drivable_area() -> None:
    layout = RoadLayout(kind="merge", lanes=2, merge_start=300.0, merge_end=400.0)
    geo = road_geometry(layout)
    assert len(road_edges(layout, geo.network)) == 5
    net = geo.network
    assert on_road(net, np.array([100.0, -4.0]))  # main road, lane 1
    assert on_road(net, np.array([350.0, -8.0]))  # acceleration lane
    assert not on_road(net, np.array([100.0, -8.0]))  # between main road and ramp before the merge
    assert not on_road(net, np.array([100.0, 3.0]))  # left of lane 0
    ramp = net.get_lane(("k", "b", 0))
    assert np.allclose(ramp.position(ramp.length, 0.0), [300.0, -8.0])  # the ramp ends in the acceleration lane
    assert layout.lane_of(-3.2) == 1 and layout.lane_of(-8.0) == 1  # clipped to the main road
