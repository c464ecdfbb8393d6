"""What the rest of the product knows about the pedestrian simulator (:class:`core.descriptor.SimDescriptor`)."""

from __future__ import annotations

from typing import Any

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor
from sims.pedestrian.config import PedestrianConfig
from sims.pedestrian.families import FAMILY, family_kwargs
from sims.pedestrian.metrics import METRIC_COLUMNS
from sims.pedestrian.world import encode


def keys_to_action(throttle: float, steer: float) -> int:
    """Operator axes in [-1, 1] -> one of the 9 actions. No throttle input brakes (a person holding control
    without pressing forward never cruises: the safe action); up to half forward maintains the speed, more
    accelerates. Steering beyond ±0.3 turns the wheel."""
    t = 1 if throttle > 0.5 else (0 if throttle > 0.05 else -1)
    s = 1 if steer > 0.3 else (-1 if steer < -0.3 else 0)
    return encode(t, s)


SCENARIOS = (
    ScenarioSpec("crossing", "crossing · a pedestrian steps out in front of the truck", {}),
    ScenarioSpec("clear", "clear · the truck, no pedestrian", {"pedestrian_probability": 0.0}),
    ScenarioSpec(
        "parked",
        "parked · more parked cars, no pedestrian",
        {"pedestrian_probability": 0.0, "parked_vehicles": (1, 4)},
    ),
    ScenarioSpec(
        "rare",
        "rare · training mix: parked cars, a pedestrian in 20% of episodes",
        {"pedestrian_probability": 0.2, "parked_vehicles": (0, 4)},
    ),
)


def _family_scenario(name: str) -> dict[str, Any]:
    """A name outside the named scenarios: ``pedestrian-shift:train`` / ``:test`` (:mod:`sims.pedestrian.families`)."""
    kwargs = family_kwargs(name)
    if kwargs is None:
        raise ValueError(f"choose one of {', '.join(spec.name for spec in SCENARIOS)}, {FAMILY}:train or {FAMILY}:test")
    return kwargs


DESCRIPTOR = SimDescriptor(
    name="pedestrian",
    title="Occluded pedestrian (urban road, parked truck)",
    env_id="sage/Pedestrian-v0",
    entry_point="sims.pedestrian.env:PedestrianEnv",
    dt=PedestrianConfig().dt,
    scenarios=SCENARIOS,
    default_scenario="crossing",
    input_mapping=InputMapping(throttle_index=None, steer_index=None, discrete=keys_to_action),
    metric_columns=METRIC_COLUMNS,
    safe_action=encode(-1, 0),  # brake, keep the wheel straight
    parse_scenario=_family_scenario,  # pedestrian-shift:train / :test (sims/pedestrian/families.py)
)
