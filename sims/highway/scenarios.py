"""The pool of 500 seeded logged scenarios (400 train, 100 test), recorded once and cached.

A scenario id fixes everything: the road layout (a multi-lane highway or an on-ramp merge), traffic
density and the mix of driver behaviours (normal, aggressive, defensive IDM/MOBIL drivers), and the
random draws of the traffic. Its *log* is produced by driving that traffic with highway-env's own
IDM/MOBIL vehicles (with a reference ego, itself an IDM/MOBIL driver, standing where the ego starts),
recording every surrounding vehicle's pose at 5 Hz. Episodes then replay the log (the reference ego is
kept as a prediction of a normal driver, not replayed). The log is a pure function of the id and
``LOG_VERSION``; it is cached on disk (``$SAGE_HIGHWAY_CACHE`` or ``~/.cache/sage/highway``) and in
memory, and loading it by id gives the same arrays every time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
from collections import OrderedDict
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import highway_env
import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

from sims.highway.road import Layout, RoadLayout, make_road

LOG_VERSION = 1
"""Bump when anything that changes generated logs changes (the disk cache is keyed by it and by
highway-env's version)."""
N_SCENARIOS = 500
N_TRAIN = 400
SPLIT_SEED = 2024
LOG_DT = 0.2
"""Logging period [s]; replay interpolates between frames at the control rate."""
WARMUP = 4.0
"""Traffic settles this long before recording starts, so a log starts mid-flow [s]."""
MAX_ROUTE_TIME = 18.0
"""A route must be drivable by the reference ego within this time (else it is shortened)."""
TIME_LIMIT_FACTOR = 1.4
"""The episode time limit is this many times the reference ego's time to drive the route."""
LOG_DURATION = MAX_ROUTE_TIME * TIME_LIMIT_FACTOR + 1.0
"""Recorded time: the longest time limit plus one second of look-ahead [s]."""

Split = Literal["train", "test", "all"]
BEHAVIOURS = ("normal", "aggressive", "defensive")

_BEHAVIOUR_PARAMS: dict[str, dict[str, float]] = {
    # highway-env IDMVehicle class attributes, overridden per vehicle
    "normal": {},
    "aggressive": {
        "TIME_WANTED": 0.9,
        "DISTANCE_WANTED": 7.0,
        "COMFORT_ACC_MAX": 4.0,
        "LANE_CHANGE_MIN_ACC_GAIN": 0.05,
        "LANE_CHANGE_MAX_BRAKING_IMPOSED": 3.5,
        "LANE_CHANGE_DELAY": 0.6,
    },
    "defensive": {
        "TIME_WANTED": 2.0,
        "DISTANCE_WANTED": 12.0,
        "COMFORT_ACC_MAX": 2.0,
        "POLITENESS": 0.5,
        "LANE_CHANGE_MIN_ACC_GAIN": 0.5,
        "LANE_CHANGE_MAX_BRAKING_IMPOSED": 1.5,
    },
}
_TARGET_SPEED_RANGE = {"normal": (0.8, 1.0), "aggressive": (0.95, 1.1), "defensive": (0.7, 0.9)}


@dataclass(frozen=True)
class ScenarioSpec:
    """Everything a scenario id decides before traffic is simulated."""

    scenario_id: int
    layout: RoadLayout
    spacing: float
    """Mean distance between consecutive vehicles in a lane at spawn [m] (density)."""
    behaviour_mix: tuple[float, float, float]
    """Probabilities of normal, aggressive and defensive drivers."""
    ego_lane: int
    ego_x: float
    route_length: float
    """Requested route length; shortened when even the reference ego could not drive it in time [m]."""
    seed: int

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @staticmethod
    def from_json(text: str) -> ScenarioSpec:
        data = json.loads(text)
        data["layout"] = RoadLayout(**data["layout"])
        data["behaviour_mix"] = tuple(data["behaviour_mix"])
        return ScenarioSpec(**data)


def scenario_spec(scenario_id: int) -> ScenarioSpec:
    """The spec of pool scenario ``scenario_id`` (0..499), a pure function of the id."""
    if not 0 <= int(scenario_id) < N_SCENARIOS:
        raise ValueError(f"scenario id {scenario_id} is outside the pool 0..{N_SCENARIOS - 1}")
    rng = np.random.default_rng([LOG_VERSION, int(scenario_id)])
    kind: Layout = "merge" if rng.random() < 0.3 else "highway"
    lanes = int(rng.integers(2, 4) if kind == "merge" else rng.integers(2, 5))
    speed_limit = float(rng.uniform(16.0, 30.0))
    ego_x = 200.0
    merge_start = ego_x + float(rng.uniform(60.0, 220.0))
    layout = RoadLayout(
        kind=kind,
        lanes=lanes,
        speed_limit=speed_limit,
        merge_start=merge_start,
        merge_end=merge_start + float(rng.uniform(80.0, 130.0)),
    )
    aggressive, defensive = rng.uniform(0.0, 0.4, size=2)
    mix = (float(1.0 - aggressive - defensive), float(aggressive), float(defensive))
    return ScenarioSpec(
        scenario_id=int(scenario_id),
        layout=layout,
        spacing=float(rng.uniform(24.0, 60.0)),
        behaviour_mix=mix,
        ego_lane=int(rng.integers(lanes)),
        ego_x=ego_x,
        route_length=float(rng.uniform(180.0, 300.0)),
        seed=int(rng.integers(2**31 - 1)),
    )


def scenario_ids(split: Split = "train") -> list[int]:
    """The fixed split of the pool: 400 training and 100 test scenario ids (a seeded permutation)."""
    order = np.random.default_rng(SPLIT_SEED).permutation(N_SCENARIOS)
    if split == "train":
        return sorted(int(i) for i in order[:N_TRAIN])
    if split == "test":
        return sorted(int(i) for i in order[N_TRAIN:])
    if split == "all":
        return list(range(N_SCENARIOS))
    raise ValueError(f"unknown split {split!r}; choose train, test or all")


@dataclass
class TrafficLog:
    """A recorded scenario: surrounding vehicles' poses at ``dt`` and the reference ego's drive."""

    spec: ScenarioSpec
    dt: float
    x: np.ndarray
    """(F, N) positions, headings [rad] and speeds [m/s] of the N surrounding vehicles over F frames."""
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    """(N,) vehicle lengths and widths [m]."""
    width: np.ndarray
    behaviour: np.ndarray
    """(N,) index into ``BEHAVIOURS``."""
    ego_ref: np.ndarray
    """(F, 4) the reference ego's x, y, heading, speed: a normal driver's drive through this traffic."""
    route_length: float
    time_limit: float
    """Episode time limit [s]: ``TIME_LIMIT_FACTOR`` × the reference ego's time to drive the route."""

    @property
    def frames(self) -> int:
        return int(self.x.shape[0])

    @property
    def vehicles(self) -> int:
        return int(self.x.shape[1])

    @property
    def ego_start(self) -> np.ndarray:
        return self.ego_ref[0].astype(np.float64)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ("x", "y", "heading", "speed", "length", "width", "behaviour", "ego_ref")}


def spawn_traffic(
    spec: ScenarioSpec, road: object, rng: np.random.Generator
) -> tuple[IDMVehicle, list[IDMVehicle], list[int]]:
    """Place the reference ego and the surrounding traffic of ``spec`` on ``road`` (not yet added to it)."""
    layout = spec.layout
    net = road.network  # type: ignore[attr-defined]
    main_road = ("a", "b")
    others: list[IDMVehicle] = []
    kinds: list[int] = []

    def add(lane_index: tuple[str, str, int], s: float, behaviour: int) -> None:
        lane = net.get_lane(lane_index)
        name = BEHAVIOURS[behaviour]
        lo, hi = _TARGET_SPEED_RANGE[name]
        target = layout.speed_limit * float(rng.uniform(lo, hi))
        v = IDMVehicle(
            road,
            lane.position(s, 0.0),
            heading=lane.heading_at(s),
            speed=target * float(rng.uniform(0.85, 1.0)),
            target_speed=target,
        )
        for attr, value in _BEHAVIOUR_PARAMS[name].items():
            setattr(v, attr, value)
        v.randomize_behavior()
        v.check_collisions = False
        others.append(v)
        kinds.append(behaviour)

    x_lo, x_hi = spec.ego_x - 120.0, spec.ego_x + 180.0
    for k in range(layout.lanes):
        x = x_lo + float(rng.uniform(0.0, spec.spacing))
        while x < x_hi:
            if not (k == spec.ego_lane and abs(x - spec.ego_x) < 15.0):
                add((*main_road, k), x, int(rng.choice(3, p=spec.behaviour_mix)))
            x += spec.spacing * float(rng.uniform(0.6, 1.4))
    if layout.kind == "merge":
        ramp = net.get_lane(("j", "k", 0))
        # ramp traffic timed so that it reaches the merge zone while the ego passes it
        s = float(rng.uniform(0.0, 40.0))
        while s < ramp.length - 10.0:
            add(("j", "k", 0), s, int(rng.choice(3, p=spec.behaviour_mix)))
            s += max(spec.spacing, 25.0) * float(rng.uniform(0.7, 1.3))
    lane = net.get_lane((*main_road, spec.ego_lane))
    ego_speed = layout.speed_limit * 0.9
    ego = IDMVehicle(road, lane.position(spec.ego_x, 0.0), speed=ego_speed, target_speed=layout.speed_limit)
    ego.check_collisions = False
    return ego, others, kinds


def record_log(spec: ScenarioSpec) -> TrafficLog:
    """Simulate the scenario's traffic with highway-env IDM/MOBIL vehicles and record it (no cache)."""
    rng = np.random.default_rng(spec.seed)
    road = make_road(spec.layout, rng)
    ego, others, kinds = spawn_traffic(spec, road, rng)
    road.vehicles.extend([ego, *others])
    for _ in range(round(WARMUP / LOG_DT)):
        road.act()
        road.step(LOG_DT)
    frames = round(LOG_DURATION / LOG_DT) + 1
    n = len(others)
    rec = np.zeros((frames, n, 4))
    ego_rec = np.zeros((frames, 4))
    for f in range(frames):
        if f:
            road.act()
            road.step(LOG_DT)
        rec[f] = [(v.position[0], v.position[1], v.heading, v.speed) for v in others]
        ego_rec[f] = (ego.position[0], ego.position[1], ego.heading, ego.speed)
    progress = ego_rec[:, 0] - ego_rec[0, 0]
    route_length = spec.route_length
    reached = np.flatnonzero(progress >= route_length)
    if not reached.size or reached[0] * LOG_DT > MAX_ROUTE_TIME:
        route_length = float(progress[round(MAX_ROUTE_TIME / LOG_DT)])
        arrival = MAX_ROUTE_TIME
    else:
        arrival = float(reached[0] * LOG_DT)
    time_limit = float(min(LOG_DURATION - 1.0, max(10.0, round(TIME_LIMIT_FACTOR * arrival, 1))))
    keep = min(frames, round((time_limit + 1.0) / LOG_DT) + 1)
    f32 = np.float32
    return TrafficLog(
        spec=spec,
        dt=LOG_DT,
        x=rec[:keep, :, 0].astype(f32),
        y=rec[:keep, :, 1].astype(f32),
        heading=rec[:keep, :, 2].astype(f32),
        speed=rec[:keep, :, 3].astype(f32),
        length=np.full(n, IDMVehicle.LENGTH, dtype=f32),
        width=np.full(n, IDMVehicle.WIDTH, dtype=f32),
        behaviour=np.asarray(kinds, dtype=np.int8),
        ego_ref=ego_rec[:keep].astype(f32),
        route_length=float(route_length),
        time_limit=time_limit,
    )


# -- cache ------------------------------------------------------------------------------------------
def cache_dir() -> Path:
    root = os.environ.get("SAGE_HIGHWAY_CACHE")
    base = Path(root) if root else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sage" / "highway"
    # logs are highway-env's IDM/MOBIL traffic: another highway-env version may drive differently
    return base / f"v{LOG_VERSION}-highway-env-{highway_env.__version__}"


def _cache_name(spec: ScenarioSpec) -> str:
    if 0 <= spec.scenario_id < N_SCENARIOS and spec == scenario_spec(spec.scenario_id):
        return f"scenario_{spec.scenario_id:04d}.npz"
    digest = hashlib.sha1(spec.to_json().encode()).hexdigest()[:16]
    return f"custom_{digest}.npz"


def _save(log: TrafficLog, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    meta = json.dumps(
        {"spec": log.spec.to_json(), "dt": log.dt, "route_length": log.route_length, "time_limit": log.time_limit}
    )
    with open(tmp, "wb") as fh:
        # numpy's stub lets the ** keys reach allow_pickle: bool (the keys are array names, never that)
        np.savez_compressed(fh, meta=np.array(meta), **log.arrays())  # type: ignore[arg-type]
    os.replace(tmp, path)  # atomic: a concurrent reader sees the old file or the whole new one


def _load(path: Path) -> TrafficLog:
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
        arrays = {k: data[k] for k in data.files if k != "meta"}
    return TrafficLog(
        spec=ScenarioSpec.from_json(meta["spec"]),
        dt=float(meta["dt"]),
        route_length=float(meta["route_length"]),
        time_limit=float(meta["time_limit"]),
        **arrays,
    )


_MEMORY: OrderedDict[str, TrafficLog] = OrderedDict()
_MEMORY_SIZE = 64


def load_log(scenario: int | ScenarioSpec, cache: bool = True) -> TrafficLog:
    """The log of a pool scenario (by id) or of a custom spec: from memory, disk, or recorded now."""
    spec = scenario if isinstance(scenario, ScenarioSpec) else scenario_spec(scenario)
    if not cache:
        return record_log(spec)
    name = _cache_name(spec)
    if name in _MEMORY:
        _MEMORY.move_to_end(name)
        return _MEMORY[name]
    path = cache_dir() / name
    log: TrafficLog | None = None
    if path.exists():
        try:
            log = _load(path)
            if log.spec != spec:
                log = None
        except (OSError, ValueError, KeyError):
            log = None  # a damaged cache file is simply recorded again
    if log is None:
        log = record_log(spec)
        with contextlib.suppress(OSError):  # a read-only cache costs time, not correctness
            _save(log, path)
    _MEMORY[name] = log
    while len(_MEMORY) > _MEMORY_SIZE:
        _MEMORY.popitem(last=False)
    return log


def _record_to_disk(scenario_id: int) -> int:
    load_log(scenario_id)
    _MEMORY.clear()  # a worker process only writes the cache
    return scenario_id


def warm_cache(
    ids: Iterable[int] | None = None, processes: int = 1, on_done: Callable[[int, int], None] | None = None
) -> int:
    """Record and cache on disk every pool log of ``ids`` (default: all 500) not cached yet.

    Returns how many were recorded; ``on_done(done, total)`` after each. A log takes ~1 s of CPU, so the
    whole pool ~10 minutes on one core; ``processes`` > 1 records in parallel worker processes.
    """
    todo = [
        i for i in (range(N_SCENARIOS) if ids is None else ids) if not (cache_dir() / f"scenario_{i:04d}.npz").exists()
    ]
    if processes <= 1:
        for k, i in enumerate(todo):
            load_log(i)
            if on_done is not None:
                on_done(k + 1, len(todo))
        return len(todo)
    with ProcessPoolExecutor(max_workers=processes) as pool:
        for k, _ in enumerate(pool.map(_record_to_disk, todo)):
            if on_done is not None:
                on_done(k + 1, len(todo))
    return len(todo)


def clear_memory_cache() -> None:
    """Forget logs held in memory (the disk cache stays)."""
    _MEMORY.clear()


def custom_spec(
    layout: RoadLayout,
    *,
    spacing: float = 40.0,
    behaviour_mix: tuple[float, float, float] = (0.6, 0.2, 0.2),
    ego_lane: int = 0,
    route_length: float = 300.0,
    seed: int = 0,
) -> ScenarioSpec:
    """A scenario outside the pool (benchmarks, experiments); its id is -1."""
    return ScenarioSpec(
        scenario_id=-1,
        layout=layout,
        spacing=spacing,
        behaviour_mix=behaviour_mix,
        ego_lane=ego_lane,
        ego_x=200.0,
        route_length=route_length,
        seed=seed,
    )
