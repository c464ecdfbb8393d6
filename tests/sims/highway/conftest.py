"""Shared helpers for the highway sim tests: a few test-split scenarios and a fixed simple policy."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sims.highway.scenarios import scenario_ids

torch.set_num_threads(1)

FEW_TEST_IDS = scenario_ids("test")[:12]
"""Scenarios shared by the slower tests (their logs are recorded once and cached on disk)."""


class LaneKeeper:
    """Constant speed, steering towards the next route checkpoint on its lane: the fixed simple policy."""

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        bearing_sin, heading_sin = float(obs[6]), float(obs[1])
        return np.array([np.clip(3.0 * bearing_sin - 2.0 * heading_sin, -1.0, 1.0), 0.0], np.float32)


@pytest.fixture
def lane_keeper() -> LaneKeeper:
    return LaneKeeper()
