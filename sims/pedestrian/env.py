"""``sage/Pedestrian-v0``: an occluded pedestrian steps out from in front of a parked truck (the paper's
long-tail experiment).

Action: ``Discrete(9)``, index = 3 * throttle + steer, throttle in (brake, maintain, accelerate), steer in
(left, keep, right), held for 0.5 s on a kinematic bicycle.

Observation (39 float32): a 360° lidar in 36 bins of 10° (nearest range per bin / lidar_range, bin 0 starting
straight behind, counter-clockwise from -180°), ego speed / v_max, distance to goal / initial distance, goal
bearing / pi. The lidar is ray-cast against the parked vehicles (boxes), the road edges and the pedestrian
(a disc), so the truck hides the pedestrian until it steps out.

Reward: r_col (-10) on collision + r_goal (+5) at the goal + 0.1 v / v_max - 0.1 |δ|.
Cost: 1 on collision (with the pedestrian, a parked vehicle or the road edge), else 0 (info ``cost``,
``violation``). The episode terminates on collision or at the goal line and truncates at ``time_limit``.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from core.scene import Box, Circle, Rays, Scene, Shape
from sims.pedestrian.config import PedestrianConfig, default_config, with_overrides
from sims.pedestrian.expert import expert_action
from sims.pedestrian.metrics import episode_metrics, time_to_collision
from sims.pedestrian.world import (
    Ego,
    Parked,
    Pedestrian,
    bicycle_step,
    decode,
    disc_box_overlap,
    ego_circles,
    ego_front,
)
from sims.ugv.config import LidarConfig
from sims.ugv.lidar import NumpyLidar, box_edges_batch, two_sided

OBS_SIZE = 39
COLORS = {
    "road": "#4a4f57",
    "truck": "#8a8f98",
    "car": "#a3a8b0",
    "ped": "#e0812b",
    "ego": "#2b7de0",
    "goal": "#2bb673",
}


class PedestrianEnv(gym.Env[np.ndarray, np.int64]):
    """Keyword overrides replace :class:`PedestrianConfig` fields (``pedestrian_probability=0.2``)."""

    metadata = {"render_modes": [], "render_fps": 2}  # noqa: RUF012 (gymnasium's convention)

    def __init__(self, config: PedestrianConfig | None = None, render_mode: str | None = None, **overrides: Any):
        if render_mode is not None:
            raise ValueError("PedestrianEnv does not render; draw env.unwrapped.scene() instead")
        self.config = with_overrides(config or default_config(), overrides)
        c = self.config
        self.action_space = gym.spaces.Discrete(9)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (OBS_SIZE,), np.float32)
        self._lidar_config = LidarConfig(
            fov_deg=360.0, sectors=c.lidar_bins, rays_per_sector=c.lidar_rays_per_bin, max_range=c.lidar_range
        )
        self.lidar = NumpyLidar(self._lidar_config)
        self.ego = Ego(0.0, c.lane_width / 2, 0.0, 0.0)
        self.parked: list[Parked] = []
        self.pedestrian: Pedestrian | None = None
        self.goal_x = 0.0
        self.time = 0.0
        self.episode = -1
        self._inverse = np.zeros(self.lidar.n_rays, np.float32)

    # -- episode -----------------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        c, rng = self.config, self.np_random
        self.episode += 1
        truck_x = float(rng.uniform(*c.truck_x))
        strip_y = -c.parking_width / 2
        truck = Parked(truck_x, strip_y, c.truck_length, c.truck_width)
        self.parked = [truck]
        n_cars = int(rng.integers(c.parked_vehicles[0], c.parked_vehicles[1] + 1))
        slots = rng.permutation(np.arange(12.0, truck_x - c.truck_length / 2 - 4.0, 6.0))[:n_cars]
        self.parked += [Parked(float(x), strip_y, 4.5, 1.9) for x in sorted(slots)]
        truck_front = truck_x + c.truck_length / 2
        self.pedestrian = None
        if rng.random() < c.pedestrian_probability:
            self.pedestrian = Pedestrian(
                x=truck_front + float(rng.uniform(*c.pedestrian_ahead)),
                y0=strip_y,
                speed=float(rng.uniform(*c.pedestrian_speed)),
                trigger=float(rng.uniform(*c.trigger_distance)),
                radius=c.pedestrian_radius,
                y_end=2 * c.lane_width - c.pedestrian_radius - 0.3,
            )
        self.goal_x = truck_front + c.goal_after_truck
        self.ego = Ego(0.0, c.lane_width / 2, 0.0, float(rng.uniform(*c.v_start)))
        self.time, self._steps = 0.0, 0
        self._collision = self._success = False
        self._trace: list[tuple[float, float, float, float]] = []  # t, x, y, v
        self._ttc: list[float] = []
        self._last_delta = 0.0
        road = np.array(
            [
                [-20.0, -c.parking_width, self.goal_x + 20.0, -c.parking_width],
                [-20.0, 2 * c.lane_width, self.goal_x + 20.0, 2 * c.lane_width],
            ]
        )
        # box edges wind clockwise with the outside on their left, the caster's one-sided convention
        edges = np.concatenate(
            [box_edges_batch(np.array([[p.x, p.y, 0.0]]), p.length, p.width)[0] for p in self.parked]
        )
        self.lidar.set_static(np.vstack([two_sided(road), edges]), np.zeros((0, 3)), dynamic_circles=1)
        self._record()
        return self._observation(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self.episode < 0:
            raise RuntimeError("call reset() before step()")
        throttle, steer = decode(int(np.asarray(action).reshape(())))
        c = self.config
        accel = c.accel if throttle > 0 else (-c.brake if throttle < 0 else 0.0)
        delta = steer * c.steer
        h = c.dt / c.substeps
        for _ in range(c.substeps):
            self.ego = bicycle_step(self.ego, accel, delta, h, c)
            self.time += h
            self._update_pedestrian()
            if self._collides():
                self._collision = True
                break
            if ego_front(self.ego, c) >= self.goal_x:
                self._success = True
                break
        self._steps += 1
        self._last_delta = delta
        reward = c.speed_weight * self.ego.v / c.v_max - c.steer_weight * abs(delta)
        reward += c.r_collision * self._collision + c.r_goal * self._success
        terminated = self._collision or self._success
        truncated = not terminated and self._steps >= c.steps
        self._timeout = truncated
        self._record()
        return self._observation(), float(reward), terminated, truncated, self._info()

    # -- dynamics ----------------------------------------------------------------------------------------------
    def _update_pedestrian(self) -> None:
        ped = self.pedestrian
        if ped is not None and ped.start_time is None and ped.x - ego_front(self.ego, self.config) <= ped.trigger:
            ped.start_time = self.time

    def pedestrian_position(self) -> tuple[float, float] | None:
        ped = self.pedestrian
        return None if ped is None else (ped.x, ped.y_at(self.time))

    def pedestrian_cleared(self) -> bool:
        """The pedestrian has walked past the ego lane (or there is none)."""
        pos = self.pedestrian_position()
        return pos is None or pos[1] - self.config.pedestrian_radius > self.config.lane_width + 0.5

    def _collides(self) -> bool:
        c, ego = self.config, self.ego
        discs = ego_circles(ego, c)
        if any(disc_box_overlap(discs, p) for p in self.parked):
            return True
        if np.any(discs[:, 1] - discs[:, 2] < -c.parking_width) or np.any(discs[:, 1] + discs[:, 2] > 2 * c.lane_width):
            return True
        pos = self.pedestrian_position()
        if pos is not None:
            d = np.hypot(discs[:, 0] - pos[0], discs[:, 1] - pos[1])
            return bool(np.any(d < discs[:, 2] + c.pedestrian_radius))
        return False

    # -- observation -------------------------------------------------------------------------------------------
    def _scan(self) -> np.ndarray:
        pos = self.pedestrian_position()
        circle = np.array([[pos[0], pos[1], self.config.pedestrian_radius]]) if pos else np.array([[1e6, 1e6, 1e-3]])
        self.lidar.set_dynamic_circles(circle)
        self._inverse = self.lidar.cast(self.ego.x, self.ego.y, self.ego.yaw)
        return self._inverse

    def lidar_bins(self) -> np.ndarray:
        """Nearest range (m) per 10° bin, bin 0 from -180° (behind) counter-clockwise."""
        inverse = self._scan()
        return 1.0 / inverse.reshape(-1, self.config.lidar_bins).max(axis=0)

    def _observation(self) -> np.ndarray:
        c, ego = self.config, self.ego
        ranges = np.minimum(self.lidar_bins(), c.lidar_range) / c.lidar_range
        distance = max(self.goal_x - ego_front(ego, c), 0.0)
        bearing = math.atan2(c.lane_width / 2 - ego.y, max(self.goal_x - ego.x, 1e-3)) - ego.yaw
        bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
        extra = [ego.v / c.v_max, min(distance / self.goal_x, 1.0), bearing / math.pi]
        return np.concatenate([ranges, extra]).astype(np.float32)

    def pedestrian_visible(self) -> bool:
        """Whether any lidar ray's nearest hit is the pedestrian (from the last scan)."""
        pos = self.pedestrian_position()
        if pos is None:
            return False
        ranges = 1.0 / self._inverse.astype(float)
        dirs = self.ego.yaw + self.lidar.angles
        ends = np.column_stack([self.ego.x + ranges * np.cos(dirs), self.ego.y + ranges * np.sin(dirs)])
        near = np.hypot(ends[:, 0] - pos[0], ends[:, 1] - pos[1]) < self.config.pedestrian_radius + 1e-3
        return bool(np.any(near & (ranges < self.config.lidar_range - 1e-6)))

    def _record(self) -> None:
        self._trace.append((self.time, self.ego.x, self.ego.y, self.ego.v))
        self._ttc.append(time_to_collision(self.ego, self.pedestrian_position(), self.config))

    def _info(self) -> dict[str, Any]:
        return {
            "cost": float(self._collision),
            "violation": bool(self._collision),
            "collision": bool(self._collision),
            "success": bool(self._success),
            "pedestrian": self.pedestrian is not None,
            "pedestrian_visible": self.pedestrian_visible(),
            "ttc": self._ttc[-1],
        }

    # -- simulator protocol ------------------------------------------------------------------------------------
    def expert_action(self) -> np.ndarray:
        """The cautious scripted expert's action index (privileged: it knows the pedestrian's script)."""
        return np.asarray(
            expert_action(self.config, self.ego, self.pedestrian, self.pedestrian_cleared()), dtype=np.int64
        )

    def metrics(self) -> dict[str, float]:
        return episode_metrics(
            np.asarray(self._trace), np.asarray(self._ttc), success=self._success, collision=self._collision
        )

    def scene(self) -> Scene:
        c, ego = self.config, self.ego
        if self.episode < 0:
            raise RuntimeError("call reset() before scene()")
        static: list[Shape] = [
            {"kind": "polyline", "points": [[-20.0, y], [self.goal_x + 20.0, y]], "width": 0.1, "color": COLORS["road"]}
            for y in (-c.parking_width, 0.0, c.lane_width, 2 * c.lane_width)
        ]
        for i, p in enumerate(self.parked):
            color = COLORS["truck"] if i == 0 else COLORS["car"]
            static.append(Box(kind="box", x=p.x, y=p.y, yaw=0.0, length=p.length, width=p.width, color=color))
        movers: list[Shape] = []
        pos = self.pedestrian_position()
        if pos is not None:
            movers.append(Circle(kind="circle", x=pos[0], y=pos[1], radius=c.pedestrian_radius, color=COLORS["ped"]))
        ranges = 1.0 / self._inverse.astype(float)
        dirs = ego.yaw + self.lidar.angles
        ends = np.column_stack([ego.x + ranges * np.cos(dirs), ego.y + ranges * np.sin(dirs)])
        return Scene(
            sim="pedestrian",
            bounds=[-5.0, -c.parking_width - 1, self.goal_x + 5.0, 2 * c.lane_width + 1],
            static_key=f"pedestrian:{self.episode}",
            static=static,
            movers=movers,
            ego=Box(
                kind="box", x=ego.x, y=ego.y, yaw=ego.yaw, length=c.ego_length, width=c.ego_width, color=COLORS["ego"]
            ),
            goal=Box(
                kind="box",
                x=self.goal_x,
                y=c.lane_width / 2,
                yaw=0.0,
                length=0.5,
                width=c.lane_width,
                color=COLORS["goal"],
            ),
            rays=Rays(origin=[ego.x, ego.y], ends=ends.tolist(), hit=(ranges < c.lidar_range - 1e-6).tolist()),
            labels={
                "t": f"{self.time:.1f} s",
                "v": f"{ego.v:.1f} m/s",
                "pedestrian": "visible" if self.pedestrian_visible() else "hidden",
            },
        )
