"""A toy simulator with discrete actions for the learner-registry tests: a corridor of ``LENGTH`` cells.

Actions: ``Discrete(3)`` = left, stay, right. Observation (2): position and distance to the goal, both / LENGTH.
Reward: +1 per cell of progress, -0.05 per step, +5 at the goal (which ends the episode); 20 steps at most.
No safety cost. The expert always moves right. Registered as ``sage-test/Corridor-v0`` on import; its
``DESCRIPTOR`` is all the simulator registry needs.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor

ENV_ID = "sage-test/Corridor-v0"
LENGTH = 6


class CorridorEnv(gym.Env[np.ndarray, np.int64]):
    observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gym.spaces.Discrete(3)

    def __init__(self, scenario: str = "plain", horizon: int = 20) -> None:
        self.horizon, self.pos, self.t, self.success = horizon, 0, 0, False

    def _obs(self) -> np.ndarray:
        return np.array([self.pos / LENGTH, (LENGTH - self.pos) / LENGTH], np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.pos, self.t, self.success = 0, 0, False
        return self._obs(), {}

    def step(self, action: Any):
        move = int(np.asarray(action).reshape(-1)[0]) - 1
        before = self.pos
        self.pos = min(max(self.pos + move, 0), LENGTH)
        self.t += 1
        self.success = self.pos == LENGTH
        reward = float(self.pos - before) - 0.05 + (5.0 if self.success else 0.0)
        truncated = not self.success and self.t >= self.horizon
        return self._obs(), reward, self.success, truncated, {"cost": 0.0, "violation": False}

    def expert_action(self) -> np.ndarray:
        return np.array([2], np.int64)

    def scene(self) -> dict[str, Any]:
        return {"sim": "corridor", "ego": [float(self.pos), 0.0]}

    def metrics(self) -> dict[str, float]:
        return {"success": float(self.success), "position": float(self.pos)}


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="tests.core.corridor_env:CorridorEnv")

DESCRIPTOR = SimDescriptor(
    name="corridor",
    title="corridor (tests, discrete actions)",
    env_id=ENV_ID,
    entry_point="tests.core.corridor_env:CorridorEnv",
    dt=0.1,
    scenarios=(ScenarioSpec("plain", "plain corridor", {"scenario": "plain"}),),
    default_scenario="plain",
    input_mapping=InputMapping(throttle_index=0, steer_index=0),
    metric_columns=("success", "position"),
    safe_action=1,
)


def make(scenario: str = "plain", **kwargs: Any) -> gym.Env[Any, Any]:
    return gym.make(ENV_ID, scenario=scenario, **kwargs)
