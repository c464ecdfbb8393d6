"""Every default of the UGV simulation in one place: robot, control, lidar, reward, cost, expert.

Values follow the paper's field tests where it gives them (270° lidar in 54 sectors normalised by
10 m, 10 Hz control, the reward and cost weights); the rest describe a small indoor robot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

from core.dotted import replaced


@dataclass(frozen=True)
class RobotConfig:
    length: float = 0.5
    """Footprint along the heading (m)."""
    width: float = 0.4
    """Footprint across the heading (m)."""
    v_max: float = 0.6
    """Top linear speed (m/s); the robot does not reverse, so v is in [0, v_max]."""
    w_max: float = 1.0
    """Top yaw rate (rad/s); w is in [-w_max, w_max]."""

    @property
    def circumradius(self) -> float:
        """Radius of the circle around the footprint (what a corner sweeps when turning in place)."""
        return math.hypot(self.length / 2, self.width / 2)


@dataclass(frozen=True)
class LidarConfig:
    fov_deg: float = 270.0
    """Field of view, centred on the heading."""
    sectors: int = 54
    """Sectors of the observation; each holds the nearest range of its rays."""
    rays_per_sector: int = 2
    """Rays cast per sector (2 keeps a 0.4 m obstacle visible out to 9 m)."""
    max_range: float = 10.0
    """Ranges are clipped to this and divided by it in the observation."""
    backend: Literal["numpy", "pymunk"] = "numpy"
    """``numpy``: vectorised ray casting (fast); ``pymunk``: one ``segment_query_first`` per ray (reference)."""

    @property
    def n_rays(self) -> int:
        return self.sectors * self.rays_per_sector


@dataclass(frozen=True)
class RewardConfig:
    """r = 10 (d_{t-1} - d_t) + 0.5 v - 0.5 |w| - 0.2 |w - w_{t-1}| - 100 collision + 100 goal."""

    progress: float = 10.0
    speed: float = 0.5
    yaw_rate: float = 0.5
    yaw_rate_change: float = 0.2
    collision: float = 100.0
    goal: float = 100.0


@dataclass(frozen=True)
class CostConfig:
    """c = min(1, max(0, (safe_range - m) / band)), m the minimum range in the front cone (m)."""

    safe_range: float = 1.0
    band: float = 0.5
    front_fov_deg: float = 90.0
    """Width of the front cone whose minimum range enters the cost (the paper's "front laser")."""


@dataclass(frozen=True)
class ExpertConfig:
    """The scripted expert: a grid planner over static obstacles, pure pursuit, yielding to movers."""

    grid_resolution: float = 0.1
    """Cell size of the planning grid (m)."""
    inflation: float = 0.3
    """Cells closer than this to a static obstacle are not traversable (m)."""
    preferred_clearance: float = 0.8
    """Clearance below which a cell costs extra, so paths keep to the middle of passages (m)."""
    clearance_weight: float = 3.0
    """Extra cost factor of a cell touching an obstacle's inflation."""
    lookahead: float = 0.5
    """Pure-pursuit lookahead distance (m)."""
    turn_in_place_deg: float = 60.0
    """Above this heading error to the lookahead point the robot turns on the spot."""
    clear_horizon: float = 0.6
    """Commands whose arc would graze a static obstacle this soon are slowed and turned harder (s)."""
    stall_time: float = 4.0
    """Without getting closer to the goal this long (and not yielding), drive out along the clearest arc (s)."""
    replan_distance: float = 0.35
    """Re-extract the path when the robot is farther than this from it (m)."""
    speed_caps: tuple[float, ...] = (0.6, 0.45, 0.3, 0.15, 0.0)
    """Candidate speed limits tried against the movers' future, fastest first (m/s)."""
    go_horizon: float = 8.0
    """A speed cap is taken only if driving on along the path at it stays clear of movers this long (s)."""
    stop_horizon: float = 10.0
    """Failing that, the robot moves at most one step, to where standing still stays clear this long (s)."""
    evade_time: float = 1.0
    """Where no speed along the path keeps clear of a mover (a takeover in its way), the expert leaves the path by
    the manoeuvre that keeps clear longest (``sims/ugv/expert.py``); its arcs and straight runs last this long (s)
    before it stops and replans."""
    yield_to_movers: bool = True
    """False makes the expert a goal seeker blind to movers (the same planner and tracker): demonstrations that run
    into movers, the collision-rich data a world model needs to learn what a closing mover means (``sage train
    --set env.expert.yield_to_movers=false``)."""
    evade_turns: tuple[float, ...] = (0.3, 0.6, 1.0, 1.5, 2.0, 2.5)
    """Durations of the turns on the spot (either way) that precede a straight run among the evasive manoeuvres
    (s): a robot facing the wrong way, with no reverse gear, leaves a mover's sweep so. () keeps to arcs alone."""
    mover_margin: float = 0.12
    """Extra gap kept to movers beyond the touching distance of the two bounding circles (m)."""
    detour_after: float = 1.0
    """After yielding this long (s), the expert plans a way around the movers in its way: the grid of the static
    obstacles plus each mover's bounding circle over the next ``detour_horizon``. It takes that path if a faster
    speed keeps clear along it than along its own (the same check as every step), so a mover going its way slowly
    is passed rather than trailed, and a crossing one may be passed behind. inf never detours (the yielding expert
    before detours existed)."""
    detour_horizon: float = 3.0
    """How far ahead the movers' sweep is laid on the detour's grid (s)."""


@dataclass(frozen=True)
class ConflictConfig:
    """A step is a near miss with a mover (``info["conflict"]``; no cost, no reward) when the robot, holding its
    command, would touch a mover within ``ttc`` or is within ``gap`` of one now (:mod:`sims.ugv.interaction`),
    reported where ``report`` is on (``--set env.conflict.report=true``)."""

    ttc: float = 2.0
    """Time to contact under which a step is a conflict (s): the horizon of the UGV world model's violation label
    (``violation_steps=20`` at 10 Hz), so a near miss means what a collision soon means to it."""
    gap: float = 0.12
    """Gap to a mover under which a step is a conflict (m): the margin the scripted expert keeps
    (``expert.mover_margin``)."""
    horizon: float = 3.0
    """How far ahead the time to contact is looked for (s); ``info["ttc"]`` is inf beyond it."""
    report: bool = False
    """Put ``ttc``, ``nearest_gap`` and ``conflict`` in every step's info. Off by default: on a layout with movers
    the time to contact (a rollout against every mover) costs more than the rest of the step."""


@dataclass(frozen=True)
class UGVConfig:
    """Configuration of :class:`sims.ugv.env.UGVEnv`. Scenario files hold the layout, this the robot."""

    robot: RobotConfig = field(default_factory=RobotConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    cost: CostConfig = field(default_factory=CostConfig)
    expert: ExpertConfig = field(default_factory=ExpertConfig)
    conflict: ConflictConfig = field(default_factory=ConflictConfig)
    control_hz: float = 10.0
    """Rate of actions (the paper's 10 Hz)."""
    physics_substeps: int = 6
    """pymunk steps per action; collisions are detected at each."""
    goal_distance_max: float = 10.0
    """D_max of the normalised goal distance min(d / D_max, 1) (m)."""
    time_limit: float = 60.0
    """Episode length before truncation (s), unless the scenario file sets its own."""

    @property
    def dt(self) -> float:
        return 1.0 / self.control_hz

    def updated(self, overrides: dict[str, Any]) -> UGVConfig:
        """A copy with dotted overrides applied, e.g. ``{"lidar.backend": "pymunk", "time_limit": 30}``."""
        return replaced(self, overrides, "UGV")
