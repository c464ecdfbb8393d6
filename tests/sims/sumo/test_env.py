"""The in-process SUMO env: observation, costs detected from SUMO, the SUMO expert, scenarios, errors."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import sims
from core.experts import ExpertPolicy
from core.loop import Runner, StepRecord
from sims.sumo import SumoEnv, SumoError
from sims.sumo.env import EGO, OBS_SIZE, libsumo
from sims.sumo.scene import SPECIAL_LABELS

MakeEnv = Callable[..., SumoEnv]


def _hold(env: SumoEnv, speed: float) -> np.ndarray:
    """An agent action that drives towards ``speed`` (a plain P-controller, not SUMO's model)."""
    v = libsumo.vehicle.getSpeed(EGO)
    return np.array([np.clip((speed - v) / 3.0, -1.0, 1.0)], np.float32)


def test_observation_has_29_bounded_values_and_sees_the_traffic(make_env: MakeEnv) -> None:
    env = make_env(route=1)
    obs, info = env.reset(seed=0)
    assert obs.shape == (OBS_SIZE,) == (29,) and obs.dtype == np.float32
    rng = np.random.default_rng(0)
    seen_sector = np.zeros(6, bool)
    nav = [obs[28]]
    for _ in range(80):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-0.2, 1.0, 1).astype(np.float32))
        assert env.observation_space.contains(obs)
        assert math.isfinite(reward) and {"cost", "violation", "collision", "red_light"} <= set(info)
        seen_sector |= obs[0:24:4] < 1.0
        nav.append(obs[28])
        if terminated or truncated:
            break
    assert seen_sector.any(), "no neighbour was seen in 80 steps of route 1's traffic"
    assert nav[-1] < nav[0], "the distance to the goal did not shrink while driving"


def test_front_sector_and_traffic_light_features(make_env: MakeEnv) -> None:
    env = make_env(route=1, traffic_scale=0.0)  # the ego alone, plus one parked truck
    obs, _ = env.reset(seed=0)
    assert np.allclose(obs[:24].reshape(6, 4), [1.0, 0.0, 0.0, 0.0])  # every sector empty
    pos = libsumo.vehicle.getLanePosition(EGO)
    libsumo.vehicle.add("truck0", "ego_r1", typeID="truck", depart="now", departPos=str(pos + 80.0), departSpeed="0")
    libsumo.vehicle.setSpeedMode("truck0", 0)
    libsumo.vehicle.setSpeed("truck0", 0.0)
    obs, *_ = env.step(np.array([0.5], np.float32))
    obs, *_ = env.step(np.array([0.5], np.float32))
    distance, heading, rel_speed, rel_direction = obs[0:4]
    assert 0.3 < distance < 0.5  # about 80 m ahead (centre to centre) of 200 m
    assert abs(heading) < 0.05  # same direction
    assert rel_speed < 0.0  # the ego is faster than the parked truck
    assert abs(abs(rel_direction) - 1.0) < 0.05  # relative velocity points back at the ego: closing in
    assert np.allclose(obs[4:24].reshape(5, 4), [1.0, 0.0, 0.0, 0.0])
    assert obs[24] > 0.0  # ego speed
    assert obs[26] == 1.0  # s1 is more than 200 m away


def test_collision_detected_from_sumo_ends_the_episode_with_cost(make_env: MakeEnv) -> None:
    env = make_env(route=1, traffic_scale=0.0)
    env.reset(seed=0)
    pos = libsumo.vehicle.getLanePosition(EGO)
    libsumo.vehicle.add("truck0", "ego_r1", typeID="truck", depart="now", departPos=str(pos + 60.0), departSpeed="0")
    libsumo.vehicle.setSpeedMode("truck0", 0)
    libsumo.vehicle.setSpeed("truck0", 0.0)
    costs = []
    for _ in range(60):
        _, reward, terminated, truncated, info = env.step(np.ones(1, np.float32))
        costs.append(info["cost"])
        if terminated or truncated:
            break
    assert terminated and not truncated
    assert info["collision"] and info["violation"] and info["cost"] == 1.0 and not info["red_light"]
    assert costs.count(1.0) == 1  # nothing before the impact
    assert reward == pytest.approx(info["speed"] / 5.0 - math.log1p(1.0 - info["route_progress"]) - 1.0 - 1.0, abs=1e-6)
    m = env.metrics()
    assert (m["collision"], m["success"], m["red_light"], m["timeout"]) == (1.0, 0.0, 0.0, 0.0)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, np.float32))


def test_red_light_run_is_detected_and_the_expert_stops_for_it(make_env: MakeEnv) -> None:
    env = make_env(route=1, traffic_scale=0.0)
    # the agent, speed checks off, at 10 m/s through s1 held red
    env.reset(seed=0)
    libsumo.trafficlight.setRedYellowGreenState("s1", "r" * 9)
    flagged = []
    for t in range(300):
        _, _, terminated, _, info = env.step(_hold(env, 10.0))
        if info["red_light"]:
            flagged.append((t, libsumo.vehicle.getLaneID(EGO), info["cost"], terminated))
        if libsumo.vehicle.getRoadID(EGO) == "s1_to_ramp1":
            break
    assert len(flagged) == 1, flagged
    _, lane, cost, terminated = flagged[0]
    assert lane.startswith(":s1_") and cost == 1.0 and not terminated  # crossing the stop line, not the end
    assert env.metrics()["red_light"] == 1.0

    # the same drive on green is not flagged
    env.reset(seed=0)
    libsumo.trafficlight.setRedYellowGreenState("s1", "G" * 9)
    for _ in range(300):
        _, _, _, _, info = env.step(_hold(env, 10.0))
        assert not info["red_light"]
        if libsumo.vehicle.getRoadID(EGO) == "s1_to_ramp1":
            break
    assert libsumo.vehicle.getRoadID(EGO) == "s1_to_ramp1"

    # SUMO's own model (the expert) waits at the red light, then goes on green
    obs, _ = env.reset(seed=0)
    libsumo.trafficlight.setRedYellowGreenState("s1", "r" * 9)
    for _ in range(160):
        obs, _, _, _, info = env.step(env.expert_action())
        assert info["expert_drove"] and not info["red_light"]
    assert libsumo.vehicle.getRoadID(EGO) == "rb1_to_s1" and libsumo.vehicle.getSpeed(EGO) < 0.1
    assert obs[26] < 0.01 and obs[27] == 1.0  # at the stop line, red
    libsumo.trafficlight.setRedYellowGreenState("s1", "G" * 9)
    for _ in range(40):
        _, _, _, _, info = env.step(env.expert_action())
        assert not info["red_light"]
    assert libsumo.vehicle.getRoadID(EGO) != "rb1_to_s1"


@pytest.mark.parametrize(("route", "special"), [(1, False), (2, True)])
def test_expert_completes_routes_without_violations(make_env: MakeEnv, route: int, special: bool) -> None:
    env = make_env(route=route, special_vehicles=special)
    runner = Runner(env, ExpertPolicy(env), seed=10)
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    for _ in range(2):
        records.clear()
        summary = runner.run_episode()
        assert summary.error is None
        m = summary.metrics
        assert (m["success"], m["collision"], m["red_light"], m["timeout"]) == (1.0, 0.0, 0.0, 0.0), m
        assert summary.cost == 0.0 and m["route_progress"] == 1.0 and m["speed_mean"] > 5.0
        assert all(r.info["expert_drove"] for r in records)
        last = records[-1]
        assert last.terminated and last.reward == pytest.approx(last.info["speed"] / 5.0 + 100.0)
        # the expert's action is SUMO's next acceleration, predicted from SUMO's API: close to what SUMO did
        errors = [abs(r.info["executed_action"] - float(r.action[0])) for r in records]
        assert np.mean(errors) < 0.15


def test_only_the_experts_own_array_hands_the_step_to_sumo(make_env: MakeEnv) -> None:
    env = make_env(route=1)
    env.reset(seed=0)
    suggestion = env.expert_action()
    _, _, _, _, info = env.step(suggestion.copy())  # an equal action from someone else: the agent drives
    assert not info["expert_drove"]
    _, _, _, _, info = env.step(env.expert_action())
    assert info["expert_drove"]
    env.expert_action()  # asked, but not followed
    _, _, _, _, info = env.step(np.zeros(1, np.float32))
    assert not info["expert_drove"]


def _special_labels_seen(env: SumoEnv, steps: int) -> set[str]:
    seen: set[str] = set()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.expert_action())
        seen |= {m.get("label", "") for m in env.scene()["movers"] if m["kind"] == "box"}
        if terminated or truncated:
            break
    return seen & set(SPECIAL_LABELS.values())


def test_special_vehicles_join_in_c2_only(make_env: MakeEnv) -> None:
    c1 = make_env(route=2, special_vehicles=False)
    c1.reset(seed=4)
    assert _special_labels_seen(c1, 120) == set()
    c2 = make_env(route=2, special_vehicles=True)
    c2.reset(seed=4)
    assert len(_special_labels_seen(c2, 120)) >= 2


def test_scene_is_plain_data_around_the_ego(make_env: MakeEnv) -> None:
    env = make_env(route=2, special_vehicles=True)
    env.reset(seed=1)
    for _ in range(20):
        env.step(env.expert_action())
    scene = env.scene()
    assert scene["sim"] == "sumo" and scene["static_key"].startswith("sumo:composite:")
    kinds = {s["kind"] for s in scene["static"]}
    assert kinds == {"polyline", "polygon"} and len(scene["static"]) > 50
    ego = scene["ego"]
    x0, y0, x1, y1 = scene["bounds"]
    assert x0 < ego["x"] < x1 and y0 < ego["y"] < y1
    boxes = [m for m in scene["movers"] if m["kind"] == "box"]
    lights = [m for m in scene["movers"] if m["kind"] == "circle"]
    assert len(boxes) == libsumo.vehicle.getIDCount() - 1
    assert len(lights) == 9 + 4  # one per signalised link of s1 and s2
    assert all(m["color"].startswith("#") and len(m["color"]) == 7 for m in scene["movers"])
    assert scene["labels"]["phase"] == "C2" and scene["labels"]["route"] == "2"
    for _ in range(200):  # the ego may be waiting to cross u2a's major road
        env.step(env.expert_action())
        later = env.scene()
        if math.hypot(later["ego"]["x"] - ego["x"], later["ego"]["y"] - ego["y"]) > 5.0:
            break
    assert later["static_key"] == scene["static_key"]  # static drawn once per network
    assert later["labels"]["time"] != scene["labels"]["time"]
    assert math.hypot(later["ego"]["x"] - ego["x"], later["ego"]["y"] - ego["y"]) > 5.0


def test_set_scenario_switches_route_at_the_next_reset(make_env: MakeEnv) -> None:
    env = make_env(route=1)
    _, info = env.reset(seed=0)
    assert (info["route"], info["phase"]) == (1, "C1")
    env.unwrapped.set_scenario(route=2, special_vehicles=True)
    assert env.config.route == 1  # the running episode is not changed
    _, info = env.reset(seed=0)
    assert (info["route"], info["phase"]) == (2, "C2")
    assert libsumo.vehicle.getRoadID(EGO).startswith("r2_start")
    _, info = env.reset(seed=0, options={"route": 1, "special_vehicles": False})
    assert (info["route"], info["phase"]) == (1, "C1")


def test_a_crashed_simulation_ends_the_episode_with_a_clear_error_and_the_next_one_works(make_env: MakeEnv) -> None:
    env = make_env(route=1)

    class CrashesSumo:
        """Drives gently, and on its 5th call kills the simulation under the env (as a SUMO crash would)."""

        calls = 0

        def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
            self.calls += 1
            if self.calls == 5:
                libsumo.close()
            return np.array([0.3], np.float32)

    runner = Runner(env, CrashesSumo(), seed=0)
    summary = runner.run_episode()
    assert summary.error is not None and "SumoError" in summary.error and "SUMO failed" in summary.error
    assert summary.steps == 4
    assert not env.running
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, np.float32))
    summary = runner.run_episode(max_steps=30)
    assert summary.error is None and summary.steps == 30


def test_bad_files_give_errors_naming_the_file(make_env: MakeEnv, tmp_path: Path) -> None:
    missing = tmp_path / "nope.net.xml"
    with pytest.raises(FileNotFoundError, match=r"nope\.net\.xml"):
        SumoEnv(net_file=str(missing))
    garbled = tmp_path / "garbled.net.xml"
    garbled.write_text("<net><edge id='a'")
    with pytest.raises(SumoError, match=r"garbled\.net\.xml"):
        SumoEnv(net_file=str(garbled))
    with pytest.raises(SumoError, match="not a <net> file"):
        SumoEnv(net_file=str(Path(__file__).parent.parent.parent.parent / "sims/sumo/data/common.rou.xml"))
    with pytest.raises(ValueError, match="route"):
        SumoEnv(route=4)  # 1-3 exist (3: the sumo-shift family's route)
    # well-formed but empty: SUMO itself refuses it at reset, with its own reason
    empty = tmp_path / "empty.net.xml"
    empty.write_text('<?xml version="1.0"?>\n<net version="1.20"></net>\n')
    broken = make_env(net_file=str(empty))
    with pytest.raises(SumoError, match="SUMO could not start"):
        broken.reset(seed=0)
    good = make_env(route=1)
    obs, _ = good.reset(seed=0)
    assert obs.shape == (29,)
    good.step(np.zeros(1, np.float32))


def test_a_second_in_process_env_takes_the_simulation_over_clearly(make_env: MakeEnv) -> None:
    first = make_env(route=1)
    second = make_env(route=2)
    first.reset(seed=0)
    second.reset(seed=0)
    with pytest.raises(SumoError, match="one simulation per process"):
        first.step(np.zeros(1, np.float32))
    second.step(np.zeros(1, np.float32))
    assert libsumo.vehicle.getRoadID(EGO).startswith("r2_start")


def test_registered_and_passes_gymnasiums_env_checker() -> None:
    env = gym.make("sage/Sumo-v0")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the checker reports problems as warnings: none allowed
            check_env(env.unwrapped)
    finally:
        env.close()
    made = sims.make("sumo", route=2, special_vehicles=True)
    try:
        assert isinstance(made.unwrapped, SumoEnv) and made.unwrapped.config.phase == "C2"
    finally:
        made.close()


def test_a_takeover_records_the_action_sumo_executed_as_the_experts_label(make_env: MakeEnv) -> None:
    """SUMO's driver may not do what expert_action() predicted: the loop records what it did."""
    from core.experts import ScriptedExpert
    from core.sage.gate import AlwaysGate

    class Hold:
        def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
            return np.zeros(1, np.float32)

    env = make_env(route=1)
    runner = Runner(env, Hold(), AlwaysGate(), ScriptedExpert(), seed=0)
    records: list[StepRecord] = []
    runner.step_listeners.append(records.append)
    runner.reset()
    for _ in range(60):
        if runner.step() is None or records[-1].done:
            break
    assert records and all(r.takeover for r in records)
    for r in records:
        assert r.a_expert is not None
        assert float(r.a_expert[0]) == pytest.approx(r.info["executed_action"], abs=1e-6)
        assert np.array_equal(r.action, r.a_expert)
    # the label is what SUMO's driver executed, which is not always what was predicted before the step
    speeds = [r.info["speed"] for r in records]
    assert max(speeds) > 1.0, "the expert should have driven off"
