"""Configuration of ``sage/Pedestrian-v0`` (one dataclass, highway-env style ``default_config()``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from core.dotted import replaced


@dataclass(frozen=True)
class PedestrianConfig:
    """Urban road along +x: the ego lane is y in [0, lane_width], the opposite lane above it, a parking
    strip below it (y < 0) where the truck and other vehicles stand."""

    dt: float = 0.5
    """Control period (s): one discrete action every 0.5 s (the paper's)."""
    substeps: int = 10
    """Kinematic integration steps per action; collisions are checked at each."""
    time_limit: float = 30.0
    """Episode truncation (s)."""
    lane_width: float = 3.5
    """Width of each lane (m)."""
    parking_width: float = 2.6
    """Width of the parking strip below the ego lane (m)."""
    wheelbase: float = 2.7
    """Ego bicycle wheelbase (m)."""
    ego_length: float = 4.5
    ego_width: float = 1.8
    v_max: float = 10.0
    """Speed limit (m/s); speed is clipped to [0, v_max]."""
    v_start: tuple[float, float] = (6.0, 9.0)
    """Initial speed range (m/s), drawn per seed."""
    accel: float = 2.0
    """Acceleration of the ``accelerate`` action (m/s^2)."""
    brake: float = 5.0
    """Deceleration of the ``brake`` action (m/s^2)."""
    steer: float = 0.08
    """Front-wheel angle of the ``left``/``right`` actions (rad)."""
    truck_length: float = 10.0
    truck_width: float = 2.5
    truck_x: tuple[float, float] = (35.0, 55.0)
    """Range of the truck's centre x (m) drawn per seed; the ego starts at x = 0."""
    goal_after_truck: float = 30.0
    """The goal line is this far (m) past the truck's front."""
    pedestrian_radius: float = 0.35
    pedestrian_speed: tuple[float, float] = (1.0, 1.8)
    """Walking speed range (m/s) drawn per seed."""
    pedestrian_ahead: tuple[float, float] = (0.4, 1.2)
    """How far past the truck's front (m) the pedestrian waits, drawn per seed."""
    trigger_distance: tuple[float, float] = (12.0, 22.0)
    """The pedestrian steps out when the ego's front is this far (m) behind it, drawn per seed."""
    pedestrian_probability: float = 1.0
    """Chance that an episode has a pedestrian (below 1 keeps the event rare in training)."""
    parked_vehicles: tuple[int, int] = (0, 0)
    """Range of the number of other parked cars placed along the strip (inclusive)."""
    lidar_bins: int = 36
    """360° lidar bins of 10° (nearest return per bin), the paper's."""
    lidar_rays_per_bin: int = 5
    """Rays cast per bin (5: a 0.7 m pedestrian stays visible to 40 m)."""
    lidar_range: float = 40.0
    """Ranges are clipped to this and divided by it in the observation."""
    r_collision: float = -10.0
    r_goal: float = 5.0
    speed_weight: float = 0.1
    """Weight of v / v_max in the reward."""
    steer_weight: float = 0.1
    """Weight of |δ| (rad) in the reward."""

    @property
    def steps(self) -> int:
        return round(self.time_limit / self.dt)


def default_config() -> PedestrianConfig:
    return PedestrianConfig()


def with_overrides(config: PedestrianConfig, overrides: dict[str, Any]) -> PedestrianConfig:
    """``config`` with fields replaced; an unknown name is a clear error."""
    return replaced(config, overrides, "pedestrian")


__all__ = ["PedestrianConfig", "default_config", "with_overrides"]
