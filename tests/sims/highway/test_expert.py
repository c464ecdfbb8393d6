"""The scripted expert: near-zero collisions where a simple policy crashes, in replay and adversarial traffic."""

from __future__ import annotations

import numpy as np

import sims
from studies.highway_evaluate import evaluate
from tests.sims.highway.conftest import FEW_TEST_IDS


def test_expert_survives_adversarial_episodes_aimed_at_itself() -> None:
    """Adversaries are resampled against the expert's own predicted path (CAT with the expert as the policy)."""
    rows = evaluate("expert", "test", "adversarial", episodes=len(FEW_TEST_IDS))
    assert all(r["adversary_events"] >= 1 for r in rows)
    assert sum(r["collision"] for r in rows) == 0 and sum(r["off_road"] for r in rows) == 0
    assert sum(r["success"] for r in rows) == len(rows)
    assert float(np.mean([r["min_ttc"] for r in rows])) < 9.0  # the encounters were real


def test_expert_brakes_for_a_cut_in_and_reads_no_lidar() -> None:
    env = sims.make("highway", scenario_id=FEW_TEST_IDS[2], mode="adversarial", ego_predictor="expert")
    _, info = env.reset(seed=0)
    inner = env.unwrapped
    choices, accels = [], []
    done = False
    while not done:
        inner.world.lidar[:] = 1.0  # blind the sensor: the expert uses privileged state only
        action = inner.expert_action()
        choices.append(inner.expert.last_choice)
        accels.append(float(action[1]))
        _, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    assert info["success"] and not info["crashed"]
    assert {"brake", "evasive"} & set(choices)  # the safety check overrode IDM/MOBIL at least once
    assert min(accels) < -0.9  # and braked hard (the strongest candidate is -7 m/s²)


def test_expert_takes_over_mid_episode_from_wherever_the_agent_left_the_car() -> None:
    env = sims.make("highway", scenario_id=FEW_TEST_IDS[3])
    env.reset(seed=0)
    for _ in range(15):  # an agent drifting towards the left edge
        _, _, terminated, _, info = env.step(np.array([0.15, 0.0], np.float32))
        assert not terminated
    inner = env.unwrapped
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(inner.expert_action())
        done = terminated or truncated
    assert info["success"] and not info["crashed"] and not info["offroad"]
    assert abs(inner.world.ego.heading) < 0.05


def _beside(dx: float, closing: float, alongside_time: float) -> tuple[float, str]:
    """The expert's normalised acceleration and choice with one vehicle ``dx`` m ahead of the ego (centre to
    centre) in the lane to its left, ``closing`` m/s faster than it, every other vehicle far away."""
    env = sims.make("highway", scenario_id=FEW_TEST_IDS[0], **{"expert.alongside_time": alongside_time})
    env.reset(seed=0)
    world = env.unwrapped.world
    lay, tr = world.layout, world.traffic
    ex, ey, _, ev = world.ego_state
    lane = int(lay.lane_of(ey))
    left = lane - 1 if lane > 0 else lane + 1
    tr.x[:] = ex + 1000.0 + 30.0 * np.arange(tr.x.size)
    tr.x[0], tr.y[0], tr.heading[0], tr.speed[0], tr.accel[0] = ex + dx, lay.lane_y(left), 0.0, ev + closing, 0.0
    action = env.unwrapped.expert_action()
    return float(action[1]), env.unwrapped.expert.last_choice


def test_expert_drops_back_from_a_vehicle_riding_alongside() -> None:
    """Defensive driving (``expert.alongside_time``): a vehicle beside the ego at its speed could cut in with no gap
    to brake into, so the expert slows down to fall behind it; one that is passing, or one far ahead of the ego,
    changes nothing, and with the rule off the expert keeps its speed beside it."""
    level, choice = _beside(dx=1.0, closing=0.0, alongside_time=1.0)
    assert level < -0.1 and choice == "nominal"  # IDM's own command, not the safety check's emergency
    assert _beside(dx=1.0, closing=0.0, alongside_time=0.0)[0] > -0.05
    assert _beside(dx=1.0, closing=8.0, alongside_time=1.0)[0] > -0.05  # it clears the ego within the second
    assert _beside(dx=20.0, closing=0.0, alongside_time=1.0)[0] > -0.05  # far ahead in its own lane
