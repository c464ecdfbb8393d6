"""What the rest of the product knows about the SUMO simulator (:class:`core.descriptor.SimDescriptor`)."""

from __future__ import annotations

from typing import Any

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor
from sims.sumo.config import SumoConfig
from sims.sumo.families import FAMILY, family_kwargs

METRIC_COLUMNS = ("success", "collision", "red_light", "timeout", "route_progress", "speed_mean")

SCENARIOS = (
    ScenarioSpec("c1", "C1 · route 1", {"route": 1, "special_vehicles": False}),
    ScenarioSpec("c2", "C2 · route 2 + special vehicles (route shift)", {"route": 2, "special_vehicles": True}),
    ScenarioSpec("1", "route 1", {"route": 1, "special_vehicles": False}),
    ScenarioSpec("2", "route 2", {"route": 2, "special_vehicles": False}),
    ScenarioSpec("1-special", "route 1 · special vehicles", {"route": 1, "special_vehicles": True}),
)


def _family_scenario(name: str) -> dict[str, Any]:
    """A name outside the named scenarios: ``sumo-shift:train`` / ``:test`` (:mod:`sims.sumo.families`)."""
    kwargs = family_kwargs(name)
    if kwargs is None:
        raise ValueError(f"choose one of {', '.join(spec.name for spec in SCENARIOS)}, {FAMILY}:train or {FAMILY}:test")
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
    # libsumo holds the GIL while it steps, which would stall the server's event loop and the page's input
    live_options={"process": True},
    parse_scenario=_family_scenario,  # sumo-shift:train / :test (sims/sumo/families.py)
)
