"""The vectorised lidar against pymunk's own segment queries, and on shapes with known answers."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pymunk
import pytest

import sims
from sims.ugv.config import LidarConfig
from sims.ugv.lidar import NumpyLidar, PymunkLidar, oriented_box_edges, ray_angles, two_sided
from sims.ugv.world import LIDAR_FILTER


@pytest.mark.parametrize("scenario", [1, 2, 3, 4])
def test_matches_pymunk_queries_along_random_drives(scenario: int) -> None:
    """Every ray of every step, movers included, agrees with segment_query_first to float32 precision."""
    env = sims.make("ugv", scenario=scenario)
    unwrapped = env.unwrapped
    rng = np.random.default_rng(scenario)
    checked = 0
    for episode in range(3):
        env.reset(seed=episode)
        reference = PymunkLidar(unwrapped.config.lidar, unwrapped.world.space, LIDAR_FILTER)
        for _ in range(60):
            _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2))
            x, y, yaw = unwrapped.world.pose
            ours = 1.0 / unwrapped.lidar.cast(x, y, yaw)
            theirs = 1.0 / reference.cast(x, y, yaw)
            np.testing.assert_allclose(ours, theirs, atol=1e-4)
            checked += 1
            if terminated or truncated:
                break
    assert checked >= 20


def test_boxes_circles_and_walls_from_many_poses() -> None:
    """Rotated boxes, circles and two-sided walls, seen from random poses, including near-grazing rays."""
    rng = np.random.default_rng(7)
    config = LidarConfig(rays_per_sector=3)
    space = pymunk.Space()
    segments = []
    for _ in range(6):
        x, y, yaw = rng.uniform(1, 9), rng.uniform(1, 9), rng.uniform(-math.pi, math.pi)
        length, width = rng.uniform(0.2, 1.5, 2)
        edges = oriented_box_edges(x, y, yaw, length, width)
        space.add(pymunk.Poly(space.static_body, [tuple(p) for p in edges[:, 0:2]]))
        segments.append(edges)
    walls = np.array([[0, 0, 10, 0], [10, 0, 10, 10], [10, 10, 0, 10], [0, 10, 0, 0], [4, 5, 6, 5.5]], float)
    for a0, a1, b0, b1 in walls:
        space.add(pymunk.Segment(space.static_body, (a0, a1), (b0, b1), 0))
    circles = np.column_stack([rng.uniform(1, 9, 5), rng.uniform(1, 9, 5), rng.uniform(0.1, 0.6, 5)])
    for cx, cy, r in circles:
        space.add(pymunk.Circle(space.static_body, r, (cx, cy)))
    lidar = NumpyLidar(config)
    lidar.set_static(np.vstack([two_sided(walls), *segments]), circles)
    reference = PymunkLidar(config, space, pymunk.ShapeFilter())
    tested = 0
    while tested < 150:
        x, y, yaw = rng.uniform(0.2, 9.8), rng.uniform(0.2, 9.8), rng.uniform(-math.pi, math.pi)
        if space.point_query_nearest((x, y), 0.0, pymunk.ShapeFilter()) is not None:
            continue  # inside an obstacle
        np.testing.assert_allclose(1.0 / lidar.cast(x, y, yaw), 1.0 / reference.cast(x, y, yaw), atol=1e-4)
        tested += 1


def test_a_pose_on_an_edges_line_sees_the_box_without_warnings() -> None:
    """The robot's centre exactly on the line of a box's edge (h = 0) divided by zero; now that edge is seen
    edge-on, as hiding nothing, and every ray still agrees with pymunk, with no floating-point warning."""
    config = LidarConfig()
    edges = oriented_box_edges(1.5, 0.5, 0.0, 1.0, 1.0)  # the box [1, 2] x [0, 1]: edges on y = 0 and x = 1
    space = pymunk.Space()
    space.add(pymunk.Poly(space.static_body, [tuple(p) for p in edges[:, 0:2]]))
    lidar = NumpyLidar(config)
    lidar.set_static(edges, np.zeros((0, 3)))
    reference = PymunkLidar(config, space, pymunk.ShapeFilter())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for pose in [(0.0, 0.0, 0.0), (0.0, 0.0, 0.3), (3.0, 1.0, math.pi), (1.0, 3.0, -1.2)]:
            ours = 1.0 / lidar.cast(*pose)
            assert np.all(np.isfinite(ours))
            np.testing.assert_allclose(ours, 1.0 / reference.cast(*pose), atol=1e-4)
    ahead = 1.0 / lidar.cast(0.0, 0.0, 0.0)
    assert ahead[np.argmin(np.abs(ray_angles(config)))] == pytest.approx(1.0)  # the corner (1, 0), 1 m ahead


def test_known_ranges_and_ray_order() -> None:
    """A wall 2 m ahead, a circle to the left, nothing behind: ranges by hand; sector 0 is the rightmost."""
    config = LidarConfig()
    lidar = NumpyLidar(config)
    wall = np.array([[2.0, -50.0, 2.0, 50.0]])  # the line x = 2
    lidar.set_static(two_sided(wall), np.array([[0.0, 3.0, 0.5]]))  # circle centred 3 m to the left
    ranges = 1.0 / lidar.cast(0.0, 0.0, 0.0)
    angles = ray_angles(config)
    assert angles[0] == pytest.approx(-math.radians(135))  # ray 0 of sector 0: the rightmost
    assert angles[54 + 53] == pytest.approx(math.radians(132.5))  # ray 1 of sector 53: the leftmost
    assert np.min(np.abs(angles)) == 0.0  # one ray straight ahead
    ahead = np.abs(angles) < math.radians(60)
    np.testing.assert_allclose(ranges[ahead], 2.0 / np.cos(angles[ahead]), rtol=1e-5)
    left = int(np.argmin(np.abs(angles - math.pi / 2)))
    phi = angles[left]
    expected = 3 * math.sin(phi) - math.sqrt(0.25 - (3 * math.cos(phi)) ** 2)  # ray vs circle by hand
    assert ranges[left] == pytest.approx(expected, abs=1e-4)
    behind_right = angles < math.radians(-100)
    assert np.all(ranges[behind_right] == pytest.approx(config.max_range))  # nothing there: max range


def test_moving_geometry_replaces_only_the_dynamic_rows() -> None:
    config = LidarConfig()
    lidar = NumpyLidar(config)
    lidar.set_static(two_sided(np.array([[5.0, -50, 5.0, 50]])), np.zeros((0, 3)), dynamic_segments=4)
    lidar.set_dynamic_segments(oriented_box_edges(2.0, 0.0, 0.0, 0.4, 1.0))
    angles = ray_angles(config)
    front = int(np.argmin(np.abs(angles)))  # straight ahead
    assert 1.0 / lidar.cast(0, 0, 0)[front] == pytest.approx(1.8 / math.cos(angles[front]), abs=1e-4)
    lidar.set_dynamic_segments(oriented_box_edges(3.0, 0.0, 0.0, 0.4, 1.0))
    assert 1.0 / lidar.cast(0, 0, 0)[front] == pytest.approx(2.8 / math.cos(angles[front]), abs=1e-4)
