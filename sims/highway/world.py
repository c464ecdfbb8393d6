"""The state of one episode and its step: ego kinematics, replayed traffic, collisions, sensing.

No gymnasium here: the env (env.py) turns a world into observations, rewards and metrics, the expert
(expert.py) reads it as privileged state, and the CAT predictor (adversary.py) rolls a private world
to predict the ego's path.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from highway_env.road.road import RoadNetwork
from highway_env.vehicle.kinematics import Vehicle

from sims.highway.config import HighwayConfig
from sims.highway.road import RoadLayout, build_network, on_road, polyline_segments, road_edges
from sims.highway.scenarios import TrafficLog
from sims.highway.sensing import (
    box_corners,
    box_segments,
    interaction_stats,
    overlaps,
    ray_distances,
    segments_near,
)
from sims.highway.traffic import Paths, Traffic


@dataclass(frozen=True)
class RoadGeometry:
    layout: RoadLayout
    network: RoadNetwork
    edges: list[np.ndarray]
    edge_segments: np.ndarray


@lru_cache(maxsize=64)
def road_geometry(layout: RoadLayout) -> RoadGeometry:
    """Lanes and edges of a layout (shared by every episode on it; nothing in it is mutated)."""
    network = build_network(layout)
    edges = road_edges(layout, network)
    return RoadGeometry(layout, network, edges, polyline_segments(edges))


@dataclass
class StepResult:
    progress: float
    """Distance gained along the route this step [m]."""
    crashed: bool
    offroad: bool
    success: bool
    timeout: bool
    ttc: float
    gap: float
    lead_gap: float
    accel: float
    """Realised longitudinal acceleration of the ego this step [m/s²]."""


class World:
    def __init__(self, log: TrafficLog, paths: Paths, cfg: HighwayConfig) -> None:
        self.log = log
        self.cfg = cfg
        self.layout = log.spec.layout
        self.geometry = road_geometry(self.layout)
        x, y, h, v = (float(a) for a in log.ego_start)
        self.ego = Vehicle(None, np.array([x, y]), heading=h, speed=v)  # highway-env bicycle model, no road lookups
        self.ego.LENGTH, self.ego.WIDTH = cfg.ego.length, cfg.ego.width
        self.traffic = Traffic(paths, cfg.traffic, cfg.dt, cfg.ego.length, cfg.ego.width)
        self.route_start = x
        self.route_end = x + log.route_length
        self.time_limit = log.time_limit
        self.t = 0.0
        self.steps = 0
        self.steer = 0.0
        """Last applied steering angle [rad] and acceleration command [m/s²]."""
        self.accel_cmd = 0.0
        self.crashed = False
        self.offroad = False
        self.angles = np.arange(cfg.sensor.beams) * (2 * np.pi / cfg.sensor.beams)
        self.lidar = self._scan()

    # -- state views --------------------------------------------------------------------------
    @property
    def ego_state(self) -> np.ndarray:
        """(x, y, heading, speed) of the ego."""
        e = self.ego
        return np.array([e.position[0], e.position[1], e.heading, e.speed])

    @property
    def progress(self) -> float:
        return float(self.ego.position[0] - self.route_start)

    @property
    def route_length(self) -> float:
        return float(self.route_end - self.route_start)

    def ego_corners(self) -> np.ndarray:
        e = self.ego
        return box_corners(
            np.array([e.position[0]]),
            np.array([e.position[1]]),
            np.array([e.heading]),
            np.array([self.cfg.ego.length]),
            np.array([self.cfg.ego.width]),
        )[0]

    def traffic_corners(self, mask: np.ndarray | None = None) -> np.ndarray:
        tr = self.traffic
        if mask is None:
            return box_corners(tr.x, tr.y, tr.heading, tr.length, tr.width)
        return box_corners(tr.x[mask], tr.y[mask], tr.heading[mask], tr.length[mask], tr.width[mask])

    def map_action(self, action: np.ndarray) -> tuple[float, float]:
        """Normalised [steer, acc] in [-1, 1]² -> (steering angle [rad], acceleration [m/s²])."""
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        if a.shape != (2,) or not np.all(np.isfinite(a)):
            raise ValueError(f"highway action must be two finite numbers [steer, acc], got {action!r}")
        lim = self.cfg.ego
        acc = a[1] * (lim.max_accel if a[1] >= 0 else lim.max_brake)
        return float(a[0] * lim.max_steer), float(acc)

    # -- the step -----------------------------------------------------------------------------
    def step(self, action: np.ndarray, sense: bool = True) -> StepResult:
        """One control period. ``sense=False`` skips the LiDAR and interaction statistics (for rollouts
        that do not need them: ``lidar`` is then stale and ``ttc``/gaps are reported as capped)."""
        steer, acc = self.map_action(action)
        dt = self.cfg.dt
        ego = self.ego
        before_x, before_v = float(ego.position[0]), float(ego.speed)
        # no reversing and no speeding beyond the vehicle's limit: clamp what the command could do
        acc = min(max(acc, -before_v / dt), (self.cfg.ego.max_speed - before_v) / dt)
        ego.act({"steering": steer, "acceleration": acc})
        ego.step(dt)
        ego.speed = min(max(float(ego.speed), 0.0), self.cfg.ego.max_speed)
        self.steer, self.accel_cmd = steer, acc
        self.traffic.step(self.ego_state)
        self.t += dt
        self.steps += 1
        self.crashed = self._collides()
        self.offroad = not self._on_road()
        s = self.cfg.sensor
        ttc, gap, lead_gap = s.ttc_cap, s.gap_cap, s.gap_cap
        if sense:
            self.lidar = self._scan()
            tr = self.traffic
            near = np.abs(tr.x - ego.position[0]) < s.gap_cap + 10.0
            ttc, gap, lead_gap = interaction_stats(
                self.ego_state,
                self.cfg.ego.length,
                self.cfg.ego.width,
                tr.x[near],
                tr.y[near],
                tr.heading[near],
                tr.speed[near],
                tr.length[near],
                tr.width[near],
                s.ttc_cap,
                s.gap_cap,
            )
        success = not (self.crashed or self.offroad) and float(ego.position[0]) >= self.route_end
        timeout = not (self.crashed or self.offroad or success) and self.t >= self.time_limit - 1e-9
        return StepResult(
            progress=float(ego.position[0]) - before_x,
            crashed=self.crashed,
            offroad=self.offroad,
            success=success,
            timeout=timeout,
            ttc=ttc,
            gap=gap,
            lead_gap=lead_gap,
            accel=(float(ego.speed) - before_v) / dt,
        )

    def _collides(self) -> bool:
        tr = self.traffic
        e = self.ego.position
        reach = (tr.length + self.cfg.ego.length) / 2 + 1.0
        near = (np.abs(tr.x - e[0]) < reach) & (np.abs(tr.y - e[1]) < reach)
        if not near.any():
            return False
        return bool(overlaps(self.ego_corners(), self.traffic_corners(near)).any())

    def _on_road(self) -> bool:
        p = self.ego.position
        lay = self.layout
        if lay.right_edge_y <= p[1] <= lay.left_edge_y and 0.0 <= p[0] <= lay.length:
            return True
        return on_road(self.geometry.network, p)

    def _scan(self) -> np.ndarray:
        """Normalised distances (1 = nothing within range) of the 72 beams, vehicles and road edges."""
        s = self.cfg.sensor
        e = self.ego.position
        tr = self.traffic
        near = np.hypot(tr.x - e[0], tr.y - e[1]) < s.range + 6.0
        segs = [segments_near(self.geometry.edge_segments, e, s.range)]
        if near.any():
            segs.append(box_segments(self.traffic_corners(near)))
        dist = ray_distances(e, self.ego.heading + self.angles, np.vstack(segs), s.range)
        return dist / s.range

    def ray_ends(self) -> np.ndarray:
        """(beams, 2) world points where the beams ended (for drawing)."""
        d = self.lidar * self.cfg.sensor.range
        ang = self.ego.heading + self.angles
        return self.ego.position[None, :] + d[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
