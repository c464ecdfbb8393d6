"""A tiny protocol-conforming simulator for loop-level tests: a point on a line moved by its action."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np


class LineEnv(gym.Env[np.ndarray, np.ndarray]):
    """A point on a line moving by its action; the expert always pushes +1; cost when x > 3."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, horizon: int = 10, crash_at: int | None = None) -> None:
        self.horizon, self.crash_at = horizon, crash_at
        self.x, self.t = 0.0, 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return np.array([self.x], np.float32), {}

    def step(self, action: np.ndarray):
        self.t += 1
        if self.crash_at is not None and self.t == self.crash_at:
            raise RuntimeError("simulator crashed")
        self.x += float(np.asarray(action).reshape(-1)[0])
        cost = float(self.x > 3)
        return np.array([self.x], np.float32), 1.0, False, self.t >= self.horizon, {"cost": cost, "violation": False}

    def expert_action(self) -> np.ndarray:
        return np.array([1.0], np.float32)

    def scene(self) -> dict[str, Any]:
        return {"sim": "line"}

    def metrics(self) -> dict[str, float]:
        return {"x": self.x}
