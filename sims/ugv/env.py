"""``sage/UGV-v0``: a differential-drive robot among static and moving obstacles (the paper's field tests).

Action: ``a`` in [-1, 1]^2, mapped to v = (a0 + 1) / 2 * v_max in [0, 0.6] m/s and w = a1 * w_max
in [-1, 1] rad/s, held for one 10 Hz control period.

Observation (58 float32): 54 lidar sectors over the front 270° (nearest range, clipped and divided
by 10 m, rightmost sector first), min(d / D_max, 1), heading error to the goal / pi, and the previous
command (v / v_max, w / w_max).

Reward: 10 (d_{t-1} - d_t) + 0.5 v - 0.5 |w| - 0.2 |w - w_{t-1}|, -100 on collision, +100 at the goal.
Cost: min(1, max(0, (1 - m) / 0.5)), m the minimum range (m) in the front cone (the 18 sectors
within ±45° of the heading, ``cost.front_fov_deg``). Ranges are measured from the robot's centre.
The episode terminates on collision or at the goal and truncates at the scenario's time limit.
With ``conflict.report`` on, each step's info also carries the true time to contact with a mover, the gap to the
nearest one and the near-miss flag (``ttc``, ``nearest_gap``, ``conflict``: :mod:`sims.ugv.interaction`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from core.scene import Box, Circle, Rays, Scene, Shape
from sims.ugv.config import UGVConfig
from sims.ugv.expert import UGVExpert
from sims.ugv.interaction import interaction_stats
from sims.ugv.lidar import NumpyLidar, ray_angles
from sims.ugv.metrics import episode_metrics
from sims.ugv.scenario import (
    Layout,
    Scenario,
    ScenarioError,
    load_scenario,
    sample_obstacles_and_movers,
    sample_start_goal,
    wall_segments,
)
from sims.ugv.world import World, WorldLidar

SECTORS = 54
"""Lidar sectors of the observation (the paper's)."""
OBS_SIZE = SECTORS + 4
INITIAL_TABLE_STEPS = 320
"""Mover poses tabulated at reset (32 s); later steps are added on demand, doubling."""
MAX_PLACEMENT_TRIES = 100
"""Draws of the start (and, failing that, the whole layout) before a scenario is declared unplayable."""


def scan_layout(config: UGVConfig | None = None) -> dict[str, Any]:
    """``world_model_config`` fields for a world model whose motion input turns the previous lidar frame to the
    current heading (:mod:`core.motion`): the first 54 channels are sectors over the front 270° (rightmost
    first), the last channel the last yaw-rate command over w_max, and one step at it turns the heading by
    w_max dt, that many sector widths. Measured (``experiments/refit_spread.py``), not a default."""
    config = config or UGVConfig()
    sector_width = math.radians(config.lidar.fov_deg) / SECTORS
    return {
        "scan_sectors": SECTORS,
        "scan_turn_channel": OBS_SIZE - 1,
        "scan_turn_sectors": config.robot.w_max * config.dt / sector_width,
    }


def ego_motion_layout(config: UGVConfig | None = None) -> dict[str, Any]:
    """``world_model_config`` fields for a world model that computes the scan's change under the robot's own motion
    and learns the residual (:class:`core.motion.EgoScanStep`): 54 sectors over the front 270° (rightmost first),
    two rays each (:func:`sims.ugv.lidar.ray_angles`), ranges over ``max_range``; the action's first channel
    drives v = (a0 + 1) / 2 v_max, its second turns at w = a1 w_max, each for one step of dt."""
    config = config or UGVConfig()
    lidar = config.lidar
    sector_width = math.radians(lidar.fov_deg) / SECTORS
    reach = config.robot.v_max * config.dt / lidar.max_range
    return {
        "ego_sectors": SECTORS,
        "ego_scan_start": -math.radians(lidar.fov_deg) / 2,
        "ego_sector_width": sector_width,
        "ego_rays_per_sector": lidar.rays_per_sector,
        "ego_forward_channel": 0,
        "ego_forward_scale": 0.5 * reach,
        "ego_forward_offset": 0.5 * reach,
        "ego_turn_channel": 1,
        "ego_turn_scale": config.robot.w_max * config.dt,
    }


COLORS = {
    "wall": "#4a4f57",
    "box": "#8a8f98",
    "circle": "#8a8f98",
    "mover": "#e0812b",
    "ego": "#2b7de0",
    "goal": "#2bb673",
}


@dataclass(frozen=True)
class Sensing:
    """What the robot senses at one step (see :meth:`UGVEnv.sensing`)."""

    pose: tuple[float, float, float]
    """Odometry: x, y (m) and heading (rad) in the map frame."""
    velocity: tuple[float, float]
    """The command being executed: linear speed (m/s) and yaw rate (rad/s)."""
    goal: tuple[float, float, float]
    """The mission goal: x, y and radius (m)."""
    ray_angles: np.ndarray
    """Angle of each lidar ray relative to the heading (rad)."""
    ranges: np.ndarray
    """Range of each ray (m); ``max_range`` where it hit nothing."""
    max_range: float


def wrap_angle(angle: float) -> float:
    """Angle in [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


class ScenarioSource(Protocol):
    """A family of whole scenarios, one drawn at each reset (e.g. :class:`sims.ugv.fields.FieldSelection`)."""

    def draw(self, rng: np.random.Generator) -> tuple[int, Scenario]:
        """The episode's scenario and its index in the family, drawn from the env's seeded generator."""
        ...

    def placeholder(self) -> Scenario:
        """A scenario that stands for the family until the first reset draws one."""
        ...


class UGVEnv(gym.Env[np.ndarray, np.ndarray]):
    """The UGV navigation env. ``scenario``: 1..4 (the paper's four field tests), a YAML file path or a generated
    :class:`ScenarioSource` that draws a whole scenario at each reset (``ugv-fields:test``: :mod:`sims.ugv.fields`,
    which the descriptor turns such a name into).

    Keyword overrides change the :class:`~sims.ugv.config.UGVConfig` with dotted names, e.g.
    ``UGVEnv(3, **{"lidar.backend": "pymunk"})`` or ``gym.make("sage/UGV-v0", scenario=2, time_limit=30)``.
    """

    metadata = {"render_modes": [], "render_fps": 10}  # noqa: RUF012 (gymnasium's convention)

    def __init__(
        self,
        scenario: int | str | Path | Scenario | ScenarioSource = 1,
        config: UGVConfig | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if render_mode is not None:
            raise ValueError("UGVEnv does not draw; use scene() and draw it in the app")
        self.config = (config or UGVConfig()).updated(overrides)
        # a time limit given here beats the scenario file's, which beats the config default
        self._time_limit_override: float | None = overrides.get("time_limit")
        if self.config.lidar.backend not in ("numpy", "pymunk"):
            raise ValueError(f"unknown lidar backend {self.config.lidar.backend!r}; choose numpy or pymunk")
        if self.config.lidar.sectors != SECTORS or self.config.lidar.fov_deg <= 0:
            raise ValueError("the observation has 54 lidar sectors (the paper's); lidar.sectors must stay 54")
        # a source (a split of generated fields) draws a whole scenario at each reset
        self.source: ScenarioSource | None = None
        self.field_index: int | None = None
        """The source's index of the current episode's scenario (None for a scenario file)."""
        if isinstance(scenario, int | str | Path | Scenario):
            self.scenario = load_scenario(scenario)
        else:
            self.source = scenario
            self.scenario = scenario.placeholder()
        self.render_mode = render_mode
        sectors = self.config.lidar.sectors
        low = np.concatenate([np.zeros(sectors), [0.0, -1.0, 0.0, -1.0]]).astype(np.float32)
        high = np.ones(OBS_SIZE, np.float32)
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)

        lidar = self.config.lidar
        angles = self._ray_angles = ray_angles(lidar)
        self._rel_dirs = np.stack([np.cos(angles), np.sin(angles)])
        # the cost's front cone: the sectors whose centre lies within it (sectors 18..35 at 90°)
        width = lidar.fov_deg / lidar.sectors
        centres = -lidar.fov_deg / 2 + (np.arange(lidar.sectors) + 0.5) * width
        front = np.flatnonzero(np.abs(centres) <= self.config.cost.front_fov_deg / 2)
        if len(front) == 0:
            raise ValueError("cost.front_fov_deg is narrower than one lidar sector")
        self._front = slice(int(front[0]), int(front[-1]) + 1)
        self._floor = 1.0 / lidar.max_range
        self._caster = NumpyLidar(lidar)
        # plain floats read at every step
        self._v_max, self._w_max = self.config.robot.v_max, self.config.robot.w_max
        rw = self.config.reward
        self._reward_weights = (rw.progress, rw.speed, rw.yaw_rate, rw.yaw_rate_change, rw.collision, rw.goal)
        self.expert = UGVExpert(self)
        self.world: World | None = None
        self.layout: Layout | None = None
        self.episode = -1
        """Resets so far, minus one: the index of the current episode."""

    # -- gymnasium -----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.world, self.layout = self._build_world()
        self.episode += 1
        cfg = self.config
        self.lidar = WorldLidar(self.world, self._caster)
        limit = self._time_limit_override or self.layout.time_limit or cfg.time_limit
        self.max_steps = max(1, round(limit * cfg.control_hz))
        x, y, yaw = self.world.pose
        self._goal = gx, gy, _ = self.layout.goal
        self._d_goal = math.hypot(gx - x, gy - y)
        self._prev_v = 0.0
        self._prev_w = 0.0
        self._xs, self._ys = [x], [y]
        self._success = self._collision = self._timeout = False
        self._scan(x, y, yaw)
        self._static_scene: list[Shape] | None = None
        self.expert.reset()
        return self._observation(x, y, yaw), self._info(cost=self._cost())

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        world = self.world
        if world is None:
            raise RuntimeError("call reset() before step()")
        try:
            a0, a1 = np.asarray(action, dtype=np.float64).reshape(2).tolist()
        except (TypeError, ValueError):
            raise ValueError(f"action must be 2 numbers in [-1, 1], got {action!r}") from None
        if not (math.isfinite(a0) and math.isfinite(a1)):
            raise ValueError(f"action must be finite, got {action!r}")
        v = (min(max(a0, -1.0), 1.0) + 1.0) * 0.5 * self._v_max
        w = min(max(a1, -1.0), 1.0) * self._w_max

        x, y, yaw = world.step(v, w)
        self._scan(x, y, yaw)
        gx, gy, goal_radius = self._goal
        d_goal = math.hypot(gx - x, gy - y)
        collision = world.collided
        success = not collision and d_goal <= goal_radius
        timeout = not (collision or success) and world.k >= self.max_steps

        progress, speed, yaw_rate, yaw_rate_change, collision_penalty, goal_bonus = self._reward_weights
        reward = progress * (self._d_goal - d_goal) + speed * v
        reward -= yaw_rate * abs(w) + yaw_rate_change * abs(w - self._prev_w)
        if collision:
            reward -= collision_penalty
        elif success:
            reward += goal_bonus
        cost = self._cost()

        self._d_goal = d_goal
        self._prev_v, self._prev_w = v, w
        self._xs.append(x)
        self._ys.append(y)
        self._collision, self._success, self._timeout = collision, success, timeout
        obs = self._observation(x, y, yaw)
        return obs, reward, collision or success, timeout, self._info(cost)

    # -- observation, cost -----------------------------------------------------------------------
    def _scan(self, x: float, y: float, yaw: float) -> None:
        """Cast the lidar; keep per-ray and per-sector inverse ranges (the nearest hit is the largest)."""
        inverse = self._inverse = self.lidar.cast(x, y, yaw)
        if len(inverse) == 2 * SECTORS:
            self._sector_inverse = np.maximum(inverse[:SECTORS], inverse[SECTORS:])
        else:
            self._sector_inverse = inverse.reshape(-1, SECTORS).max(axis=0)
        self._pose = (x, y, yaw)

    def min_front_range(self) -> float:
        """Nearest lidar range in the cost's front cone (m)."""
        return 1.0 / max(self._sector_inverse[self._front].tolist())

    def _cost(self) -> float:
        cost = self.config.cost
        return min(1.0, max(0.0, (cost.safe_range - self.min_front_range()) / cost.band))

    def _observation(self, x: float, y: float, yaw: float) -> np.ndarray:
        obs = np.empty(OBS_SIZE, np.float32)
        sectors = SECTORS
        np.divide(self._floor, self._sector_inverse, out=obs[:sectors])  # range / max_range, in [0, 1]
        gx, gy, _ = self._goal
        bearing = math.atan2(gy - y, gx - x)
        obs[sectors:] = (
            min(self._d_goal / self.config.goal_distance_max, 1.0),
            wrap_angle(bearing - yaw) / math.pi,
            self._prev_v / self._v_max,
            self._prev_w / self._w_max,
        )
        return obs

    def _info(self, cost: float) -> dict[str, Any]:
        info: dict[str, Any] = {
            "cost": cost,
            "violation": self._collision,
            "collision": self._collision,
            "success": self._success,
            "timeout": self._timeout,
            "d_goal": self._d_goal,
        }
        conflict = self.config.conflict
        if conflict.report:
            ttc, gap = self.interaction_stats()
            info.update(ttc=ttc, nearest_gap=gap, conflict=ttc < conflict.ttc or gap < conflict.gap)
        return info

    def interaction_stats(self) -> tuple[float, float]:
        """The true time to contact with a mover holding the last command, and the gap to the nearest one now
        (privileged: :mod:`sims.ugv.interaction`); inf for both on a layout without movers."""
        world, layout, cfg = self.world, self.layout, self.config
        if world is None or layout is None or not layout.movers:
            return math.inf, math.inf
        steps = max(1, round(cfg.conflict.horizon / cfg.dt))
        world.ensure_table(world.k + steps)
        return interaction_stats(
            self._pose,
            (self._prev_v, self._prev_w),
            world.mover_poses[:, world.k : world.k + steps + 1],
            layout.movers,
            cfg.robot,
            cfg.dt,
        )

    # -- episode set-up --------------------------------------------------------------------------
    def _build_world(self) -> tuple[World, Layout]:
        """Draw a layout whose start pose is free and whose goal is reachable, from the seeded generator."""
        if self.source is not None:
            self.field_index, self.scenario = self.source.draw(self.np_random)
        scenario, rng, cfg = self.scenario, self.np_random, self.config
        table_steps = INITIAL_TABLE_STEPS  # mover poses are tabulated further on demand
        walls = wall_segments(scenario)
        goal_clearance = cfg.robot.width / 2
        for _layout_try in range(MAX_PLACEMENT_TRIES):
            boxes, circles, movers = sample_obstacles_and_movers(scenario, rng)
            for _start_try in range(10):
                start, goal = sample_start_goal(scenario, rng)
                layout = Layout(
                    scenario.name, scenario.bounds, walls, boxes, circles, movers, start, goal, scenario.time_limit
                )
                world = World(cfg, layout, table_steps)
                if not world.robot_overlaps() and world.clearance_at(goal[0], goal[1], goal_clearance):
                    return world, layout
        raise ScenarioError(
            f"scenario {scenario.name!r}: no free start pose and goal found in {MAX_PLACEMENT_TRIES * 10} draws; "
            "check that the start and goal regions are not covered by obstacles"
        )

    # -- what the robot senses (for planners that may not read the layout) ---------------------------
    def sensing(self) -> Sensing:
        """The robot's own sensing now: odometry pose, the command it is executing, the mission goal and the
        full-resolution lidar scan. Nothing of the layout or the movers' scripts: what a local planner
        (:mod:`sims.ugv.teb`) may use."""
        if self.world is None:
            raise RuntimeError("call reset() before sensing()")
        return Sensing(
            pose=self._pose,
            velocity=(self._prev_v, self._prev_w),
            goal=self._goal,
            ray_angles=self._ray_angles,
            ranges=(1.0 / self._inverse.astype(np.float64)),
            max_range=self.config.lidar.max_range,
        )

    # -- the simulator protocol ------------------------------------------------------------------
    def expert_action(self) -> np.ndarray:
        """The scripted expert's normalised action (privileged: it knows the movers' scripted paths)."""
        return self.expert.act()

    def expert_engaged(self) -> bool:
        """True when the expert's last action was an evasion of a mover, which it should be left to finish."""
        return self.expert.engaged

    def metrics(self) -> dict[str, float]:
        """The paper's table row for the current (or just finished) episode; see :mod:`sims.ugv.metrics`."""
        xy = np.column_stack([self._xs, self._ys])
        return episode_metrics(
            xy, self.config.dt, success=self._success, collision=self._collision, timeout=self._timeout
        )

    def scene(self) -> Scene:
        """Plain data for drawing (see :mod:`core.scene`); static shapes are built once per episode."""
        world, layout = self.world, self.layout
        if world is None or layout is None:
            raise RuntimeError("call reset() before scene()")
        if self._static_scene is None:
            self._static_scene = self._build_static_scene()
        robot = self.config.robot
        x, y, yaw = self._pose
        k = world.k
        movers: list[Shape] = []
        if layout.movers:
            world.ensure_table(k)
            for i, mover in enumerate(layout.movers):
                mx, my, myaw = (float(v) for v in world.mover_poses[i, k])
                if mover.kind == "box":
                    movers.append(
                        Box(
                            kind="box",
                            x=mx,
                            y=my,
                            yaw=myaw,
                            length=mover.length,
                            width=mover.width,
                            color=COLORS["mover"],
                        )
                    )
                else:
                    movers.append(Circle(kind="circle", x=mx, y=my, radius=mover.radius, color=COLORS["mover"]))
        ranges = 1.0 / self._inverse.astype(float)
        c, s = math.cos(yaw), math.sin(yaw)
        dx = c * self._rel_dirs[0] - s * self._rel_dirs[1]
        dy = s * self._rel_dirs[0] + c * self._rel_dirs[1]
        ends = np.column_stack([x + ranges * dx, y + ranges * dy])
        gx, gy, gr = layout.goal
        return Scene(
            sim="ugv",
            bounds=[float(b) for b in layout.bounds],
            static_key=f"{layout.name}:{self.episode}",
            static=self._static_scene,
            movers=movers,
            ego=Box(kind="box", x=x, y=y, yaw=yaw, length=robot.length, width=robot.width, color=COLORS["ego"]),
            goal=Circle(kind="circle", x=gx, y=gy, radius=gr, color=COLORS["goal"]),
            rays=Rays(origin=[x, y], ends=ends.tolist(), hit=(ranges < self.config.lidar.max_range - 1e-6).tolist()),
            labels={
                "scenario": layout.name,
                "t": f"{world.time:.1f} s",
                "cost": f"{self._cost():.2f}",
            },
        )

    def _build_static_scene(self) -> list[Shape]:
        layout = self.layout
        assert layout is not None
        shapes: list[Shape] = []
        for a, b in layout.walls:
            shapes.append({"kind": "polyline", "points": [list(a), list(b)], "width": 0.05, "color": COLORS["wall"]})
        for box in layout.boxes:
            shape = Box(
                kind="box", x=box.x, y=box.y, yaw=box.yaw, length=box.length, width=box.width, color=COLORS["box"]
            )
            if box.label:
                shape["label"] = box.label
            shapes.append(shape)
        for circle in layout.circles:
            shapes.append(Circle(kind="circle", x=circle.x, y=circle.y, radius=circle.radius, color=COLORS["circle"]))
        return shapes
