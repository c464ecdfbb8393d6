"""``pedestrian-shift``: the occluded crossing with its parameters inside (train) or outside (test) the training ranges
(the generalisation benchmark, issue 60).

- ``pedestrian-shift:train``: a pedestrian in every episode, parked cars (0-4) as in the training mix, every range the
  training default (truck 10 m x 2.5 m, walking 1.0-1.8 m/s, waiting 0.4-1.2 m past the truck's front, stepping out
  when the ego is 12-22 m behind);
- ``pedestrian-shift:test``: a larger occluder (a 14 m x 2.9 m truck), a pedestrian who runs (1.9-2.4 m/s), waits
  further out (1.3-2.0 m past the truck's front) and steps out later (the ego 9-11.5 m behind): every range disjoint
  from training's.

Each episode draws its values from the env's seeded generator (episode seed s: the same draw), within the split's
ranges: the two splits differ by their ranges, which do not overlap, rather than by seed. The test ranges were chosen
so that the scripted expert alone still avoids the pedestrian (``tests/sims/pedestrian/test_families.py`` checks a
sample of both splits).
"""

from __future__ import annotations

from typing import Any

from sims.families import split_kwargs

FAMILY = "pedestrian-shift"
SPLITS: dict[str, dict[str, Any]] = {
    "train": {"pedestrian_probability": 1.0, "parked_vehicles": (0, 4)},
    "test": {
        "pedestrian_probability": 1.0,
        "parked_vehicles": (0, 4),
        "truck_length": 14.0,
        "truck_width": 2.9,
        "pedestrian_speed": (1.9, 2.4),
        "pedestrian_ahead": (1.3, 2.0),
        "trigger_distance": (9.0, 11.5),
    },
}
"""Each split's ``make`` keyword arguments (:class:`~sims.pedestrian.config.PedestrianConfig` fields)."""


def family_kwargs(name: str) -> dict[str, Any] | None:
    """``make`` keyword arguments of ``FAMILY:train`` / ``:test``; None for a name outside the family."""
    return split_kwargs(name, FAMILY, SPLITS)
