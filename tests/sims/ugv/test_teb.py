"""The TEB local planner: its band's Jacobian, goal reaching without collision on static layouts it never reads,
and the planner registry."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sims
from core.planners import is_planner, make_planner
from sims.ugv.teb import Band, TebConfig, TebOptimizer, TebPlanner
from tests.sims.ugv.conftest import room


def test_the_analytic_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(3)
    optimizer = TebOptimizer(TebConfig(), v_max=0.6, w_max=1.0)
    n = 8
    poses = np.column_stack([np.linspace(0, 2.5, n), rng.normal(0, 0.2, n), rng.normal(0, 0.8, n)])
    band = Band(poses, rng.uniform(0.1, 0.8, n - 1))
    obstacles = rng.uniform(-0.5, 3.0, (n - 1, 4, 2))
    z = optimizer.pack(band)
    args = (poses[0], poses[-1, :2], n, 0.5, -0.4, obstacles)
    analytic = optimizer.jacobian(z, *args)
    eps = 1e-6
    numeric = np.stack(
        [
            (optimizer.residuals(z + e, *args) - optimizer.residuals(z - e, *args)) / (2 * eps)
            for e in np.eye(len(z)) * eps
        ],
        axis=1,
    )
    assert np.abs(analytic - numeric).max() < 1e-5


class SensingOnly:
    """What a real robot's planner gets: sensing, the episode counter and the robot's own configuration."""

    def __init__(self, env: Any) -> None:
        self._env = env

    @property
    def unwrapped(self) -> SensingOnly:
        return self

    @property
    def config(self) -> Any:
        return self._env.unwrapped.config

    @property
    def episode(self) -> int:
        return self._env.unwrapped.episode

    def sensing(self) -> Any:
        return self._env.unwrapped.sensing()


def drive(env: Any, planner: Any, seeds: range) -> list[str]:
    outcomes = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        while True:
            obs, _, terminated, truncated, info = env.step(planner.act(obs, deterministic=True))
            if terminated or truncated:
                break
        outcomes.append("success" if info["success"] else "collision" if info["collision"] else "timeout")
    return outcomes


# scenario 1 runs by default; the barrier and the clutter field drive the same planner path for 30 s more (-m slow)
@pytest.mark.parametrize(
    "scenario",
    [
        "1",
        pytest.param("2", marks=pytest.mark.slow),
        pytest.param(str(Path(sims.__file__).parent / "ugv/scenarios/clutter.yaml"), marks=pytest.mark.slow),
    ],
)
def test_teb_reaches_the_goal_on_static_layouts_without_collision(scenario: str) -> None:
    """Through the offset gaps (1), around the barrier (2) and among lone obstacles placed anew every episode, seeing
    the layout only through the lidar (the planner gets a proxy with nothing but the robot's sensing)."""
    env = sims.make("ugv", scenario=scenario)
    outcomes = drive(env, TebPlanner(SensingOnly(env)), range(40, 43))
    assert outcomes == ["success"] * 3


def test_teb_finds_its_way_out_of_a_dead_end_it_only_sees_on_arrival(
    write_scenario: Callable[[dict[str, Any]], Path],
) -> None:
    """A cup-shaped wall facing the robot hides the way round until the lidar has seen the cup: the sensed costmap
    and the replanned global path take it out and around to the goal."""
    layout = room(
        bounds=[0, 0, 8, 6],
        start={"x": 1.0, "y": 3.0, "yaw_deg": 0},
        goal={"x": 7.0, "y": 3.0, "radius": 0.3},
        time_limit=60,
        obstacles=[
            {"kind": "box", "x": 4.0, "y": 3.0, "length": 0.2, "width": 2.4},
            {"kind": "box", "x": 3.3, "y": 4.1, "length": 1.4, "width": 0.2},
            {"kind": "box", "x": 3.3, "y": 1.9, "length": 1.4, "width": 0.2},
        ],
    )
    env = sims.make("ugv", scenario=str(write_scenario(layout)))
    assert drive(env, TebPlanner(SensingOnly(env)), range(1)) == ["success"]


def test_teb_is_a_registered_planner_for_the_ugv_only() -> None:
    assert is_planner("teb")
    env = sims.make("ugv", scenario="2")
    obs, _ = env.reset(seed=0)
    action = make_planner("teb", env, sim="ugv").act(obs, deterministic=True)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    with pytest.raises(ValueError, match="drives ugv"):
        make_planner("teb", env, sim="highway")
