"""The occluded-pedestrian simulator (#12): spaces, occlusion by the truck computed by the lidar, the
cautious expert, and how often naive driving collides."""

from __future__ import annotations

import numpy as np
import pytest

import sims
from sims.pedestrian.env import OBS_SIZE, PedestrianEnv
from sims.pedestrian.world import encode


def run(env: PedestrianEnv, policy, seed: int) -> tuple[dict[str, float], list[dict]]:
    env.reset(seed=seed)
    infos, done = [], False
    while not done:
        _, _, terminated, truncated, info = env.step(policy(env))
        infos.append(info)
        done = terminated or truncated
    return env.metrics(), infos


def test_registered_with_descriptor_and_spaces() -> None:
    env = sims.descriptor("pedestrian").make("crossing")
    obs, info = env.reset(seed=0)
    assert env.action_space.n == 9 and obs.shape == (OBS_SIZE,) == (39,)
    assert env.observation_space.contains(obs)
    assert info["cost"] == 0.0 and info["violation"] is False
    scene = env.unwrapped.scene()
    assert scene["sim"] == "pedestrian" and len(scene["rays"]["ends"]) == env.unwrapped.lidar.n_rays
    mapping = sims.descriptor("pedestrian").input_mapping.discrete
    assert mapping(1.0, 0.0) == encode(1, 0) and mapping(-1.0, 1.0) == encode(-1, 1)
    assert mapping(0.0, 0.0) == encode(-1, 0) == sims.descriptor("pedestrian").safe_action  # resting brakes
    assert mapping(0.3, -1.0) == encode(0, -1)


def test_bad_action_and_config_are_clear_errors() -> None:
    env = PedestrianEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"0\.\.8"):
        env.step(9)
    with pytest.raises(ValueError, match="unknown pedestrian config"):
        PedestrianEnv(walking_speed=2.0)


def test_expert_never_collides_in_100_seeded_episodes() -> None:
    env = PedestrianEnv()
    results = [run(env, lambda e: e.expert_action(), seed)[0] for seed in range(100)]
    assert sum(r["collision"] for r in results) == 0
    assert sum(r["success"] for r in results) == 100


def test_naive_driving_collides_often() -> None:
    """Keeping speed through the scene (what an untrained policy that learnt to drive fast does) hits the
    pedestrian in most episodes: the event is dangerous, not decorative."""
    env = PedestrianEnv()
    collisions = sum(run(env, lambda e: encode(0, 0), seed)[0]["collision"] for seed in range(50))
    assert collisions >= 25


def test_pedestrian_hidden_by_the_truck_until_it_steps_out() -> None:
    env = PedestrianEnv()
    for seed in range(20):
        env.reset(seed=seed)
        ped = env.pedestrian
        assert ped is not None and not env.pedestrian_visible()
        visible_at = None
        while True:
            position = env.pedestrian_position()
            assert position is not None
            if env.pedestrian_visible() and visible_at is None:
                visible_at = position[1]
            if (
                0.0 < position[1] - ped.radius < env.config.lane_width
            ):  # in the ego lane: nothing between it and the ego
                assert env.pedestrian_visible(), f"seed {seed}: pedestrian in the lane but not seen"
            _, _, terminated, truncated, _ = env.step(env.expert_action())
            if terminated or truncated:
                break
        # it is first seen only after stepping out from the truck's side (the truck's left edge is at y = -0.05)
        assert visible_at is not None and visible_at > ped.y0


def test_lidar_bins_see_the_truck_not_the_hidden_pedestrian() -> None:
    with_ped, without = PedestrianEnv(), PedestrianEnv()
    with_ped.reset(seed=3)
    without.reset(seed=3)
    without.pedestrian = None  # same layout, pedestrian removed
    assert np.allclose(with_ped.lidar_bins(), without.lidar_bins())
    assert with_ped.lidar_bins().min() < with_ped.config.lidar_range  # the truck and the road edges are seen


def test_scenarios_keep_the_pedestrian_rare() -> None:
    rare = sims.descriptor("pedestrian").make("rare").unwrapped
    seen = [rare.reset(seed=s)[1]["pedestrian"] for s in range(200)]
    assert 0.1 < np.mean(seen) < 0.3
    clear = sims.descriptor("pedestrian").make("clear").unwrapped
    assert not any(clear.reset(seed=s)[1]["pedestrian"] for s in range(20))


def test_runs_in_the_shared_loop_with_the_scripted_expert() -> None:
    from core.experts import ExpertPolicy, ScriptedExpert
    from core.loop import Runner

    env = sims.make("pedestrian", "rare", live=True)
    runner = Runner(env, ExpertPolicy(env), expert=ScriptedExpert(), seed=0)
    summaries = [runner.run_episode() for _ in range(5)]
    assert all(s.error is None and s.metrics["success"] == 1.0 and s.cost == 0.0 for s in summaries)
    assert set(summaries[0].metrics) == set(sims.descriptor("pedestrian").metric_columns)
