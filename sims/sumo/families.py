"""``sumo-shift``: the composite network with a route and special vehicles that no committed model was trained on
(the generalisation benchmark, issue 60).

- ``sumo-shift:train``: phase C2 (route 2 with C2's special vehicles), ground the committed policy was trained on;
- ``sumo-shift:test``: route 3 (from the south arm of junction u1a it turns onto the arterial, giving way to its
  traffic, then follows route 1 to the exit; ``data/common.rou.xml``), with route 1's flows and a busier arterial
  (``data/route3.rou.xml``), and special vehicles that behave unlike C2's (``data/special3.rou.xml``): faster and
  harder-braking emergency vehicles with more driver noise, head-on along the arterial and across the ego's start
  junction, and a slow, erratic bus, on the western corridor where C2 had none.

Each episode's traffic comes from SUMO's seed, the episode seed: the splits differ by route and vehicles, not by seed.

Two more training splits vary the traffic itself (:mod:`sims.sumo.variation`), for fitting a world model that has met
vehicles of other habits than C1's and C2's: ``sumo-shift:varied1`` (route 1) and ``:varied2`` (route 2 with C2's
special vehicles), each episode with six special-vehicle flows of random type on the route's own flows' edges and a
background density drawn between 0.7 and 1.5 times the route's. Nothing of them comes from route 3's files.
"""

from __future__ import annotations

from typing import Any

from sims.families import split_kwargs

FAMILY = "sumo-shift"
VARIED_FLOWS = 6
"""Special-vehicle flows of random type in each episode of the varied training splits."""
SPLITS: dict[str, dict[str, Any]] = {
    "train": {"route": 2, "special_vehicles": True},
    "test": {"route": 3, "special_vehicles": True},
    "varied1": {"route": 1, "random_specials": VARIED_FLOWS, "random_density": True},
    "varied2": {"route": 2, "special_vehicles": True, "random_specials": VARIED_FLOWS, "random_density": True},
}
"""Each split's ``make`` keyword arguments (:class:`~sims.sumo.config.SumoConfig` fields)."""


def family_kwargs(name: str) -> dict[str, Any] | None:
    """``make`` keyword arguments of ``FAMILY:train`` / ``:test``; None for a name outside the family."""
    return split_kwargs(name, FAMILY, SPLITS)
