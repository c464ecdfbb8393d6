"""sage/Highway-v0: gymnasium conformance, the paper's observation, action, reward and cost, scene and metrics."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import sims
from core.experts import PolicyExpert, ScriptedExpert
from core.loop import Runner
from core.protocol import simulator
from sims.highway.config import DEFAULT
from sims.highway.env import OBS_SIZE, HighwayEnv
from sims.highway.traffic import Paths
from sims.highway.world import World

SID = 149  # light traffic, a straight 3-lane highway
COAST = np.array([0.0, 0.0], np.float32)


def _env(**kwargs: object) -> HighwayEnv:
    env = sims.make("highway", scenario_id=SID, **kwargs)
    return env.unwrapped  # type: ignore[return-value]


def _only(env: HighwayEnv, dx: float, dy: float, speed: float) -> None:
    """Replace the traffic by one vehicle at (dx, dy) from the ego, driving straight at ``speed``."""
    assert env.world is not None and env.log is not None
    ex, ey = env.world.ego.position
    frames = env.log.frames
    t = np.arange(frames) * env.log.dt
    state = np.zeros((frames, 1, 4))
    state[:, 0, 0] = ex + dx + speed * t
    state[:, 0, 1] = ey + dy
    state[:, 0, 3] = speed
    env.world = World(env.log, Paths(env.log.dt, state, np.array([5.0]), np.array([2.0])), env.cfg)


def test_passes_gymnasium_env_checker_and_offers_the_protocol() -> None:
    env = gym.make("sage/Highway-v0", scenario_id=SID, mode="adversarial")
    check_env(env.unwrapped, skip_render_check=True)
    simulator(env)
    obs, info = env.reset(seed=0)
    assert obs.shape == (OBS_SIZE,) == (83,) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    assert {"cost", "violation", "crashed", "offroad", "ttc", "gap", "nearest_gap"} <= set(info)


def test_observation_layout_kinematics_route_guidance_and_lidar() -> None:
    env = _env()
    env.reset(seed=0)
    _only(env, dx=20.0, dy=0.0, speed=env.world.ego.speed)  # type: ignore[union-attr]
    obs = np.asarray(env.step(COAST)[0])
    w = env.world
    assert w is not None
    assert obs[0] == pytest.approx(w.ego.speed / 40.0, abs=1e-5)
    assert obs[2] == pytest.approx(1.0, abs=1e-4)  # heading along the road
    # next checkpoint straight ahead on the ego's lane, at most 40 m away
    assert obs[6] == pytest.approx(0.0, abs=1e-3) and obs[7] == pytest.approx(1.0, abs=1e-4)
    assert 0.0 < obs[5] <= 0.5 and obs[8] == pytest.approx(obs[5] + 0.5, abs=1e-4)
    lidar = obs[11:]
    assert lidar.shape == (72,)
    # beam 0 points ahead: the vehicle's rear bumper 20 - 2.5 m ahead of the ego's centre
    assert lidar[0] * 50.0 == pytest.approx(17.5, abs=0.05)
    # beam 36 points back: nothing within 50 m
    assert lidar[36] == pytest.approx(1.0)
    # beams 18 and 54 (left and right) meet the road edges: lane 0 is 2 m wide to the left of its centre
    lane = int(w.layout.lane_of(w.ego.position[1]))
    left = w.layout.left_edge_y - w.ego.position[1]
    right = w.ego.position[1] - w.layout.right_edge_y
    assert lidar[18] * 50.0 == pytest.approx(left, abs=0.05) and lidar[54] * 50.0 == pytest.approx(right, abs=0.05)
    assert lane in range(w.layout.lanes)


def test_reward_is_progress_along_the_route_and_cost_zero_while_safe() -> None:
    env = _env()
    env.reset(seed=0)
    _only(env, dx=60.0, dy=0.0, speed=30.0)
    before = env.world.progress  # type: ignore[union-attr]
    _, reward, terminated, truncated, info = env.step(np.array([0.0, 1.0], np.float32))
    assert reward == pytest.approx(info["progress"] - before, abs=1e-9) and reward > 1.0
    assert info["cost"] == 0.0 and info["violation"] is False and not (terminated or truncated)


def test_crash_costs_one_rewards_minus_one_and_ends_the_episode() -> None:
    env = _env()
    env.reset(seed=0)
    _only(env, dx=6.0, dy=0.0, speed=0.0)  # a stopped car 1 m ahead of the bumper
    before = env.world.progress  # type: ignore[union-attr]
    _, reward, terminated, _, info = env.step(np.array([0.0, 1.0], np.float32))
    assert info["crashed"] and info["violation"] and info["cost"] == 1.0 and terminated
    assert reward == pytest.approx(info["progress"] - before - 1.0, abs=1e-9)
    m = env.metrics()
    assert m["collision"] == 1.0 and m["success"] == 0.0 and m["min_ttc"] == 0.0


def test_leaving_the_road_costs_one_rewards_minus_ten_and_ends_the_episode() -> None:
    env = _env()
    env.reset(seed=0)
    _only(env, dx=80.0, dy=0.0, speed=30.0)
    rewards, progress, info, terminated = [], [env.world.progress], {}, False  # type: ignore[union-attr]
    for _ in range(60):
        _, r, terminated, _, info = env.step(np.array([1.0, 0.0], np.float32))  # full left
        rewards.append(r)
        progress.append(info["progress"])
        if terminated:
            break
    assert terminated and info["offroad"] and info["cost"] == 1.0 and not info["crashed"]
    gained = np.diff(progress)
    assert rewards[-1] == pytest.approx(gained[-1] - 10.0, abs=1e-9)
    assert np.allclose(rewards[:-1], gained[:-1])
    assert env.metrics()["off_road"] == 1.0


def test_action_maps_to_physical_limits_and_bad_actions_are_named() -> None:
    env = _env()
    env.reset(seed=0)
    w = env.world
    assert w is not None
    assert w.map_action(np.array([1.0, 1.0])) == (DEFAULT.ego.max_steer, DEFAULT.ego.max_accel)
    assert w.map_action(np.array([-1.0, -1.0])) == (-DEFAULT.ego.max_steer, -DEFAULT.ego.max_brake)
    assert w.map_action(np.array([3.0, -0.5])) == (DEFAULT.ego.max_steer, -0.5 * DEFAULT.ego.max_brake)
    with pytest.raises(ValueError, match="two finite numbers"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="two finite numbers"):
        env.step(np.array([0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="unknown mode"):
        HighwayEnv(mode="hard")  # type: ignore[arg-type]


def test_scene_is_plain_data_with_a_static_key_per_scenario() -> None:
    env = _env()
    env.reset(seed=0)
    first = env.scene()
    for _ in range(5):
        env.step(COAST)
    later = env.scene()
    json.dumps(later)
    assert later["static_key"] == first["static_key"] and later["static"] == first["static"]
    assert later["ego"]["kind"] == "box" and later["ego"]["x"] > first["ego"]["x"]
    assert later["movers"] and all(m["kind"] == "box" for m in later["movers"])
    xmin, _, xmax, _ = later["bounds"]
    assert xmin < later["ego"]["x"] < xmax
    other = sims.make("highway", scenario_id=119, scene_rays=True).unwrapped
    other.reset(seed=0)
    with_rays = other.scene()
    assert with_rays["static_key"] != first["static_key"] and "rays" not in later
    rays = with_rays["rays"]
    assert len(rays["ends"]) == len(rays["hit"]) == 72 and any(rays["hit"])
    json.dumps(with_rays)


def test_metrics_of_an_expert_episode() -> None:
    env = sims.make("highway", scenario_id=SID)
    runner = Runner(env, _Constant(), expert=ScriptedExpert(), gate=_Always())
    summary = runner.run_episode()
    m = summary.metrics
    assert m["success"] == 1.0 and m["collision"] == 0.0 and m["timeout"] == 0.0
    assert summary.takeovers == summary.steps  # the expert drove every step
    assert 5.0 < m["speed_mean"] < 40.0 and m["speed_std"] >= 0.0
    assert m["acc_mean"] >= 0.0 and m["acc_std"] >= 0.0 and 0.0 < m["mean_gap"] <= 50.0
    assert m["progress"] >= 1.0


def test_a_trained_policy_can_be_the_expert() -> None:
    env = sims.make("highway", scenario_id=SID, mode="adversarial")
    runner = Runner(env, _Constant(0.0, -1.0), expert=PolicyExpert(_Constant(0.0, 0.3)), gate=_Always())
    record = runner.step()
    assert record is not None and record.actor == "expert" and record.takeover
    assert np.allclose(record.action, [0.0, 0.3]) and np.allclose(record.a_rl, [0.0, -1.0])


class _Constant:
    def __init__(self, steer: float = 0.0, acc: float = 0.0) -> None:
        self.action = np.array([steer, acc], np.float32)

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return self.action


class _Always:
    """A gate that always asks for the expert."""

    def reset(self) -> None:
        pass

    def decide(self, obs: np.ndarray, a_rl: np.ndarray):  # type: ignore[no-untyped-def]
        from core.loop import GateDecision

        return GateDecision(1.0, 0.0, True)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> float:
        return 0.0


@pytest.mark.parametrize(
    ("dx", "dy", "speed", "conflict"),
    [
        (60.0, 0.0, 30.0, False),  # a leader far ahead and pulling away
        (30.0, 0.0, 0.0, True),  # a stopped car 30 m ahead at 23 m/s: contact in about a second
        (0.0, 3.0, None, True),  # a car alongside at the ego's speed, 1 m between the bodies: no contact time
        (0.0, 4.5, None, False),  # the same one lane further over, 2.5 m between the bodies
    ],
)
def test_a_near_miss_is_a_conflict_with_no_cost(dx: float, dy: float, speed: float | None, conflict: bool) -> None:
    """info["conflict"]: time to contact under RewardConfig.conflict_ttc or a body within conflict_gap; a label for
    the world model, never a cost, a violation or the end of the episode."""
    env = _env()
    env.reset(seed=0)
    ego_speed = float(env.world.ego.speed)  # type: ignore[union-attr]
    _only(env, dx=dx, dy=dy, speed=ego_speed if speed is None else speed)
    _, _, terminated, _, info = env.step(COAST)
    assert info["conflict"] is conflict
    assert info["cost"] == 0.0 and info["violation"] is False and not terminated
    near = info["ttc"] < DEFAULT.reward.conflict_ttc or info["nearest_gap"] < DEFAULT.reward.conflict_gap
    assert near is conflict


def test_the_conflict_thresholds_come_from_the_config() -> None:
    """The same stopped car 30 m ahead is no conflict where the config asks for contact within half a second."""
    env = _env(**{"reward.conflict_ttc": 0.5})
    env.reset(seed=0)
    _only(env, dx=30.0, dy=0.0, speed=0.0)
    _, _, _, _, info = env.step(COAST)
    assert 0.5 < info["ttc"] < DEFAULT.reward.conflict_ttc and info["conflict"] is False
