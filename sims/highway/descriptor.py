"""What the rest of the product knows about the highway simulator (:class:`core.descriptor.SimDescriptor`)."""

from __future__ import annotations

import math
from typing import Any

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor
from sims.highway.config import HighwayConfig
from sims.highway.env import OBS_SIZE
from sims.highway.families import parse_family_name
from sims.highway.road import LANE_WIDTH

METRIC_COLUMNS = ("success", "collision", "speed_mean", "acc_mean", "off_road", "timeout", "min_ttc", "mean_gap")
"""The paper's S.R., C.R., speed and acceleration, then what makes the adversarial set harder."""


def lane_beams(config: HighwayConfig | None = None) -> tuple[int, ...]:
    """The beams (indices into the 72, 0 straight ahead, counter-clockwise) that see only the ego's own lane over
    the sensor's whole reach: a beam at θ from the heading reaches the near side of a vehicle centred in the next lane
    (``LANE_WIDTH`` - width / 2 to the side) at (``LANE_WIDTH`` - width / 2) / |sin θ|, and only beyond the range for
    these. With 72 beams and a 50 m reach: straight ahead and straight behind."""
    config = config or HighwayConfig()
    beams, reach = config.sensor.beams, config.sensor.range
    side = LANE_WIDTH - config.ego.width / 2
    return tuple(i for i in range(beams) if abs(math.sin(2 * math.pi * i / beams)) * reach < side)


def contact_floors(config: HighwayConfig | None = None) -> tuple[float | None, ...]:
    """The observation's channels where it shows contact (:func:`sims.highway.env.observe`): a lane beam
    (:func:`lane_beams`) reads the distance from the ego's centre to the nearest box along its own lane, so at or
    under half the ego's length (over the reach) a vehicle ahead or behind touches its bumper. None elsewhere: the
    kinematics and guidance say nothing of contact, and a beam at an angle also sees the next lane's traffic, which
    passes by without touching."""
    config = config or HighwayConfig()
    first = OBS_SIZE - HighwayConfig().sensor.beams  # kinematics and guidance; the beams are the last channels
    floor = config.ego.length / 2 / config.sensor.range
    floors: list[float | None] = [None] * (first + config.sensor.beams)
    for beam in lane_beams(config):
        floors[first + beam] = floor
    return tuple(floors)


def _pool_id(name: str) -> dict[str, Any]:
    """One logged scenario of the pool by its id (``"17"``, or ``"17-adversarial"``), or a ``highway-shift`` name
    (:mod:`sims.highway.families`)."""
    selection = parse_family_name(name)  # a FamilyNameError (a ValueError) for a malformed family name
    if selection is not None:
        return selection.env_kwargs()
    base, _, mode = name.partition("-")
    if base.isdigit() and mode in ("", "normal", "adversarial"):
        return {"scenario_id": int(base), **({"mode": mode} if mode else {})}
    raise ValueError(
        "give a logged split: train, test or all (optionally -adversarial), a pool id 0-499, or highway-shift:train, "
        "highway-shift:test or highway-shift:<split>:<index>"
    )


DESCRIPTOR = SimDescriptor(
    name="highway",
    title="Highway (logged and adversarial traffic)",
    env_id="sage/Highway-v0",
    entry_point="sims.highway.env:HighwayEnv",
    dt=HighwayConfig().dt,
    scenarios=(
        ScenarioSpec("test", "test logs · normal", {"split": "test", "mode": "normal"}),
        ScenarioSpec("test-adversarial", "test logs · adversarial", {"split": "test", "mode": "adversarial"}),
        ScenarioSpec("train", "train logs · normal", {"split": "train", "mode": "normal"}),
        ScenarioSpec("train-adversarial", "train logs · adversarial", {"split": "train", "mode": "adversarial"}),
        ScenarioSpec("all", "all logs · normal", {"split": "all", "mode": "normal"}),
    ),
    default_scenario="train",
    # the action is [steer, acc]; y points north, the left of the driving direction: positive steering turns left
    input_mapping=InputMapping(throttle_index=1, steer_index=0),
    metric_columns=METRIC_COLUMNS,
    safe_action=(0.0, -1.0),  # wheels straight, full braking
    contact_floors=contact_floors(),
    parse_scenario=_pool_id,
)
