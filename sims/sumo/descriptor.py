"""What the rest of the product knows about the SUMO simulator (:class:`core.descriptor.SimDescriptor`)."""

from __future__ import annotations

from typing import Any
from xml.etree import ElementTree

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor
from sims.sumo.config import SumoConfig
from sims.sumo.families import FAMILY, SPLITS, family_kwargs

METRIC_COLUMNS = ("success", "collision", "red_light", "timeout", "route_progress", "speed_mean")

SCENARIOS = (
    ScenarioSpec("c1", "C1 · route 1", {"route": 1, "special_vehicles": False}),
    ScenarioSpec("c2", "C2 · route 2 + special vehicles (route shift)", {"route": 2, "special_vehicles": True}),
    ScenarioSpec("1", "route 1", {"route": 1, "special_vehicles": False}),
    ScenarioSpec("2", "route 2", {"route": 2, "special_vehicles": False}),
    ScenarioSpec("1-special", "route 1 · special vehicles", {"route": 1, "special_vehicles": True}),
)


def vehicle_length(type_id: str) -> float:
    """The length (m) of a vehicle type of the routes' common file (``data/common.rou.xml``)."""
    from sims.sumo.network import DATA_DIR

    for vtype in ElementTree.parse(DATA_DIR / "common.rou.xml").getroot().iter("vType"):
        if vtype.get("id") == type_id:
            return float(vtype.get("length", "5.0"))  # SUMO's default length
    raise ValueError(f"no vehicle type {type_id!r} in {DATA_DIR / 'common.rou.xml'}")


def contact_floors(config: SumoConfig | None = None) -> tuple[float, ...]:
    """The observation's first channel is the leader's centre distance over the perception range
    (:func:`sims.sumo.sensing.observe`): at or under half the ego's length plus half a car's, a car ahead touches the
    ego. One floor, for that channel only: the others (the leader's heading, speed and bearing, the other sectors) say
    nothing of contact by themselves. A longer leader touches further out (a bus or truck at (4.5 + 12) / 2 m); the
    common car's floor keeps a queue at standstill (the ego's minGap behind its leader) above it."""
    config = config or SumoConfig()
    return ((vehicle_length("ego") + vehicle_length("car")) / 2.0 / config.perception_range,)


def _family_scenario(name: str) -> dict[str, Any]:
    """A name outside the named scenarios: ``sumo-shift:train`` / ``:test`` (:mod:`sims.sumo.families`)."""
    kwargs = family_kwargs(name)
    if kwargs is None:
        splits = " or ".join(f"{FAMILY}:{split}" for split in SPLITS)
        raise ValueError(f"choose one of {', '.join(spec.name for spec in SCENARIOS)}, {splits}")
    return kwargs


DESCRIPTOR = SimDescriptor(
    name="sumo",
    title="SUMO (composite route, route shift)",
    env_id="sage/Sumo-v0",
    entry_point="sims.sumo:make_sumo_env",
    dt=SumoConfig().step_length,
    scenarios=SCENARIOS,
    default_scenario="c1",
    # the ego is driven longitudinally only: accelerate / brake
    input_mapping=InputMapping(throttle_index=0, steer_index=None),
    metric_columns=METRIC_COLUMNS,
    safe_action=(-1.0,),  # full braking
    contact_floors=contact_floors(),
    # libsumo holds the GIL while it steps, which would stall the server's event loop and the page's input
    live_options={"process": True},
    parse_scenario=_family_scenario,  # sumo-shift:train / :test (sims/sumo/families.py)
)
