"""Shared helpers for the UGV tests: small scenario files written on the fly."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml


def room(**overrides: Any) -> dict[str, Any]:
    """An empty 4 m x 4 m room with a fixed start and goal; override any field."""
    data: dict[str, Any] = {
        "name": "test_room",
        "bounds": [0, 0, 4, 4],
        "start": {"x": 1.0, "y": 2.0, "yaw_deg": 0},
        "goal": {"x": 3.0, "y": 2.0, "radius": 0.3},
        "time_limit": 10,
    }
    data.update(overrides)
    return data


@pytest.fixture
def write_scenario(tmp_path: Path) -> Callable[[dict[str, Any]], Path]:
    counter = iter(range(1000))

    def write(data: dict[str, Any]) -> Path:
        path = tmp_path / f"scenario_{next(counter)}.yaml"
        path.write_text(yaml.safe_dump(data))
        return path

    return write
