"""The UGV env: gymnasium conformance, and the paper's observation, action, reward and cost definitions."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import sims
from core.protocol import simulator
from sims.ugv.env import UGVEnv
from tests.sims.ugv.conftest import room

STOP = np.array([-1.0, 0.0], np.float32)  # a0 = -1 is v = 0
FULL_AHEAD = np.array([1.0, 0.0], np.float32)


@pytest.mark.parametrize("scenario", [1, 4])
def test_passes_gymnasium_env_checker(scenario: int) -> None:
    env = gym.make("sage/UGV-v0", scenario=scenario)
    check_env(env.unwrapped, skip_render_check=True)
    simulator(env)  # offers expert_action, scene, metrics


def test_registered_and_built_by_short_name() -> None:
    env = sims.make("ugv", scenario="2")
    assert env.spec is not None and env.spec.id == "sage/UGV-v0"
    assert env.unwrapped.scenario.name == "detour"
    obs, info = env.reset(seed=0)
    assert obs.shape == (58,) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    assert env.action_space.shape == (2,)
    assert {"cost", "violation", "collision", "success", "timeout"} <= set(info)


def test_cost_is_0_6_at_0_7_m_facing_a_wall(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    """c = min(1, max(0, (1 - m) / 0.5)) with m = 0.7 m: 0.6. The lidar sits at the robot's centre."""
    path = write_scenario(room(start={"x": 3.3, "y": 2.0, "yaw_deg": 0}, goal={"x": 3.3, "y": 3.5, "radius": 0.3}))
    env = UGVEnv(path)
    obs, info = env.reset(seed=0)
    assert info["cost"] == pytest.approx(0.6, abs=1e-4)
    assert env.min_front_range() == pytest.approx(0.7, abs=1e-4)
    # sector 27 ([0°, 5°)) holds the ray straight ahead; sector 26 ([-5°, 0°)) its nearest at -2.5°
    assert obs[27] == pytest.approx(0.07, abs=1e-6)
    assert obs[26] == pytest.approx(0.07 / math.cos(math.radians(2.5)), abs=1e-6)
    # the leftmost sector's nearest ray (130°) meets the north wall, 2 m to the left
    assert obs[53] == pytest.approx(2.0 / math.sin(math.radians(130)) / 10, abs=1e-5)
    # goal 1.5 m straight to the left: distance 1.5 / D_max, heading error +pi/2 -> 0.5
    assert obs[54] == pytest.approx(0.15, abs=1e-6)
    assert obs[55] == pytest.approx(0.5, abs=1e-6)
    assert obs[56] == 0.0 and obs[57] == 0.0


def test_cost_is_zero_in_the_open_and_one_when_close(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    far = UGVEnv(write_scenario(room(start={"x": 1.0, "y": 2.0, "yaw_deg": 0}, bounds=[0, 0, 8, 4])))
    assert far.reset(seed=0)[1]["cost"] == 0.0
    near = UGVEnv(write_scenario(room(start={"x": 3.6, "y": 2.0, "yaw_deg": 0})))
    assert near.reset(seed=0)[1]["cost"] == 1.0


def test_previous_command_and_action_mapping(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    env = UGVEnv(write_scenario(room(bounds=[0, 0, 8, 8], start={"x": 4, "y": 4, "yaw_deg": 0})))
    env.reset(seed=0)
    obs, *_ = env.step(np.array([0.0, -0.5]))  # v = 0.3 m/s, w = -0.5 rad/s
    assert obs[56] == pytest.approx(0.5) and obs[57] == pytest.approx(-0.5)
    x0, y0, _ = env.world.pose
    env.step(STOP)
    x1, y1, _ = env.world.pose
    assert math.hypot(x1 - x0, y1 - y0) < 1e-12  # a0 = -1 is standing still
    obs, *_ = env.step(np.array([3.0, -7.0]))  # clipped to [-1, 1]
    assert obs[56] == pytest.approx(1.0) and obs[57] == pytest.approx(-1.0)


def test_unicycle_arc_is_exact(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    """v = 0.6, w = 1 for 1 s traces the arc of radius 0.6: the chord velocity makes the end pose exact."""
    env = UGVEnv(write_scenario(room(bounds=[0, 0, 8, 8], start={"x": 2, "y": 2, "yaw_deg": 0})))
    env.reset(seed=0)
    for _ in range(10):
        env.step(np.array([1.0, 1.0]))
    x, y, yaw = env.world.pose
    assert x == pytest.approx(2 + 0.6 * math.sin(1.0), abs=1e-9)
    assert y == pytest.approx(2 + 0.6 * (1 - math.cos(1.0)), abs=1e-9)
    assert yaw == pytest.approx(1.0, abs=1e-9)
    assert env.metrics()["path_curvature"] == pytest.approx(1 / 0.6, rel=1e-6)


def test_reward_terms_by_hand(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    env = UGVEnv(write_scenario(room(bounds=[0, 0, 8, 8], start={"x": 2, "y": 4, "yaw_deg": 0})))
    _, info = env.reset(seed=0)
    d0 = info["d_goal"]
    _, r1, *_, info = env.step(np.array([0.5, 0.4]))  # v = 0.45, w = 0.4
    d1 = info["d_goal"]
    assert r1 == pytest.approx(10 * (d0 - d1) + 0.5 * 0.45 - 0.5 * 0.4 - 0.2 * abs(0.4 - 0.0))
    _, r2, *_, info = env.step(np.array([-0.5, -0.6]))  # v = 0.15, w = -0.6
    assert r2 == pytest.approx(10 * (d1 - info["d_goal"]) + 0.5 * 0.15 - 0.5 * 0.6 - 0.2 * abs(-0.6 - 0.4))
    assert d1 < d0  # the goal is ahead


def test_collision_costs_100_and_is_a_violation(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    env = UGVEnv(write_scenario(room(start={"x": 3.3, "y": 2.0, "yaw_deg": 0}, goal={"x": 1, "y": 1, "radius": 0.3})))
    env.reset(seed=0)
    steps = 0
    for steps in range(1, 21):  # noqa: B007 (the count is the point)
        _, reward, terminated, truncated, info = env.step(FULL_AHEAD)
        if terminated:
            break
    # the bumper (0.25 m ahead of the centre) meets the wall after 0.45 m, in the 8th step at 0.6 m/s
    assert steps == 8
    assert info["collision"] and info["violation"] and not info["success"] and not truncated
    assert info["cost"] == 1.0
    d_before = math.hypot(3.3 + 0.06 * 7 - 1, 1.0)
    assert reward == pytest.approx(10 * (d_before - info["d_goal"]) + 0.5 * 0.6 - 100, abs=1e-6)
    assert env.metrics()["collision"] == 1.0 and env.metrics()["success"] == 0.0


def test_goal_gives_100_and_success(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    env = UGVEnv(
        write_scenario(room(start={"x": 1.0, "y": 2.0, "yaw_deg": 0}, goal={"x": 2.0, "y": 2.0, "radius": 0.3}))
    )
    env.reset(seed=0)
    total = 0.0
    for _ in range(20):
        _, reward, terminated, _, info = env.step(FULL_AHEAD)
        total += reward
        if terminated:
            break
    assert info["success"] and not info["collision"] and not info["violation"]
    assert reward > 100
    assert info["d_goal"] <= 0.3
    metrics = env.metrics()
    assert metrics["success"] == 1.0 and metrics["timeout"] == 0.0
    assert metrics["avg_speed"] == pytest.approx(0.6)


def test_truncates_at_the_time_limit(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    env = UGVEnv(write_scenario(room(time_limit=1.5)))
    env.reset(seed=0)
    steps = 0
    for steps in range(1, 20):  # noqa: B007 (the count is the point)
        _, _, terminated, truncated, info = env.step(STOP)
        if truncated:
            break
    assert steps == 15 and not terminated and info["timeout"]
    assert env.metrics()["timeout"] == 1.0
    shorter = sims.make("ugv", scenario=1, time_limit=0.5)  # a constructor argument beats the file's 60 s
    shorter.reset(seed=0)
    assert [shorter.step(STOP)[3] for _ in range(5)] == [False] * 4 + [True]


def test_a_mover_hitting_a_standing_robot_is_a_collision(write_scenario: Callable[[dict[str, Any]], Path]) -> None:
    mover = {"kind": "box", "path": [[2.0, 0.5], [2.0, 3.5]], "speed": 0.5, "length": 0.6, "width": 0.45}
    env = UGVEnv(write_scenario(room(start={"x": 2.0, "y": 2.5, "yaw_deg": 0}, movers=[mover])))
    env.reset(seed=0)
    for _ in range(60):
        _, reward, terminated, _, info = env.step(STOP)
        if terminated:
            break
    assert info["collision"] and reward < -99
    # it reaches the robot's side (y = 2.3) with its front (0.3 m ahead of its centre) after ~2.5 s
    assert env.world.time == pytest.approx((2.5 - 0.2 - 0.3 - 0.5) / 0.5, abs=0.11)


def test_seeded_episodes_repeat_exactly() -> None:
    def rollout(seed: int) -> list[np.ndarray]:
        env = sims.make("ugv", scenario=3)
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(0)
        out = [obs]
        for _ in range(40):
            obs, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2))
            out.append(np.append(obs, reward))
            if terminated or truncated:
                break
        return out

    first, again, other = rollout(5), rollout(5), rollout(6)
    assert len(first) == len(again)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], other[0])  # another seed draws another layout


def test_bad_actions_get_clear_errors() -> None:
    env = sims.make("ugv", scenario=1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="2 numbers"):
        env.step(np.array([0.1, 0.2, 0.3]))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([math.nan, 0.0]))
    with pytest.raises(ValueError, match=r"unknown UGV config field 'lidar\.rays': no 'rays' among backend"):
        sims.make("ugv", scenario=1, **{"lidar.rays": 3})
    with pytest.raises(ValueError, match="does not draw"):
        UGVEnv(1, render_mode="human")


def test_scene_is_plain_data_and_cheap_to_diff() -> None:
    env = sims.make("ugv", scenario=3)
    env.reset(seed=0)
    unwrapped = env.unwrapped
    first = unwrapped.scene()
    json.dumps(first)  # plain data
    assert first["sim"] == "ugv" and first["bounds"] == [0.0, 0.0, 9.0, 6.0]
    assert len(first["movers"]) == 1 and first["movers"][0]["kind"] == "box"
    assert len(first["rays"]["ends"]) == 108 and len(first["rays"]["hit"]) == 108
    x, y, yaw = unwrapped.world.pose
    assert (first["ego"]["x"], first["ego"]["y"], first["ego"]["yaw"]) == (x, y, yaw)
    assert first["goal"]["radius"] == 0.3
    kinds = {shape["kind"] for shape in first["static"]}
    assert kinds == {"polyline", "box", "circle"}
    env.step(FULL_AHEAD)
    second = unwrapped.scene()
    assert second["static"] is first["static"] and second["static_key"] == first["static_key"]
    assert second["movers"][0]["y"] != first["movers"][0]["y"] or second["ego"]["x"] != first["ego"]["x"]
    # every ray end is where the lidar says
    ends = np.array(second["rays"]["ends"])
    ranges = np.hypot(ends[:, 0] - second["rays"]["origin"][0], ends[:, 1] - second["rays"]["origin"][1])
    np.testing.assert_allclose(ranges, 1.0 / unwrapped.lidar.cast(*unwrapped.world.pose), rtol=1e-5)
    env.reset(seed=1)
    assert unwrapped.scene()["static_key"] != first["static_key"]


def test_the_scan_layout_takes_the_robots_own_turn_out_of_the_motion_input() -> None:
    """``scan_layout`` describes the UGV's observation: turning on the spot among static obstacles
    (scenario 2), the scan-aligned change of the lidar sectors is a fraction of the plain one, at full and half
    yaw rate either way (the first step after each change of rate excepted: the body's rate lags the command)."""
    from core.motion import ScanAlignment, motion_between
    from sims.ugv.env import scan_layout

    layout = scan_layout()
    env = gym.make("sage/UGV-v0", scenario=2)
    obs, _ = env.reset(seed=3)
    align = ScanAlignment.of(layout["scan_sectors"], layout["scan_turn_channel"], layout["scan_turn_sectors"], 58)
    assert align is not None and align.sectors == 54
    plain, aligned = [], []
    for w in (1.0, 0.5, -1.0, -0.5):
        obs, *_ = env.step(np.array([-1.0, w], np.float32))
        for _ in range(4):
            nxt, *_ = env.step(np.array([-1.0, w], np.float32))
            plain.append(np.abs(nxt[:54] - obs[:54]).mean())
            aligned.append(np.abs(motion_between(obs, nxt, align)[:54]).mean())
            obs = nxt
    assert min(plain) > 0.005
    assert np.mean(aligned) < 0.35 * np.mean(plain)
    assert max(a / p for a, p in zip(aligned, plain, strict=True)) < 0.8


def test_the_ego_motion_layout_predicts_the_next_scan_of_static_obstacles() -> None:
    """``ego_motion_layout`` describes the UGV's scan and action: driving arcs among static obstacles (scenario 2),
    the scan moved by each action predicts the next scan's sectors within 2 m to a fraction of their change, under
    half over each arc (the first step of one included: the command is the step's motion; measured 0.03-0.41) and
    under a quarter over the whole drive (0.12). Predicting no change errs by the change itself."""
    import torch

    from core.motion import EgoScanStep
    from core.sage.config import WorldModelConfig
    from sims.ugv.env import ego_motion_layout

    step = EgoScanStep.of(WorldModelConfig(**ego_motion_layout()), 58, 2)
    assert step is not None and step.sectors == 54
    env = gym.make("sage/UGV-v0", scenario=2)
    obs, _ = env.reset(seed=3)
    change, error = [], []
    for action in ([1.0, 0.0], [1.0, 0.8], [0.0, -1.0], [-1.0, 1.0], [0.5, 0.3], [1.0, -0.5]):
        a = np.array(action, np.float32)
        arc_change, arc_error = [], []
        for _ in range(6):
            nxt, _, terminated, truncated, _ = env.step(a)
            assert not (terminated or truncated)
            near = nxt[:54] < 0.2
            with torch.no_grad():
                moved = step.apply(torch.from_numpy(obs)[None], torch.from_numpy(a)[None])[0].numpy()
            arc_change.extend(np.abs(nxt[:54] - obs[:54])[near])
            arc_error.extend(np.abs(nxt[:54] - moved[:54])[near])
            obs = nxt
        assert len(arc_change) > 20
        assert np.mean(arc_error) < 0.5 * np.mean(arc_change), action
        change += arc_change
        error += arc_error
    assert np.mean(error) < 0.25 * np.mean(change)


@pytest.mark.parametrize(
    ("yaw_deg", "mover_side"),
    [(0, None), (90, None), (0, "left")],
)
def test_the_observation_shows_contact_where_the_simulator_registers_a_collision(
    write_scenario: Callable[[dict[str, Any]], Path], yaw_deg: float, mover_side: str | None
) -> None:
    """The descriptor's contact floors (fear's imagined contact) hold the simulator's own collision: driving into a
    wall head-on or along the other axis, or a mover hitting the robot's side, the observation of the colliding
    step has a sector at or under its floor, and none of the earlier ones has (a floor too high would call a close
    pass contact, one too low would miss the collision)."""
    floors = np.array(sims.descriptor("ugv").contact_floors)
    assert floors.shape == (54,)
    sectors = len(floors)
    # straight ahead is the bumper, 0.25 m; the rightmost and leftmost sectors (±135°) the body's corner region
    assert floors[sectors // 2] * 10.0 == pytest.approx(0.25, abs=0.01)
    assert floors.min() * 10.0 == pytest.approx(0.2, abs=0.01)
    if mover_side is None:
        start = {"x": 3.3, "y": 2.0, "yaw_deg": yaw_deg} if yaw_deg == 0 else {"x": 2.0, "y": 3.3, "yaw_deg": yaw_deg}
        env = UGVEnv(write_scenario(room(start=start, goal={"x": 1, "y": 1, "radius": 0.3})))
        action = FULL_AHEAD
    else:
        mover = {"kind": "box", "path": [[2.0, 3.5], [2.0, 0.5]], "speed": 0.5, "length": 0.6, "width": 0.45}
        env = UGVEnv(write_scenario(room(start={"x": 2.0, "y": 1.5, "yaw_deg": 0}, movers=[mover])))
        action = STOP
    obs, _ = env.reset(seed=0)
    touching = [bool((obs[:sectors] <= floors).any())]
    for _ in range(80):
        obs, _, terminated, _, info = env.step(action)
        touching.append(bool((obs[:sectors] <= floors).any()))
        if terminated:
            break
    assert info["collision"]
    assert touching[-1] and not any(touching[:-1])
