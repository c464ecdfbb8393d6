"""Small protocol-conforming envs for the learner tests (fast, deterministic given the seed).

``PointNavEnv``: a point drives to a goal past a round obstacle (scenario ``static``) or one that sweeps
across its path (``dynamic``). Observation (8): position, goal offset, obstacle offset (all / 4), distance
to the obstacle's surface / 2, and the obstacle's velocity (so that the state is Markov). Action in
[-1, 1]^2: a velocity, 0.25 per step. Reward: 5 × progress - 0.02 per step, +10 at the goal, -10 on
collision (which ends the episode). Cost: min(1, max(0, (0.35 - surface distance) / 0.35)); violation =
collision. The expert is a short-horizon planner that knows the obstacle's future. Registered as
``sage-test/Point-v0`` on import.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor

ENV_ID = "sage-test/Point-v0"
STEP = 0.25
GOAL = np.array([4.0, 0.0])
RADIUS = 0.5
CLEARANCE = 0.35
"""Cost grows from 0 to 1 as the gap to the obstacle shrinks from this to 0; the expert keeps this gap."""


class PointNavEnv(gym.Env[np.ndarray, np.ndarray]):
    observation_space = gym.spaces.Box(-5.0, 5.0, (8,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def __init__(self, scenario: str | int = "static", horizon: int = 40) -> None:
        scenario = str(scenario)
        if scenario not in ("static", "dynamic", "1", "2"):
            raise ValueError(f"unknown point scenario {scenario!r}")
        self.dynamic = scenario in ("dynamic", "2")
        self.horizon = horizon
        self.pos = np.zeros(2)
        self.obstacle = np.zeros(2)
        self.t = 0
        self.phase = 0.0
        self._outcome = {"success": 0.0, "collision": 0.0}
        self._path: list[np.ndarray] = []

    # -- dynamics ----------------------------------------------------------------------------------
    def _obstacle_at(self, t: int) -> np.ndarray:
        if not self.dynamic:
            return self.obstacle_base
        return self.obstacle_base + np.array([0.0, 1.2 * math.sin(self.phase + 0.35 * t)])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        self.pos = np.array([0.0, rng.uniform(-0.3, 0.3)])
        self.obstacle_base = np.array([2.0, rng.uniform(-0.2, 0.2)])
        self.phase = rng.uniform(0, 2 * math.pi)
        self.t = 0
        self.obstacle = self._obstacle_at(0)
        self._outcome = {"success": 0.0, "collision": 0.0}
        self._path = [self.pos.copy()]
        return self._obs(), {}

    def _surface(self) -> float:
        return float(np.linalg.norm(self.obstacle - self.pos) - RADIUS)

    def _obs(self) -> np.ndarray:
        velocity = (self._obstacle_at(self.t + 1)[1] - self.obstacle[1]) / STEP
        return np.concatenate(
            [self.pos / 4, (GOAL - self.pos) / 4, (self.obstacle - self.pos) / 4, [self._surface() / 2, velocity]]
        ).astype(np.float32)

    def step(self, action: np.ndarray):
        a = np.clip(np.asarray(action, dtype=float).reshape(2), -1, 1)
        before = float(np.linalg.norm(GOAL - self.pos))
        self.pos = self.pos + STEP * a
        self.t += 1
        self.obstacle = self._obstacle_at(self.t)
        self._path.append(self.pos.copy())
        after = float(np.linalg.norm(GOAL - self.pos))
        surface = self._surface()
        collision = surface < 0.0
        success = not collision and after < 0.3
        reward = 5.0 * (before - after) - 0.02
        if collision:
            reward -= 10.0
        elif success:
            reward += 10.0
        cost = min(1.0, max(0.0, (CLEARANCE - surface) / CLEARANCE))
        self._outcome = {"success": float(success), "collision": float(collision)}
        terminated = collision or success
        truncated = not terminated and self.t >= self.horizon
        return self._obs(), reward, terminated, truncated, {"cost": cost, "violation": collision}

    # -- the simulator protocol ------------------------------------------------------------------
    def expert_action(self) -> np.ndarray:
        """Try a fan of headings (and stopping), each held for 4 steps against the obstacle's known future;
        take the one that gets nearest the goal while keeping ``CLEARANCE`` from the obstacle."""
        to_goal = GOAL - self.pos
        heading = math.atan2(to_goal[1], to_goal[0])
        best, best_score = np.zeros(2), -math.inf
        for offset in (0.0, 0.4, -0.4, 0.8, -0.8, 1.2, -1.2, 1.8, -1.8, math.pi, None):
            a = np.zeros(2) if offset is None else np.array([math.cos(heading + offset), math.sin(heading + offset)])
            pos, clear, nearest = self.pos.copy(), math.inf, math.inf
            for k in range(1, 5):
                pos = pos + STEP * a
                clear = min(clear, float(np.linalg.norm(self._obstacle_at(self.t + k) - pos)) - RADIUS)
                nearest = min(nearest, float(np.linalg.norm(GOAL - pos)))
            score = -nearest - (100.0 if clear < CLEARANCE else 0.0) + 0.3 * min(clear, 0.6)
            if score > best_score:
                best, best_score = a, score
        return best.astype(np.float32)

    def scene(self) -> dict[str, Any]:
        return {"sim": "point", "ego": self.pos.tolist(), "obstacle": self.obstacle.tolist()}

    def metrics(self) -> dict[str, float]:
        path = np.array(self._path)
        return {**self._outcome, "travel_distance": float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())}


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="tests.core.sage.envs:PointNavEnv")

METRIC_COLUMNS = ("success", "collision", "travel_distance")

DESCRIPTOR = SimDescriptor(
    name="point",
    title="point robot (tests)",
    env_id=ENV_ID,
    entry_point="tests.core.sage.envs:PointNavEnv",
    dt=0.1,
    scenarios=(
        ScenarioSpec("static", "static obstacle", {"scenario": "static"}),
        ScenarioSpec("dynamic", "moving obstacle", {"scenario": "dynamic"}),
    ),
    default_scenario="static",
    input_mapping=InputMapping(throttle_index=0, steer_index=1),
    metric_columns=METRIC_COLUMNS,
    safe_action=(0.0, 0.0),
)


def make(scenario: str = "static", **kwargs: Any) -> gym.Env[Any, Any]:
    return gym.make(ENV_ID, scenario=scenario, **kwargs)
