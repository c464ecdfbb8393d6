"""Per-simulator tables: scenario choices to ``sims.make`` arguments, and the control period."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from app.live import control_period
from app.sim_choices import listed, make_kwargs


def test_scenario_numbers_become_each_simulators_own_arguments() -> None:
    assert make_kwargs("ugv", 3) == {"scenario": 3}
    assert make_kwargs("highway", 2) == {"split": "test", "mode": "adversarial"}
    assert make_kwargs("sumo", 2) == {"route": 2}
    assert make_kwargs("sumo", None) == {}
    assert make_kwargs("elsewhere", 7) == {"scenario": 7}
    with pytest.raises(ValueError, match="no scenario 9"):
        make_kwargs("ugv", 9)
    assert [c["id"] for c in listed("ugv")] == [1, 2, 3, 4] and listed("elsewhere") == []


def env_with(**inner: object) -> SimpleNamespace:
    return SimpleNamespace(unwrapped=SimpleNamespace(**inner))


def test_control_period_is_found_where_each_simulator_keeps_it() -> None:
    assert control_period(env_with(dt=0.05)) == 0.05
    assert control_period(env_with(config=SimpleNamespace(step_length=0.5))) == 0.5
    assert control_period(env_with(config=SimpleNamespace(policy_frequency=5))) == 0.2
    assert control_period(env_with(metadata={"render_fps": 20})) == 0.05
    assert control_period(env_with(dt=True, metadata={})) == 0.1  # nothing usable: the 10 Hz default
