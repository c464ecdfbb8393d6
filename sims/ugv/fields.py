"""``ugv-fields``: a procedural family of UGV fields with a seeded train/test split (the generalisation benchmark).

A field is a whole scenario (:class:`~sims.ugv.scenario.Scenario`, every value fixed) drawn from a seed: a walled
rectangle of random size, a start and a goal anywhere in it far enough apart, maybe a wall with a door or a corridor
across or along the way, static clutter (crates and posts), and 0 to 3 movers (vehicles and walkers) whose paths,
speeds and phases are drawn relative to the robot's way so that they cross it, meet it head-on, overtake it, lead it
slowly or cut in across it, timed to arrive near when the robot would (give or take a few seconds).

Names (wherever a UGV scenario name is accepted, e.g. ``--scenario ugv-fields:test``):

- ``ugv-fields:train`` / ``ugv-fields:test``: at every reset the env draws a field index from its seeded generator
  (so episode seed s always gives the same field) and plays that field of the split;
- ``ugv-fields:test:17``: field 17 of the test split at every reset;
- ``ugv-fields:test:2+``: as ``ugv-fields:test``, drawing until a field with 2 or more movers comes (``1+``, ``3+``).

The split: field ``i`` of a split is drawn from seed ``SPLIT_BASE[split] + i`` with ``0 <= i < SPLIT_SIZE``: train
seeds are ``[0, 10^9)``, test seeds ``[10^9, 2 * 10^9)``, disjoint ranges. Candidate ``j`` of a seed (``j = 0, 1,
...``) is drawn from ``numpy.random.default_rng([FAMILY_SALT, seed, j])``. A candidate is accepted when the scripted
expert (:class:`sims.ugv.expert.UGVExpert`, default config, deterministic) drives it to the goal alone without a
collision within the time limit; otherwise (or if the env cannot place the robot) the next candidate is drawn. No
field is picked or dropped by hand; :func:`field` says how many candidates a field took.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from sims.ugv.env import UGVEnv
from sims.ugv.scenario import Scenario, ScenarioError, parse_scenario

FAMILY = "ugv-fields"
Split = Literal["train", "test"]
SPLITS: tuple[Split, ...] = ("train", "test")
SPLIT_SIZE = 1_000_000_000
"""Fields per split; field i of a split has seed ``SPLIT_BASE[split] + i``."""
SPLIT_BASE: dict[str, int] = {"train": 0, "test": SPLIT_SIZE}
FAMILY_SALT = 601
"""Mixed into every candidate's generator so that these fields share no stream with episode seeds elsewhere."""
MAX_CANDIDATES = 50
"""Candidates drawn for one field before the generator gives up (none has needed more than a few)."""
TIME_LIMIT = 60.0
BEHAVIOURS = ("cross", "meet", "overtake", "lead", "cut-in")
"""What a mover does relative to the robot's way from start to goal."""
ROBOT_CRUISE = 0.45
"""m/s: about the expert's average speed, to time movers' arrival at the robot's way."""


class FieldNameError(ValueError):
    """A ``ugv-fields`` name that does not parse; the message says the accepted forms."""


@dataclass(frozen=True)
class FieldSelection:
    """What a ``ugv-fields`` name selects: a split, and one field of it or (``index`` None) a field per reset."""

    split: Split
    index: int | None = None
    min_movers: int = 0
    """Only fields with at least this many movers (a split's draw skips the others)."""

    @property
    def name(self) -> str:
        tail = f":{self.index}" if self.index is not None else f":{self.min_movers}+" if self.min_movers else ""
        return f"{FAMILY}:{self.split}{tail}"

    def draw(self, rng: np.random.Generator) -> tuple[int, Scenario]:
        """The field of this reset and its index: the fixed one, or one drawn from the env's seeded generator (the
        first drawn with at least ``min_movers`` movers)."""
        if self.index is not None:
            return self.index, field(self.split, self.index)
        while True:
            index = int(rng.integers(SPLIT_SIZE))
            if field_draw(self.split, index).movers >= self.min_movers:
                return index, field(self.split, index)

    def placeholder(self) -> Scenario:
        """The selection's first field, until the env's first reset draws one."""
        return field(self.split, self.index or 0)


def parse_field_name(name: str) -> FieldSelection | None:
    """``ugv-fields:train``, ``ugv-fields:test``, ``ugv-fields:<split>:<index>`` or ``ugv-fields:<split>:<n>+`` (only
    fields with n or more movers); None for any other name (not of this family); :class:`FieldNameError` for a name of
    the family that does not parse."""
    parts = name.strip().lower().split(":")
    if parts[0] != FAMILY:
        return None
    usage = f"give {FAMILY}:train, {FAMILY}:test, {FAMILY}:<train|test>:<index> or {FAMILY}:<train|test>:<1-3>+"
    if len(parts) not in (2, 3) or parts[1] not in SPLITS:
        raise FieldNameError(f"{name!r} is not a field name; {usage}")
    index = None
    if len(parts) == 3 and parts[2] in ("1+", "2+", "3+"):
        return FieldSelection(parts[1], min_movers=int(parts[2][0]))
    if len(parts) == 3:
        if not parts[2].isdigit() or int(parts[2]) >= SPLIT_SIZE:
            raise FieldNameError(f"{name!r}: the index must be a whole number from 0 to {SPLIT_SIZE - 1}; {usage}")
        index = int(parts[2])
    return FieldSelection(parts[1], index)


def field_seed(split: str, index: int) -> int:
    """The seed of field ``index`` of ``split`` (disjoint ranges per split)."""
    if split not in SPLIT_BASE:
        raise FieldNameError(f"unknown split {split!r}; choose train or test")
    if not 0 <= index < SPLIT_SIZE:
        raise FieldNameError(f"field index {index} is outside [0, {SPLIT_SIZE})")
    return SPLIT_BASE[split] + index


@dataclass(frozen=True)
class FieldDraw:
    """A generated field and how it was reached."""

    scenario: Scenario
    seed: int
    candidate: int
    """Index of the accepted candidate: the candidates before it were rejected by the expert filter."""
    movers: int
    behaviours: tuple[str, ...]


def field(split: str, index: int) -> Scenario:
    """Field ``index`` of ``split`` (cached; deterministic given both)."""
    return field_draw(split, index).scenario


@functools.lru_cache(maxsize=4096)
def field_draw(split: str, index: int) -> FieldDraw:
    """Draw candidates of the field's seed until the scripted expert solves one (see the module docstring)."""
    seed = field_seed(split, index)
    for candidate in range(MAX_CANDIDATES):
        rng = np.random.default_rng([FAMILY_SALT, seed, candidate])
        data, behaviours = candidate_field(rng, f"{FAMILY}:{split}:{index}")
        try:
            scenario = parse_scenario(data, source=f"{FAMILY}:{split}:{index} candidate {candidate}")
        except ScenarioError:
            continue
        if expert_solves(scenario):
            return FieldDraw(scenario, seed, candidate, len(behaviours), tuple(behaviours))
    raise ScenarioError(f"{FAMILY}:{split}:{index}: no candidate of {MAX_CANDIDATES} was solved by the expert")


def expert_solves(scenario: Scenario) -> bool:
    """Whether the scripted expert alone reaches the goal of a fixed field without a collision in its time limit."""
    try:
        env = UGVEnv(scenario)
        env.reset(seed=0)
    except ScenarioError:  # no free start pose: the field is unplayable
        return False
    while True:
        _, _, terminated, truncated, info = env.step(env.expert_action())
        if terminated or truncated:
            return bool(info["success"])


# -- drawing one candidate --------------------------------------------------------------------------------------
Vec = np.ndarray


def _clip_line(point: Vec, direction: Vec, box: tuple[float, float, float, float]) -> tuple[float, float]:
    """The parameter range [t0, t1] of ``point + t * direction`` inside ``box`` (xmin, ymin, xmax, ymax)."""
    t0, t1 = -math.inf, math.inf
    for axis, (low, high) in enumerate(((box[0], box[2]), (box[1], box[3]))):
        d = direction[axis]
        if abs(d) < 1e-9:
            if not low <= point[axis] <= high:
                return 0.0, 0.0
            continue
        a, b = (low - point[axis]) / d, (high - point[axis]) / d
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return t0, t1


def _inside(point: Vec, box: tuple[float, float, float, float]) -> Vec:
    return np.array([min(max(point[0], box[0]), box[2]), min(max(point[1], box[1]), box[3])])


def _segments_cross(a: Vec, b: Vec, c: Vec, d: Vec) -> bool:
    def orient(p: Vec, q: Vec, r: Vec) -> float:
        return float((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    return orient(a, b, c) * orient(a, b, d) < 0 and orient(c, d, a) * orient(c, d, b) < 0


def _distance_to_segment(p: Vec, a: Vec, b: Vec) -> float:
    e = b - a
    t = float(np.clip(np.dot(p - a, e) / max(float(np.dot(e, e)), 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + t * e)))


def _walls(
    rng: np.random.Generator, start: Vec, along: Vec, across: Vec, length: float, bounds: tuple[float, ...]
) -> tuple[str, list[list[list[float]]]]:
    """None, a wall across the way with a door, or a corridor along it (each polyline a list of points)."""
    kind = str(rng.choice(["open", "open", "door", "corridor"]))
    box = (bounds[0], bounds[1], bounds[2], bounds[3])
    if kind == "door":
        centre = start + rng.uniform(0.35, 0.65) * length * along
        t0, t1 = _clip_line(centre, across, box)
        gap_at = float(rng.uniform(-1.0, 1.0))
        gap = float(rng.uniform(0.9, 1.6))
        low, high = max(t0, gap_at - gap / 2), min(t1, gap_at + gap / 2)
        walls = []
        if low - t0 > 0.2:
            walls.append([_inside(centre + t0 * across, box).tolist(), (centre + low * across).tolist()])
        if t1 - high > 0.2:
            walls.append([(centre + high * across).tolist(), _inside(centre + t1 * across, box).tolist()])
        return kind, walls
    if kind == "corridor":
        first = float(rng.uniform(0.2, 0.4))
        last = first + float(rng.uniform(0.2, 0.4))
        half = float(rng.uniform(0.6, 1.0))
        offset = float(rng.uniform(-0.3, 0.3))
        walls = []
        for side in (-1.0, 1.0):
            a = start + first * length * along + (offset + side * half) * across
            b = start + last * length * along + (offset + side * half) * across
            walls.append([_inside(a, box).tolist(), _inside(b, box).tolist()])
        return kind, walls
    return kind, []


def _mover(
    rng: np.random.Generator,
    behaviour: str,
    start: Vec,
    along: Vec,
    across: Vec,
    length: float,
    inner: tuple[float, float, float, float],
) -> dict[str, Any] | None:
    """One mover of ``behaviour``, timed to reach the robot's way near when the robot would; None when its path
    does not fit the field."""
    vehicle = bool(rng.random() < 0.6)
    side = 1.0 if rng.random() < 0.5 else -1.0
    if behaviour == "cross":
        at = float(rng.uniform(0.25, 0.8))
        angle = math.radians(float(rng.uniform(50, 130)))
        direction = math.cos(angle) * along + math.sin(angle) * across * side
        meet = start + at * length * along
        t0, t1 = _clip_line(meet, direction, inner)
        path = [meet + t0 * direction, meet + t1 * direction]
    elif behaviour == "meet":
        at = float(rng.uniform(0.3, 0.6))
        far = start + float(rng.uniform(0.9, 1.1)) * length * along + float(rng.uniform(-0.5, 0.5)) * across
        near = start + float(rng.uniform(-0.1, 0.2)) * length * along + float(rng.uniform(-0.5, 0.5)) * across
        path = [far, near]
    elif behaviour == "overtake":  # from behind the robot, faster than it, beside its way
        at = float(rng.uniform(0.3, 0.6))
        offset = side * float(rng.uniform(0.3, 0.9))
        path = [
            start + float(rng.uniform(-0.3, 0.0)) * length * along + offset * across,
            start + float(rng.uniform(0.9, 1.1)) * length * along + offset * across,
        ]
    elif behaviour == "lead":  # ahead of the robot, slower than it, on its way
        at = float(rng.uniform(0.2, 0.4))
        offset = float(rng.uniform(-0.4, 0.4))
        path = [
            start + float(rng.uniform(0.15, 0.35)) * length * along + offset * across,
            start + float(rng.uniform(0.9, 1.1)) * length * along + offset * across,
        ]
    else:  # cut-in: alongside the robot's way, then diagonally across it
        at = float(rng.uniform(0.3, 0.7))
        offset = side * float(rng.uniform(0.8, 1.6))
        run_in = float(rng.uniform(0.1, 0.3))
        across_len = float(rng.uniform(0.1, 0.3))
        path = [
            start + (at - run_in) * length * along + offset * across,
            start + (at - 0.05) * length * along + offset * across,
            start + (at + across_len) * length * along - offset * across,
        ]
    margin = 0.45
    box = (inner[0] + margin, inner[1] + margin, inner[2] - margin, inner[3] - margin)
    points = [_inside(p, box) for p in path]
    travel = sum(float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(points))
    if travel < 1.0:
        return None
    if behaviour == "overtake":
        speed = float(rng.uniform(0.7, 1.0))
    elif behaviour == "lead":
        speed = float(rng.uniform(0.12, 0.3))
    else:
        speed = float(rng.uniform(0.35, 0.9) if vehicle else rng.uniform(0.2, 0.6))
    # when the robot, at about its cruise speed, is at fraction `at` of its way; the mover reaches the point of its
    # path nearest to there at that time, give or take a few seconds
    meet_point = start + at * length * along
    distances = [float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(points)]
    along_path, best, covered = 0.0, math.inf, 0.0
    for (a, b), d in zip(itertools.pairwise(points), distances, strict=True):
        for t in np.linspace(0.0, 1.0, 11):
            gap = float(np.linalg.norm(a + t * (b - a) - meet_point))
            if gap < best:
                best, along_path = gap, covered + t * d
        covered += d
    start_time = at * length / ROBOT_CRUISE - along_path / speed + float(rng.uniform(-3.0, 3.0))
    mover: dict[str, Any] = {
        "label": ("vehicle" if vehicle else "walker") + f" ({behaviour})",
        "path": [[round(float(p[0]), 3), round(float(p[1]), 3)] for p in points],
        "speed": round(speed, 3),
        "start_time": round(start_time, 2),
        "dwell": round(float(rng.uniform(0.0, 1.0)), 2),
        "loop": str(rng.choice(["pingpong", "pingpong", "once"])),
    }
    if vehicle:
        mover.update(
            kind="box", length=round(float(rng.uniform(0.5, 0.8)), 2), width=round(float(rng.uniform(0.4, 0.5)), 2)
        )
    else:
        mover.update(kind="circle", radius=round(float(rng.uniform(0.2, 0.3)), 2))
    return mover


def _mover_radius(mover: dict[str, Any]) -> float:
    if mover["kind"] == "box":
        return math.hypot(mover["length"] / 2, mover["width"] / 2)
    return float(mover["radius"])


def candidate_field(rng: np.random.Generator, name: str) -> tuple[dict[str, Any], list[str]]:
    """One candidate field as scenario data (schema: :mod:`sims.ugv.scenario`) and its movers' behaviours."""
    width, height = float(rng.uniform(8.0, 13.0)), float(rng.uniform(5.0, 8.0))
    bounds = (0.0, 0.0, round(width, 2), round(height, 2))
    margin = 0.7
    inner = (margin, margin, bounds[2] - margin, bounds[3] - margin)
    least = max(4.5, 0.5 * math.hypot(width, height))
    for _ in range(200):
        start = np.array([rng.uniform(inner[0], inner[2]), rng.uniform(inner[1], inner[3])])
        goal = np.array([rng.uniform(inner[0], inner[2]), rng.uniform(inner[1], inner[3])])
        if np.linalg.norm(goal - start) >= least:
            break
    way = goal - start
    length = float(np.linalg.norm(way))
    along = way / max(length, 1e-9)
    across = np.array([-along[1], along[0]])
    wall_kind, walls = _walls(rng, start, along, across, length, bounds)
    wall_segments = [(np.array(w[0]), np.array(w[1])) for w in walls]

    movers: list[dict[str, Any]] = []
    behaviours: list[str] = []
    for _ in range(int(rng.integers(0, 4))):
        behaviour = str(rng.choice(BEHAVIOURS))
        for _try in range(10):
            mover = _mover(rng, behaviour, start, along, across, length, inner)
            if mover is None:
                continue
            path = [np.array(p) for p in mover["path"]]
            if any(_segments_cross(a, b, c, d) for a, b in itertools.pairwise(path) for c, d in wall_segments):
                continue  # a mover does not drive through walls
            movers.append(mover)
            behaviours.append(behaviour)
            break

    obstacles: list[dict[str, Any]] = []
    for _ in range(int(rng.integers(0, 6))):
        for _try in range(20):
            x, y = float(rng.uniform(0.4, bounds[2] - 0.4)), float(rng.uniform(0.4, bounds[3] - 0.4))
            if rng.random() < 0.6:
                length_, width_ = float(rng.uniform(0.3, 1.0)), float(rng.uniform(0.3, 0.6))
                obstacle = {
                    "kind": "box",
                    "label": "crate",
                    "x": round(x, 3),
                    "y": round(y, 3),
                    "yaw_deg": round(float(rng.uniform(0, 180)), 1),
                    "length": round(length_, 2),
                    "width": round(width_, 2),
                }
                size = math.hypot(length_ / 2, width_ / 2)
            else:
                size = float(rng.uniform(0.15, 0.35))
                obstacle = {"kind": "circle", "x": round(x, 3), "y": round(y, 3), "radius": round(size, 2)}
            p = np.array([x, y])
            if np.linalg.norm(p - start) < size + 0.9 or np.linalg.norm(p - goal) < size + 0.7:
                continue
            near_mover = any(
                _distance_to_segment(p, np.array(a), np.array(b)) < size + _mover_radius(m) + 0.15
                for m in movers
                for a, b in zip(m["path"], m["path"][1:], strict=False)
            )
            if near_mover:
                continue
            obstacles.append(obstacle)
            break

    yaw = math.degrees(math.atan2(along[1], along[0])) + float(rng.uniform(-45.0, 45.0))
    description = (
        f"{len(movers)} mover(s) ({', '.join(m['label'] for m in movers) or 'none'}); {wall_kind}; "
        f"{len(obstacles)} static obstacle(s)"
    )
    data = {
        "name": name,
        "description": description,
        "bounds": list(bounds),
        "walls": [{"points": w} for w in walls],
        "obstacles": obstacles,
        "movers": movers,
        "start": {"x": round(float(start[0]), 3), "y": round(float(start[1]), 3), "yaw_deg": round(yaw, 1)},
        "goal": {"x": round(float(goal[0]), 3), "y": round(float(goal[1]), 3), "radius": 0.3},
        "time_limit": TIME_LIMIT,
    }
    return data, behaviours


# -- the expert's solve rate: python -m sims.ugv.fields ------------------------------------------------------------
def solve_rate(split: str, episodes: int, first_seed: int) -> dict[str, float]:
    """The scripted expert alone on ``ugv-fields:<split>`` as an evaluation plays it (the env from the descriptor,
    episode i at seed ``first_seed + i``): its share of episodes at the goal without a collision, and how many
    candidates the generator rejected on the way to the fields played."""
    import sims

    env = sims.descriptor("ugv").make(f"{FAMILY}:{split}")  # the path an evaluation takes
    solved = collided = rejected = 0
    movers: list[int] = []
    try:
        for i in range(episodes):
            env.reset(seed=first_seed + i)
            inner = env.unwrapped
            assert isinstance(inner, UGVEnv) and inner.field_index is not None  # a field source sets it at reset
            draw = field_draw(split, inner.field_index)
            rejected += draw.candidate
            movers.append(draw.movers)
            while True:
                _, _, terminated, truncated, info = env.step(inner.expert_action())
                if terminated or truncated:
                    break
            solved += bool(info["success"])
            collided += bool(info["collision"])
    finally:
        env.close()
    return {
        "episodes": float(episodes),
        "solved": float(solved),
        "collided": float(collided),
        "solve_rate": solved / max(episodes, 1),
        "candidates_rejected": float(rejected),
        "mean_movers": float(np.mean(movers)) if movers else math.nan,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sims.ugv.fields", description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", choices=SPLITS, default="test")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--first-seed", type=int, default=3_000_000, help="episode i resets with this seed + i")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        print("--episodes must be at least 1", file=sys.stderr)
        return 2
    r = solve_rate(args.split, args.episodes, args.first_seed)
    print(
        f"scripted expert alone on {FAMILY}:{args.split}, {int(r['episodes'])} episodes (seeds {args.first_seed}+i): "
        f"solved {int(r['solved'])} ({r['solve_rate']:.1%}), collided {int(r['collided'])}; "
        f"mean movers {r['mean_movers']:.2f}; the generator rejected {int(r['candidates_rejected'])} candidates "
        "on the way to these fields"
    )
    return 0


if __name__ == "__main__":
    # the package imported this module already (its descriptor names these fields): run that copy, whose cache of
    # drawn fields the env shares, rather than this __main__ one
    from sims.ugv.fields import main as package_main

    raise SystemExit(package_main())
