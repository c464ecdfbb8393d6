"""Scenario files: schema, loading with clear errors, and seeded sampling of one episode's layout.

A scenario is a YAML file (see ``sims/ugv/scenarios/*.yaml``)::

    name: crossing
    bounds: [0, 0, 10, 6]          # xmin, ymin, xmax, ymax (m); closed by walls unless boundary_walls: false
    walls:                         # extra walls, each a polyline of line segments
      - points: [[3, 0], [3, 1.5]]
    obstacles:                     # static boxes and round obstacles
      - {kind: box, x: 4.0, y: [1.9, 2.1], yaw_deg: 0, length: 0.6, width: 1.2}
      - {kind: circle, x: 6.0, y: 4.0, radius: 0.2}
    movers:                        # obstacles on scripted paths
      - kind: box
        length: 0.6
        width: 0.45
        path: [[4.2, 0.7], [4.2, 5.3]]
        speed: [0.45, 0.55]        # m/s
        start_time: [-0.5, 0.5]    # s; the mover waits at the first waypoint until then (negative: under way)
        dwell: 0.5                 # s of pause at each end
        loop: pingpong             # pingpong (back and forth) | cycle (closed loop) | once
        shift: {x: 0, y: [-0.2, 0.2]}
    start: {x: [0.8, 1.2], y: [2.7, 3.3], yaw_deg: [-20, 20]}
    goal: {x: [7.0, 7.4], y: [2.7, 3.3], radius: 0.3}
    time_limit: 60                 # s (optional)

Any number may instead be a ``[low, high]`` range: it is drawn uniformly at every reset from the
env's seeded generator, which is how start, goal, obstacle poses and mover timings are randomised. A mover's
waypoint coordinates may be ranges too (``path: [[[3, 7], 0.6], [[3, 7], 5.4]]``: a crossing at a slant drawn
anew each episode); a path of fixed points draws nothing, so its seeded layouts do not depend on this.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, field_validator, model_validator

SCENARIO_DIR = Path(__file__).parent / "scenarios"
BUILTIN_SCENARIOS: dict[int, str] = {
    1: "1_narrow_passage.yaml",
    2: "2_detour.yaml",
    3: "3_crossing.yaml",
    4: "4_cut_in.yaml",
}
"""The paper's four field-test scenarios, by number."""


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message names the file, the field and the problem."""


def _to_range(value: Any) -> tuple[float, float]:
    """A number ``v`` becomes ``(v, v)``; a pair ``[lo, hi]`` stays a range with lo <= hi."""
    if isinstance(value, bool):
        raise ValueError(f"expected a number or a [low, high] range, got {value!r}")
    if isinstance(value, int | float):
        return float(value), float(value)
    if isinstance(value, list | tuple) and len(value) == 2:
        try:
            low, high = float(value[0]), float(value[1])
        except (TypeError, ValueError):
            raise ValueError(f"expected a number or a [low, high] range, got {value!r}") from None
        if not (math.isfinite(low) and math.isfinite(high)):
            raise ValueError(f"range {value!r} must be finite")
        if low > high:
            raise ValueError(f"range [{low}, {high}] has low > high")
        return low, high
    raise ValueError(f"expected a number or a [low, high] range, got {value!r}")


Range = Annotated[tuple[float, float], BeforeValidator(_to_range)]
"""A number or a ``[low, high]`` range drawn uniformly at each reset."""

Point = tuple[float, float]
RangePoint = tuple[Range, Range]
"""A waypoint whose coordinates may each be a ``[low, high]`` range."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class BoxObstacle(_Model):
    kind: Literal["box"]
    x: Range
    y: Range
    yaw_deg: Range = (0.0, 0.0)
    length: float = Field(gt=0, description="extent along yaw (m)")
    width: float = Field(gt=0, description="extent across yaw (m)")
    label: str | None = None


class CircleObstacle(_Model):
    kind: Literal["circle"]
    x: Range
    y: Range
    radius: float = Field(gt=0)
    label: str | None = None


Obstacle = Annotated[BoxObstacle | CircleObstacle, Field(discriminator="kind")]


class Wall(_Model):
    points: list[Point] = Field(min_length=2, description="polyline of wall segments")


class Shift(_Model):
    x: Range = (0.0, 0.0)
    y: Range = (0.0, 0.0)


class Mover(_Model):
    kind: Literal["box", "circle"] = "box"
    length: float = Field(0.6, gt=0)
    width: float = Field(0.45, gt=0)
    radius: float = Field(0.25, gt=0, description="used when kind is circle")
    path: list[RangePoint] = Field(min_length=2, description="waypoints; a coordinate may be a [low, high] range")
    speed: Range
    start_time: Range = (0.0, 0.0)
    dwell: float = Field(0.0, ge=0)
    loop: Literal["pingpong", "cycle", "once"] = "pingpong"
    shift: Shift = Shift()
    label: str | None = None

    @field_validator("speed")
    @classmethod
    def _positive_speed(cls, value: tuple[float, float]) -> tuple[float, float]:
        if value[0] <= 0:
            raise ValueError(f"speed must be positive, got {list(value)}")
        return value

    @model_validator(mode="after")
    def _path_has_length(self) -> Mover:
        # a path with a ranged point can only be judged once drawn (sampling keeps a coinciding draw moving)
        fixed = all(low == high for point in self.path for low, high in point)
        points = [(x[0], y[0]) for x, y in self.path]
        if fixed and sum(math.dist(a, b) for a, b in itertools.pairwise(points)) <= 0:
            raise ValueError("path has zero length")
        return self


class StartSpec(_Model):
    x: Range
    y: Range
    yaw_deg: Range = (0.0, 0.0)


class GoalSpec(_Model):
    x: Range
    y: Range
    radius: float = Field(0.3, gt=0)


class Scenario(_Model):
    name: str
    description: str = ""
    bounds: tuple[float, float, float, float]
    boundary_walls: bool = True
    walls: list[Wall] = []
    obstacles: list[Obstacle] = []
    movers: list[Mover] = []
    start: StartSpec
    goal: GoalSpec
    time_limit: float | None = Field(None, gt=0)

    @field_validator("bounds")
    @classmethod
    def _bounds_ordered(cls, b: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        if not (b[0] < b[2] and b[1] < b[3]):
            raise ValueError(f"bounds must be [xmin, ymin, xmax, ymax] with xmin < xmax and ymin < ymax, got {list(b)}")
        return b

    @model_validator(mode="after")
    def _inside_bounds(self) -> Scenario:
        problems = []
        xmin, ymin, xmax, ymax = self.bounds

        def check(where: str, axis: str, value: tuple[float, float], pad: float = 0.0) -> None:
            low, high = (xmin, xmax) if axis == "x" else (ymin, ymax)
            if value[0] < low + pad or value[1] > high - pad:
                inner = f" (keeping {pad:g} m from the edge)" if pad else ""
                problems.append(
                    f"{where}.{axis}: {_fmt(value)} lies outside the map bounds {axis} in [{low:g}, {high:g}]{inner}"
                )

        for axis in ("x", "y"):
            check("start", axis, getattr(self.start, axis))
            check("goal", axis, getattr(self.goal, axis), pad=self.goal.radius)
            for i, obstacle in enumerate(self.obstacles):
                check(f"obstacles.{i}", axis, getattr(obstacle, axis))
        for i, wall in enumerate(self.walls):
            for j, point in enumerate(wall.points):
                for axis, value in zip(("x", "y"), point, strict=True):
                    check(f"walls.{i}.points.{j}", axis, (value, value))
        for i, mover in enumerate(self.movers):
            shift = mover.shift
            for j, (px, py) in enumerate(mover.path):
                check(f"movers.{i}.path.{j}", "x", (px[0] + shift.x[0], px[1] + shift.x[1]))
                check(f"movers.{i}.path.{j}", "y", (py[0] + shift.y[0], py[1] + shift.y[1]))
        if problems:
            raise ValueError("; ".join(problems))
        return self


def _fmt(value: tuple[float, float]) -> str:
    return f"{value[0]:g}" if value[0] == value[1] else f"[{value[0]:g}, {value[1]:g}]"


def resolve_scenario_path(scenario: int | str | Path) -> Path:
    """``1``..``4`` (or ``"3"``) name a built-in scenario; anything else is a path to a YAML file."""
    if isinstance(scenario, str) and scenario.strip().isdigit():
        scenario = int(scenario)
    if isinstance(scenario, int) and not isinstance(scenario, bool):
        if scenario not in BUILTIN_SCENARIOS:
            raise ScenarioError(
                f"unknown scenario number {scenario}; built-in scenarios are "
                + ", ".join(f"{k} ({v})" for k, v in BUILTIN_SCENARIOS.items())
            )
        return SCENARIO_DIR / BUILTIN_SCENARIOS[scenario]
    if isinstance(scenario, bool):  # an int to Python, but no scenario number
        raise TypeError(f"scenario must be a built-in scenario number or a YAML path, got {scenario!r}")
    return Path(scenario)


def load_scenario(scenario: int | str | Path | Scenario) -> Scenario:
    """Load and validate a scenario; a :class:`ScenarioError` names the file, field and problem."""
    if isinstance(scenario, Scenario):
        return scenario
    path = resolve_scenario_path(scenario)
    if not path.is_file():
        raise ScenarioError(f"{path}: scenario file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{path}: not valid YAML: {exc}") from None
    return parse_scenario(data, source=str(path))


def parse_scenario(data: Any, source: str = "<scenario>") -> Scenario:
    """Validate already-parsed YAML data."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: a scenario must be a mapping of fields, got {type(data).__name__}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        lines = []
        for err in exc.errors(include_url=False):
            loc = ".".join(str(part) for part in err["loc"])
            msg = err["msg"].removeprefix("Value error, ")
            lines.append(f"{loc}: {msg}" if loc else msg)
        raise ScenarioError(f"{source}: invalid scenario:\n  " + "\n  ".join(lines)) from None


# -- one episode's layout ------------------------------------------------------------------------


@dataclass(frozen=True)
class BoxPose:
    x: float
    y: float
    yaw: float
    length: float
    width: float
    label: str | None = None


@dataclass(frozen=True)
class CirclePose:
    x: float
    y: float
    radius: float
    label: str | None = None


@dataclass(frozen=True)
class MoverPlan:
    """A mover with its randomised values drawn: everything needed to compute its pose at any time."""

    kind: Literal["box", "circle"]
    length: float
    width: float
    radius: float
    path: np.ndarray
    """(n, 2) waypoints after the random shift."""
    speed: float
    start_time: float
    dwell: float
    loop: Literal["pingpong", "cycle", "once"]
    label: str | None = None

    @property
    def bounding_radius(self) -> float:
        return math.hypot(self.length / 2, self.width / 2) if self.kind == "box" else self.radius

    def poses(self, times: np.ndarray) -> np.ndarray:
        """(len(times), 3) array of x, y, yaw at the given times (s since the episode start)."""
        path = self.path
        if self.loop == "cycle":
            path = np.vstack([path, path[:1]])
        seg = np.diff(path, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        cum = np.concatenate([[0.0], np.cumsum(seg_len)])
        total = cum[-1]
        travel = total / self.speed
        tau = np.maximum(np.asarray(times, dtype=float) - self.start_time, 0.0)
        backwards = np.zeros(tau.shape, dtype=bool)
        if self.loop == "once":
            s = np.minimum(tau * self.speed, total)
        elif self.loop == "cycle":
            phase = np.mod(tau, travel + self.dwell)
            s = np.clip(phase - self.dwell, 0.0, travel) * self.speed
        else:  # pingpong: out, dwell, back, dwell
            period = 2 * (travel + self.dwell)
            phase = np.mod(tau, period)
            half = travel + self.dwell
            backwards = phase >= half
            leg = np.where(backwards, phase - half, phase)
            s_leg = np.minimum(leg, travel) * self.speed
            s = np.where(backwards, total - s_leg, s_leg)
        x = np.interp(s, cum, path[:, 0])
        y = np.interp(s, cum, path[:, 1])
        # heading of the segment being travelled (a segment's own direction, turned around on the way back)
        idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        idx = np.where(backwards, np.clip(np.searchsorted(cum, s, side="left") - 1, 0, len(seg) - 1), idx)
        yaw = np.arctan2(seg[idx, 1], seg[idx, 0]) + np.where(backwards, math.pi, 0.0)
        return np.stack([x, y, yaw], axis=1)


@dataclass(frozen=True)
class Layout:
    """One episode's world, drawn from a :class:`Scenario` with a seeded generator."""

    name: str
    bounds: tuple[float, float, float, float]
    walls: list[tuple[Point, Point]]
    """Wall segments (two-sided line segments), boundary included."""
    boxes: list[BoxPose]
    circles: list[CirclePose]
    movers: list[MoverPlan]
    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    """x, y, radius."""
    time_limit: float | None


def _draw(rng: np.random.Generator, value: tuple[float, float]) -> float:
    return value[0] if value[0] == value[1] else float(rng.uniform(value[0], value[1]))


def sample_obstacles_and_movers(
    scenario: Scenario, rng: np.random.Generator
) -> tuple[list[BoxPose], list[CirclePose], list[MoverPlan]]:
    boxes: list[BoxPose] = []
    circles: list[CirclePose] = []
    for obstacle in scenario.obstacles:
        if isinstance(obstacle, BoxObstacle):
            yaw = math.radians(_draw(rng, obstacle.yaw_deg))
            boxes.append(
                BoxPose(
                    _draw(rng, obstacle.x), _draw(rng, obstacle.y), yaw, obstacle.length, obstacle.width, obstacle.label
                )
            )
        else:
            circles.append(CirclePose(_draw(rng, obstacle.x), _draw(rng, obstacle.y), obstacle.radius, obstacle.label))
    movers = []
    for mover in scenario.movers:
        # fixed coordinates draw nothing, so a scenario without ranges in its paths keeps its seeded layouts
        path = np.array([[_draw(rng, x), _draw(rng, y)] for x, y in mover.path])
        if not np.any(np.hypot(*np.diff(path, axis=0).T) > 1e-6):
            # ranged waypoints that happened to coincide: stretch the last one so the mover still moves
            path[-1] += (1e-3, 0.0)
        shift = np.array([_draw(rng, mover.shift.x), _draw(rng, mover.shift.y)])
        movers.append(
            MoverPlan(
                kind=mover.kind,
                length=mover.length,
                width=mover.width,
                radius=mover.radius,
                path=path + shift,
                speed=_draw(rng, mover.speed),
                start_time=_draw(rng, mover.start_time),
                dwell=mover.dwell,
                loop=mover.loop,
                label=mover.label,
            )
        )
    return boxes, circles, movers


def sample_start_goal(
    scenario: Scenario, rng: np.random.Generator
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    start = (
        _draw(rng, scenario.start.x),
        _draw(rng, scenario.start.y),
        math.radians(_draw(rng, scenario.start.yaw_deg)),
    )
    goal = (_draw(rng, scenario.goal.x), _draw(rng, scenario.goal.y), scenario.goal.radius)
    return start, goal


def wall_segments(scenario: Scenario) -> list[tuple[Point, Point]]:
    segments: list[tuple[Point, Point]] = []
    if scenario.boundary_walls:
        x0, y0, x1, y1 = scenario.bounds
        corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
        segments += list(itertools.pairwise(corners))
    for wall in scenario.walls:
        segments += [(a, b) for a, b in itertools.pairwise(wall.points) if a != b]
    return segments


def sample_layout(scenario: Scenario, rng: np.random.Generator) -> Layout:
    """Draw every range of the scenario once (obstacles and movers first, then start and goal)."""
    boxes, circles, movers = sample_obstacles_and_movers(scenario, rng)
    start, goal = sample_start_goal(scenario, rng)
    return Layout(
        name=scenario.name,
        bounds=scenario.bounds,
        walls=wall_segments(scenario),
        boxes=boxes,
        circles=circles,
        movers=movers,
        start=start,
        goal=goal,
        time_limit=scenario.time_limit,
    )
