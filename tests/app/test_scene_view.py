"""Drawing plain-data scenes with viser: geometry helpers, batched movers, windows that follow the ego."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import viser

from app.scene_view import SceneDrawer, linear, rgb, triangulate
from tests.app.fakesim import ToyRobotEnv


def polygon_area(points: np.ndarray) -> float:
    return 0.5 * abs(float(np.sum(points[:, 0] * np.roll(points[:, 1], -1) - np.roll(points[:, 0], -1) * points[:, 1])))


@pytest.mark.parametrize("clockwise", [False, True])
def test_ear_clipping_covers_a_concave_polygon_exactly(clockwise: bool) -> None:
    ell = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], dtype=float)
    if clockwise:
        ell = ell[::-1]
    tris = triangulate(ell)
    assert tris.shape == (4, 3)
    covered = sum(polygon_area(ell[list(t)]) for t in tris)
    assert covered == pytest.approx(polygon_area(ell))
    centroids = ell[tris].mean(axis=1)
    assert not np.any((centroids[:, 0] > 1) & (centroids[:, 1] > 1)), "a triangle fills the notch"


def test_ear_clipping_handles_a_long_road_outline() -> None:
    x = np.linspace(0, 300, 700)
    left = np.stack([x, 6 + np.sin(x / 20)], axis=1)
    right = np.stack([x[::-1], -6 + np.sin(x[::-1] / 20)], axis=1)
    road = np.concatenate([left, right])
    tris = triangulate(road)
    assert len(tris) == len(road) - 2
    assert sum(polygon_area(road[list(t)]) for t in tris) == pytest.approx(polygon_area(road), rel=1e-9)


def test_colours() -> None:
    assert rgb("#ff8000") == (255, 128, 0) and rgb("#f80") == (255, 136, 0)
    assert rgb("nonsense") == (160, 160, 160) and rgb(None, (1, 2, 3)) == (1, 2, 3)
    assert linear((255, 255, 255)) == (255, 255, 255) and linear((0, 0, 0)) == (0, 0, 0)
    assert linear((128, 128, 128))[0] == 55  # mid-grey in sRGB is about a fifth of full light


@pytest.fixture
def server() -> Iterator[viser.ViserServer]:
    with contextlib.redirect_stdout(io.StringIO()):
        srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        yield srv
    finally:
        srv.stop()


def scene_with_movers(n: int, x0: float = 0.0) -> dict[str, Any]:
    env = ToyRobotEnv()
    env.reset(seed=0)
    scene = env.scene()
    scene["movers"] = [
        {"kind": "box", "x": x0 + i, "y": 0.5 * i, "yaw": 0.1 * i, "length": 4.0, "width": 2.0, "color": "#3366cc"}
        for i in range(n)
    ]
    return scene


def test_movers_are_one_batched_mesh_updated_in_place_and_rebuilt_when_their_number_changes(server) -> None:
    drawer = SceneDrawer(server)
    drawer.draw(scene_with_movers(50))
    batch = drawer._batches["boxes"]
    assert batch.batched_positions.shape == (50, 3)
    drawer.draw(scene_with_movers(50, x0=10.0))
    assert drawer._batches["boxes"] is batch, "same count: positions assigned, no new node"
    assert batch.batched_positions[0, 0] == pytest.approx(10.0)
    np.testing.assert_allclose(batch.batched_scales[0], [4.0, 2.0, 0.4 * np.sqrt(8.0)], rtol=1e-5)
    drawer.draw(scene_with_movers(7))
    assert drawer._batches["boxes"] is not batch and drawer._batches["boxes"].batched_positions.shape == (7, 3)
    drawer.draw(scene_with_movers(0))
    assert "boxes" not in drawer._batches and "circles" not in drawer._batches


def test_static_geometry_is_drawn_once_per_key_and_the_trail_restarts(server) -> None:
    drawer = SceneDrawer(server)
    scene = scene_with_movers(1)
    drawer.draw(scene)
    handles = list(drawer._static_handles)
    assert len(handles) >= 4  # ground, boxes, lines, polygons
    drawer.draw(scene)
    assert [id(h) for h in drawer._static_handles] == [id(h) for h in handles]
    assert len(drawer._trail_points) == 2
    drawer.draw({**scene, "static_key": "another"})
    assert not {id(h) for h in drawer._static_handles} & {id(h) for h in handles}
    assert len(drawer._trail_points) == 1
    assert len(drawer._rays.points) == len(scene["rays"]["ends"])


def test_a_window_around_the_ego_slides_the_world_not_the_camera(server) -> None:
    drawer = SceneDrawer(server)
    drawer.set_view("overview")
    scene = scene_with_movers(3)
    scene["bounds"] = [0.0, -20.0, 120.0, 20.0]
    drawer.draw(scene)
    assert drawer.origin == (60.0, 0.0)
    camera = tuple(server.initial_camera.position)
    drawer.draw({**scene, "bounds": [30.0, -20.0, 150.0, 20.0]})
    assert drawer.origin == (90.0, 0.0)
    assert tuple(drawer._origin_frame.position) == (-90.0, -0.0, 0.0)
    assert tuple(server.initial_camera.position) == camera


def test_the_follow_view_keeps_the_ego_centred_and_close_and_the_overview_is_one_switch_away(server) -> None:
    import math

    drawer = SceneDrawer(server)
    assert drawer.view == "follow"
    scene = scene_with_movers(2)
    scene["bounds"] = [0.0, -110.0, 220.0, 110.0]  # a SUMO-like window much larger than the ego
    length = float(scene["ego"].get("length", 1.0))
    drawer.draw(scene)
    ego = (float(scene["ego"]["x"]), float(scene["ego"]["y"]))
    assert drawer.origin == pytest.approx(ego)  # the ego is at the centre of the view
    close = math.dist(server.initial_camera.position, (0, 0, 0))
    moved = {**scene, "ego": {**scene["ego"], "x": ego[0] + 3.0}}
    drawer.draw(moved)
    assert drawer.origin == pytest.approx((ego[0] + 3.0, ego[1]))  # the world slides, the camera stays
    assert math.dist(server.initial_camera.position, (0, 0, 0)) == pytest.approx(close)
    drawer.set_view("overview")
    drawer.draw(moved)
    far = math.dist(server.initial_camera.position, (0, 0, 0))
    assert far > 3 * close and drawer.follow_window(scene["ego"])[2] - drawer.follow_window(scene["ego"])[0] == (
        pytest.approx(max(14.0 * length, 4.0))
    )
    with pytest.raises(ValueError, match="follow or overview"):
        drawer.set_view("sideways")


def test_a_road_narrower_than_the_follow_window_is_framed_by_its_width_and_closer(server) -> None:
    """The pedestrian crossing (a 12 m road, 93 m long) was framed as a 63 m square: the camera stood three times
    as far as the road needs and the pedestrian was a 4-pixel dot."""
    import math

    drawer = SceneDrawer(server)
    scene = scene_with_movers(1)
    scene["ego"] = {**scene["ego"], "x": 20.0, "y": 2.0, "length": 4.5}
    wide = {**scene, "bounds": [-5.0, -40.0, 88.0, 40.0], "static_key": "wide"}
    drawer.draw(wide)
    far = math.dist(server.initial_camera.position, (0, 0, 0))
    road = {**scene, "bounds": [-5.0, -3.6, 88.0, 8.0], "static_key": "road"}
    drawer.draw(road)
    x0, y0, x1, y1 = drawer.follow_window(road["ego"])
    assert y1 - y0 == pytest.approx(11.6) and x1 - x0 == pytest.approx(9 * 4.5)
    assert math.dist(server.initial_camera.position, (0, 0, 0)) < far / 2.5
