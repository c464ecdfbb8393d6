"""What the rest of the product knows about the UGV simulator (:class:`core.descriptor.SimDescriptor`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from core.descriptor import InputMapping, ScenarioSpec, SimDescriptor
from sims.ugv.config import UGVConfig
from sims.ugv.fields import parse_field_name
from sims.ugv.lidar import footprint_ranges
from sims.ugv.metrics import METRIC_COLUMNS

REPOSITORY = Path(__file__).resolve().parents[2]
"""Where a relative scenario path that is not found from the working directory is looked up."""


def _scenario_file(name: str) -> dict[str, Any]:
    """Any scenario YAML file (schema: :mod:`sims.ugv.scenario`) is a scenario too, and so is a generated field's name
    (``ugv-fields:train``, ``ugv-fields:test``, ``ugv-fields:test:17``: :mod:`sims.ugv.fields`)."""
    selection = parse_field_name(name)  # a FieldNameError (a ValueError) for a malformed field name
    if selection is not None:
        return {"scenario": selection}
    path = Path(name).expanduser()
    if path.suffix.lower() in (".yaml", ".yml"):
        if not path.is_file() and not path.is_absolute() and (REPOSITORY / path).is_file():
            # the project's policies record their scenario files from the repository root (ugv-default's
            # sims/ugv/scenarios/clutter.yaml): they must resolve from any working directory, e.g. a Ray trial's
            path = REPOSITORY / path
        if not path.is_file():
            raise ValueError(f"scenario file not found: {path}")
        return {"scenario": str(path)}
    raise ValueError(
        "give 1-4 (the paper's field tests), the path of a scenario .yaml file or a generated field "
        "(ugv-fields:train, ugv-fields:test, ugv-fields:test:<index>)"
    )


def contact_floors(config: UGVConfig | None = None) -> tuple[float, ...]:
    """The observation's first channels are the lidar sectors' ranges over ``max_range``: a sector at or under the
    robot's footprint along its rays (:func:`sims.ugv.lidar.footprint_ranges`) has something touching the body."""
    config = config or UGVConfig()
    ranges = footprint_ranges(config.lidar, config.robot.length, config.robot.width) / config.lidar.max_range
    return tuple(float(r) for r in ranges)


DESCRIPTOR = SimDescriptor(
    name="ugv",
    title="UGV (pymunk ground robot)",
    env_id="sage/UGV-v0",
    entry_point="sims.ugv.env:UGVEnv",
    dt=UGVConfig().dt,
    scenarios=(
        ScenarioSpec("1", "1 · narrow passage", {"scenario": 1}),
        ScenarioSpec("2", "2 · detour", {"scenario": 2}),
        ScenarioSpec("3", "3 · crossing", {"scenario": 3}),
        ScenarioSpec("4", "4 · cut-in", {"scenario": 4}),
    ),
    default_scenario="1",
    # linear speed and yaw rate, both normalised to [-1, 1]; positive yaw rate turns left
    input_mapping=InputMapping(throttle_index=0, steer_index=1),
    metric_columns=METRIC_COLUMNS,
    safe_action=(-1.0, 0.0),  # a0 = -1 is v = 0: stand still, no turning
    contact_floors=contact_floors(),
    parse_scenario=_scenario_file,
)
