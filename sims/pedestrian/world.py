"""The scene's state: the ego's kinematic bicycle, the parked vehicles and the scripted pedestrian."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sims.pedestrian.config import PedestrianConfig

THROTTLE = (-1, 0, 1)
"""Action index // 3: brake, maintain, accelerate."""
STEER = (1, 0, -1)
"""Action index % 3: left (+δ), keep, right (-δ)."""


def decode(action: int) -> tuple[int, int]:
    """Action index 0..8 -> (throttle sign, steer sign)."""
    if not 0 <= int(action) < 9:
        raise ValueError(f"pedestrian actions are 0..8, got {action}")
    return THROTTLE[int(action) // 3], STEER[int(action) % 3]


def encode(throttle: int, steer: int) -> int:
    return THROTTLE.index(throttle) * 3 + STEER.index(steer)


@dataclass
class Ego:
    x: float
    y: float
    yaw: float
    v: float


@dataclass(frozen=True)
class Parked:
    x: float
    y: float
    length: float
    width: float


@dataclass
class Pedestrian:
    """Waits at (x, y0) until the ego's front is ``trigger`` metres behind x, then walks +y at ``speed`` and
    stops at ``y_end`` (the far side of the road)."""

    x: float
    y0: float
    speed: float
    trigger: float
    radius: float
    y_end: float
    start_time: float | None = None

    def y_at(self, time: float) -> float:
        if self.start_time is None or time <= self.start_time:
            return self.y0
        return min(self.y0 + self.speed * (time - self.start_time), self.y_end)


def bicycle_step(ego: Ego, accel: float, delta: float, dt: float, config: PedestrianConfig) -> Ego:
    """Kinematic bicycle about the ego's centre, speed clipped to [0, v_max]."""
    v = float(np.clip(ego.v + accel * dt, 0.0, config.v_max))
    yaw = ego.yaw + v / config.wheelbase * math.tan(delta) * dt
    return Ego(ego.x + v * math.cos(yaw) * dt, ego.y + v * math.sin(yaw) * dt, yaw, v)


def ego_circles(ego: Ego, config: PedestrianConfig) -> np.ndarray:
    """Three discs (x, y, r) covering the ego's box, for collision checks."""
    r = config.ego_width / 2
    offsets = np.array([-(config.ego_length / 2 - r), 0.0, config.ego_length / 2 - r])
    return np.column_stack([ego.x + offsets * math.cos(ego.yaw), ego.y + offsets * math.sin(ego.yaw), np.full(3, r)])


def disc_box_overlap(circles: np.ndarray, box: Parked) -> bool:
    """Any disc overlapping the axis-aligned box."""
    dx = np.maximum(np.abs(circles[:, 0] - box.x) - box.length / 2, 0.0)
    dy = np.maximum(np.abs(circles[:, 1] - box.y) - box.width / 2, 0.0)
    return bool(np.any(dx * dx + dy * dy < circles[:, 2] ** 2))


def ego_front(ego: Ego, config: PedestrianConfig) -> float:
    return ego.x + config.ego_length / 2 * math.cos(ego.yaw)
