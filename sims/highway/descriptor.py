"""What the rest of the product knows about the highway simulator (:class:`core.descriptor.SimDescriptor`)."""

from __future__ import annotations

from typing import Any

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor
from sims.highway.config import HighwayConfig
from sims.highway.families import parse_family_name

METRIC_COLUMNS = ("success", "collision", "speed_mean", "acc_mean", "off_road", "timeout", "min_ttc", "mean_gap")
"""The paper's S.R., C.R., speed and acceleration, then what makes the adversarial set harder."""


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
    parse_scenario=_pool_id,
)
