"""``highway-shift``: highway traffic drawn from a seed, with a train split inside the pool's ranges and a test split
outside them (the generalisation benchmark, issue 60).

- ``highway-shift:train``: specs drawn from the logged pool's own ranges (speed limit 16-30 m/s, 24-60 m between
  vehicles in a lane, at most 40% aggressive and 40% defensive drivers), replayed (``mode="normal"``);
- ``highway-shift:test``: outside them: denser (12-22 m between vehicles), faster (31-36 m/s) and more aggressive
  drivers (45-80%, at most 15% defensive: more and sharper cut-ins, their lane-change parameters being highway-env's
  aggressive ones), replayed;
- ``highway-shift:<split>:<index>``: that one spec at every reset.

Spec ``index`` of a split (0 <= index < 10^9) has seed ``index`` for train and ``10^9 + index`` for test (disjoint
ranges); its candidate ``j = 0, 1, ...`` is drawn from ``numpy.random.default_rng([602, seed, j])``, and the first
candidate that the scripted expert alone drives (replayed, deterministic) without a collision or leaving the road is
the spec: as for ``ugv-fields``, the generator rejects what the expert cannot drive, nobody picks by hand. The spec's
``scenario_id`` is ``10^6 + seed`` (outside the pool's 0-499, so its log is cached under its own hash). Layout kind,
lanes, merge geometry, ego lane and route length are drawn as the pool draws them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from sims.highway.env import HighwayEnv
from sims.highway.road import Layout, RoadLayout
from sims.highway.scenarios import ScenarioSpec

FAMILY = "highway-shift"
Split = Literal["train", "test"]
SPLITS: tuple[Split, ...] = ("train", "test")
SPLIT_SIZE = 1_000_000_000
SPLIT_BASE = {"train": 0, "test": SPLIT_SIZE}
FAMILY_SALT = 602
ID_BASE = 1_000_000
"""A family spec's ``scenario_id`` is ``ID_BASE + seed``: never a pool id."""


@dataclass(frozen=True)
class Ranges:
    speed_limit: tuple[float, float]
    spacing: tuple[float, float]
    aggressive: tuple[float, float]
    defensive: tuple[float, float]


RANGES: dict[str, Ranges] = {
    "train": Ranges(speed_limit=(16.0, 30.0), spacing=(24.0, 60.0), aggressive=(0.0, 0.4), defensive=(0.0, 0.4)),
    "test": Ranges(speed_limit=(31.0, 36.0), spacing=(12.0, 22.0), aggressive=(0.45, 0.8), defensive=(0.0, 0.15)),
}
ENV_KWARGS: dict[str, dict[str, Any]] = {"train": {"mode": "normal"}, "test": {"mode": "normal"}}
"""What else each split sets on the env."""


class FamilyNameError(ValueError):
    """A ``highway-shift`` name that does not parse."""


def spec_seed(split: str, index: int) -> int:
    if split not in SPLIT_BASE:
        raise FamilyNameError(f"unknown split {split!r}; choose train or test")
    if not 0 <= index < SPLIT_SIZE:
        raise FamilyNameError(f"index {index} is outside [0, {SPLIT_SIZE})")
    return SPLIT_BASE[split] + index


MAX_CANDIDATES = 50


@functools.lru_cache(maxsize=4096)
def family_spec(split: str, index: int) -> ScenarioSpec:
    """Spec ``index`` of ``split``, a pure function of both: its first candidate the expert drives (see above)."""
    seed = spec_seed(split, index)
    for candidate in range(MAX_CANDIDATES):
        spec = candidate_spec(split, seed, candidate)
        if expert_drives(spec):
            return spec
    raise ValueError(f"{FAMILY}:{split}:{index}: no candidate of {MAX_CANDIDATES} was driven by the expert")


def expert_drives(spec: ScenarioSpec) -> bool:
    """Whether the scripted expert alone drives the spec's replay without a collision or leaving the road."""
    env = HighwayEnv(custom_spec=spec, mode="normal")
    env.reset(seed=0)
    while True:
        _, _, terminated, truncated, _ = env.step(env.expert_action())
        if terminated or truncated:
            metrics = env.metrics()
            return not (metrics["collision"] or metrics["off_road"])


def candidate_spec(split: str, seed: int, candidate: int) -> ScenarioSpec:
    """Candidate ``candidate`` of the spec with ``seed``, drawn within ``split``'s ranges."""
    ranges = RANGES[split]
    rng = np.random.default_rng([FAMILY_SALT, seed, candidate])
    kind: Layout = "merge" if rng.random() < 0.3 else "highway"
    lanes = int(rng.integers(2, 4) if kind == "merge" else rng.integers(2, 5))
    ego_x = 200.0
    merge_start = ego_x + float(rng.uniform(60.0, 220.0))
    layout = RoadLayout(
        kind=kind,
        lanes=lanes,
        speed_limit=float(rng.uniform(*ranges.speed_limit)),
        merge_start=merge_start,
        merge_end=merge_start + float(rng.uniform(80.0, 130.0)),
    )
    aggressive, defensive = float(rng.uniform(*ranges.aggressive)), float(rng.uniform(*ranges.defensive))
    return ScenarioSpec(
        scenario_id=ID_BASE + seed,
        layout=layout,
        spacing=float(rng.uniform(*ranges.spacing)),
        behaviour_mix=(1.0 - aggressive - defensive, aggressive, defensive),
        ego_lane=int(rng.integers(lanes)),
        ego_x=ego_x,
        route_length=float(rng.uniform(180.0, 300.0)),
        seed=int(rng.integers(2**31 - 1)),
    )


@dataclass(frozen=True)
class SpecSelection:
    """A split of the family, one spec of it (``index``) or one drawn at each reset (None)."""

    split: Split
    index: int | None = None

    @property
    def name(self) -> str:
        return f"{FAMILY}:{self.split}" + ("" if self.index is None else f":{self.index}")

    def draw(self, rng: np.random.Generator) -> tuple[int, ScenarioSpec]:
        """This reset's spec and its index: the fixed one, or one drawn from the env's seeded generator."""
        index = self.index if self.index is not None else int(rng.integers(SPLIT_SIZE))
        return index, family_spec(self.split, index)

    def env_kwargs(self) -> dict[str, Any]:
        """``make`` keyword arguments of this selection."""
        return {"spec_source": self, **ENV_KWARGS[self.split]}


def parse_family_name(name: str) -> SpecSelection | None:
    """``highway-shift:train``, ``highway-shift:test`` or ``highway-shift:<split>:<index>``; None for a name outside
    the family; :class:`FamilyNameError` for one of it that does not parse."""
    parts = name.strip().lower().split(":")
    if parts[0] != FAMILY:
        return None
    usage = f"give {FAMILY}:train, {FAMILY}:test or {FAMILY}:<train|test>:<index>"
    if len(parts) not in (2, 3) or parts[1] not in SPLITS:
        raise FamilyNameError(f"{name!r} is not a {FAMILY} name; {usage}")
    index = None
    if len(parts) == 3:
        if not parts[2].isdigit() or int(parts[2]) >= SPLIT_SIZE:
            raise FamilyNameError(f"{name!r}: the index must be a whole number from 0 to {SPLIT_SIZE - 1}; {usage}")
        index = int(parts[2])
    return SpecSelection(parts[1], index)
